// The Lightwire wire protocol (PROTOCOL.md, version 4) in JavaScript: the
// JavaScript twin of `protocol/src/messages.rs` and `protocol/src/codec.rs`.
//
// Every message is one WebSocket binary frame, encoded with bincode 2 in one
// fixed configuration: little endian, variable-length integers (PROTOCOL.md
// §2). The message layouts below are written once, as schemas, and one
// generic reader/writer walks them in both directions, so decoding and
// encoding cannot disagree about field order.
//
// In JavaScript a message is a plain object `{ type: "Hello", ...fields }`;
// newtype variants (`Keyframe(Keyframe)`, `Delta(Delta)`, `Stats(Stats)`)
// carry their struct's fields directly. Unit enums (`Role`, `PixelFormat`,
// `LightType`) are their variant names as strings, `Option` is `null` or
// the value, `Vec<u8>` is a `Uint8Array`, and an `ErrorCode` is its numeric
// value (`ERROR_NAMES` names the known ones). Integers are Numbers: a u64
// above 2^53 - 1 cannot be held exactly by a Number and is refused by the
// decoder rather than silently rounded (versions and microsecond clocks
// stay far below it). Sequence numbers are the exception: they compare in
// serial-number order (PROTOCOL.md §1.7), so a driver may send any u64,
// and a seq above 2^53 - 1 decodes to a BigInt (the encoder takes either;
// `seqIsNewer` compares them as the server does, `nextSeq` counts on). The
// golden vectors in `protocol/tests/vectors/` pin all of it
// (`server/dashboard/test/protocol.test.mjs`).

/** The protocol version this code speaks (`Hello.protocol_version`). */
export const PROTOCOL_VERSION = 4;

/**
 * `Welcome.capabilities` bit: the server serves the scene as glTF binary at
 * `sceneGlbPath(scene.id)` on the WebSocket's host (PROTOCOL.md §3,
 * "Capabilities"). Twin of `lightwire_protocol::CAP_SCENE_GLB`.
 */
export const CAP_SCENE_GLB = 1;

/**
 * `Welcome.capabilities` bit: the server sends `Poses` to a client whose
 * Hello set `HELLO_POSES` (PROTOCOL.md §3, "Capabilities"). Twin of
 * `lightwire_protocol::CAP_POSES`.
 */
export const CAP_POSES = 2;

/**
 * `Welcome.capabilities` bit: the server sends `Lights` to a client whose
 * Hello set `HELLO_LIGHTS` and follows drivers' `SetLight` (PROTOCOL.md
 * §3, "Capabilities"); `lightwire serve` sets it, and `lightwire relay`
 * while its upstream does (it forwards SetLight upstream and passes the
 * upstream's Lights on). Twin of `lightwire_protocol::CAP_LIGHTS`.
 */
export const CAP_LIGHTS = 4;

/**
 * `Hello.capabilities` bit: send me `Poses`, the poses of the dynamic
 * objects each lightmap version was lit for. A server without `CAP_POSES`
 * ignores it. Twin of `lightwire_protocol::HELLO_POSES`.
 */
export const HELLO_POSES = 1;

/**
 * `Hello.capabilities` bit: send me `Lights`, the lights' states each
 * lightmap version was lit with (version 4; a server ignores it from an
 * older client). Twin of `lightwire_protocol::HELLO_LIGHTS`.
 */
export const HELLO_LIGHTS = 2;

const SEQ_MODULUS = 1n << 64n;
const SEQ_HALF = 1n << 63n;

/**
 * Whether sequence number `seq` is newer than `latest` in serial-number
 * order (PROTOCOL.md §1.7; twin of `lightwire_protocol::seq_is_newer`):
 * `seq - latest` modulo 2^64 is in 1 ..= 2^63 - 1, so after 2^64 - 1 comes
 * 0 and no seq freezes an object or a light. Computed on BigInt; takes
 * BigInts or (safe integer) Numbers.
 */
export function seqIsNewer(seq, latest) {
  const ahead = (((BigInt(seq) - BigInt(latest)) % SEQ_MODULUS) + SEQ_MODULUS) % SEQ_MODULUS;
  return ahead !== 0n && ahead < SEQ_HALF;
}

/** The seq after `seq` (2^64 - 1 is followed by 0): a Number when it is
 * at most 2^53 - 1, else a BigInt, as the decoder gives seqs. */
export function nextSeq(seq) {
  if (typeof seq === 'number' && seq < Number.MAX_SAFE_INTEGER) return seq + 1;
  const next = (BigInt(seq) + 1n) % SEQ_MODULUS;
  return next <= BigInt(Number.MAX_SAFE_INTEGER) ? Number(next) : next;
}

/**
 * `/api/scenes/{id}/scene.glb` with the id percent-encoded as one path
 * segment (every UTF-8 byte but A-Z a-z 0-9 - . _ ~), as the Rust
 * `scene_glb_path` writes it.
 */
export function sceneGlbPath(id) {
  let segment = '';
  for (const b of new TextEncoder().encode(id)) {
    const c = String.fromCharCode(b);
    segment += /[A-Za-z0-9\-._~]/.test(c) ? c : `%${b.toString(16).toUpperCase().padStart(2, '0')}`;
  }
  return `/api/scenes/${segment}/scene.glb`;
}

/** The largest frame either side accepts, checked before parsing (§1). */
export const MAX_FRAME_BYTES = 8 * 1024 * 1024;

/** Error code values and their names (§6). Unknown values are kept as numbers. */
export const ERROR_NAMES = Object.freeze({
  1: 'BadFrame',
  2: 'TooLarge',
  3: 'UnsupportedVersion',
  4: 'Unauthorized',
  5: 'Forbidden',
  6: 'UnknownObject',
  7: 'InvalidPose',
  8: 'RateLimited',
  9: 'StaleSeq',
  10: 'ProtocolViolation',
  11: 'UnknownLight',
  12: 'InvalidLight',
});

/** A frame that does not decode: truncated, garbage, trailing bytes, too large. */
export class DecodeError extends Error {
  constructor(message) {
    super(message);
    this.name = 'DecodeError';
  }
}

const utf8Decoder = new TextDecoder('utf-8', { fatal: true });
const utf8Encoder = new TextEncoder();

/** Reads bincode values from one frame, tracking the position for errors. */
class Reader {
  constructor(bytes, what) {
    this.bytes = bytes;
    this.view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    this.pos = 0;
    this.what = what;
  }

  fail(reason) {
    throw new DecodeError(`${this.what} at byte ${this.pos} of ${this.bytes.length}: ${reason}`);
  }

  need(n) {
    const missing = this.pos + n - this.bytes.length;
    if (missing > 0) this.fail(`frame ends early (${missing} more bytes needed)`);
  }

  u8() {
    this.need(1);
    return this.bytes[this.pos++];
  }

  /** An unsigned varint (§2) no larger than `max`. */
  varint(max, type) {
    const tag = this.u8();
    let value;
    if (tag < 251) {
      value = tag;
    } else if (tag === 251) {
      this.need(2);
      value = this.view.getUint16(this.pos, true);
      this.pos += 2;
    } else if (tag === 252) {
      this.need(4);
      value = this.view.getUint32(this.pos, true);
      this.pos += 4;
    } else if (tag === 253) {
      this.need(8);
      const big = this.view.getBigUint64(this.pos, true);
      this.pos += 8;
      if (big > BigInt(Number.MAX_SAFE_INTEGER)) {
        if (type === 'seq') return big;
        if (type !== 'u64') this.fail(`${big} does not fit a ${type}`);
        this.fail(`u64 ${big} is above 2^53 - 1, which JavaScript cannot hold exactly`);
      }
      value = Number(big);
    } else {
      this.pos -= 1;
      this.fail(`invalid varint tag 0x${tag.toString(16)}`);
    }
    if (value > max) this.fail(`${value} does not fit a ${type}`);
    return value;
  }

  f32() {
    this.need(4);
    const v = this.view.getFloat32(this.pos, true);
    this.pos += 4;
    return v;
  }

  bool() {
    const b = this.u8();
    if (b > 1) {
      this.pos -= 1;
      this.fail(`invalid bool byte 0x${b.toString(16)}`);
    }
    return b === 1;
  }

  /** A length prefix; every element takes at least one byte, so a count
   * larger than the bytes left is refused before anything is allocated. */
  length() {
    const n = this.varint(Number.MAX_SAFE_INTEGER, 'length');
    if (n > this.bytes.length - this.pos) {
      this.fail(`length ${n} exceeds the ${this.bytes.length - this.pos} bytes left`);
    }
    return n;
  }

  rawBytes(n) {
    this.need(n);
    const out = this.bytes.slice(this.pos, this.pos + n);
    this.pos += n;
    return out;
  }
}

/** Appends bincode values to a growing buffer. */
class Writer {
  constructor() {
    this.bytes = new Uint8Array(64);
    this.view = new DataView(this.bytes.buffer);
    this.len = 0;
  }

  reserve(n) {
    if (this.len + n <= this.bytes.length) return;
    let size = this.bytes.length * 2;
    while (size < this.len + n) size *= 2;
    const next = new Uint8Array(size);
    next.set(this.bytes.subarray(0, this.len));
    this.bytes = next;
    this.view = new DataView(next.buffer);
  }

  u8(v) {
    this.reserve(1);
    this.bytes[this.len++] = v;
  }

  /** The shortest varint form (§2: encoders must write it). */
  varint(v, max, type) {
    if (!Number.isSafeInteger(v) || v < 0 || v > max) {
      throw new RangeError(`${v} is not a valid ${type}`);
    }
    if (v < 251) {
      this.u8(v);
    } else if (v < 0x10000) {
      this.reserve(3);
      this.bytes[this.len] = 251;
      this.view.setUint16(this.len + 1, v, true);
      this.len += 3;
    } else if (v < 0x100000000) {
      this.reserve(5);
      this.bytes[this.len] = 252;
      this.view.setUint32(this.len + 1, v, true);
      this.len += 5;
    } else {
      this.reserve(9);
      this.bytes[this.len] = 253;
      this.view.setBigUint64(this.len + 1, BigInt(v), true);
      this.len += 9;
    }
  }

  f32(v) {
    this.reserve(4);
    this.view.setFloat32(this.len, v, true);
    this.len += 4;
  }

  /** A seq: a Number as any u64, or a BigInt up to 2^64 - 1. */
  seq(v) {
    if (typeof v !== 'bigint' || v <= BigInt(Number.MAX_SAFE_INTEGER)) {
      this.varint(typeof v === 'bigint' ? Number(v) : v, Number.MAX_SAFE_INTEGER, 'seq');
      return;
    }
    if (v >= SEQ_MODULUS) throw new RangeError(`${v} is not a valid seq`);
    this.reserve(9);
    this.bytes[this.len] = 253;
    this.view.setBigUint64(this.len + 1, v, true);
    this.len += 9;
  }

  raw(bytes) {
    this.reserve(bytes.length);
    this.bytes.set(bytes, this.len);
    this.len += bytes.length;
  }

  finish() {
    return this.bytes.slice(0, this.len);
  }
}

// --- Schemas: each type is { read(reader), write(writer, value) }. ---

const varintType = (max, name) => ({
  read: (r) => r.varint(max, name),
  write: (w, v) => w.varint(v, max, name),
});

const T = {
  u8: {
    read: (r) => r.u8(),
    write: (w, v) => {
      if (!Number.isInteger(v) || v < 0 || v > 255) throw new RangeError(`${v} is not a u8`);
      w.u8(v);
    },
  },
  u16: varintType(0xffff, 'u16'),
  u32: varintType(0xffffffff, 'u32'),
  u64: varintType(Number.MAX_SAFE_INTEGER, 'u64'),
  /** A u64 sequence number: a Number, or a BigInt above 2^53 - 1. */
  seq: { read: (r) => r.varint(Number.MAX_SAFE_INTEGER, 'seq'), write: (w, v) => w.seq(v) },
  bool: { read: (r) => r.bool(), write: (w, v) => w.u8(v ? 1 : 0) },
  f32: { read: (r) => r.f32(), write: (w, v) => w.f32(v) },
  string: {
    read: (r) => {
      const bytes = r.rawBytes(r.length());
      try {
        return utf8Decoder.decode(bytes);
      } catch {
        r.fail('string is not valid UTF-8');
      }
    },
    write: (w, v) => {
      const bytes = utf8Encoder.encode(v);
      w.varint(bytes.length, Number.MAX_SAFE_INTEGER, 'length');
      w.raw(bytes);
    },
  },
  /** `Vec<u8>`: a count, then raw bytes; a Uint8Array in JavaScript. */
  bytes: {
    read: (r) => r.rawBytes(r.length()),
    write: (w, v) => {
      w.varint(v.length, Number.MAX_SAFE_INTEGER, 'length');
      w.raw(v);
    },
  },
};

const array = (type, n) => ({
  read: (r) => Array.from({ length: n }, () => type.read(r)),
  write: (w, v) => {
    if (v.length !== n) throw new RangeError(`expected ${n} elements, got ${v.length}`);
    for (const x of v) type.write(w, x);
  },
});

const vec = (type) => ({
  read: (r) => {
    const n = r.length();
    const out = new Array(n);
    for (let i = 0; i < n; i++) out[i] = type.read(r);
    return out;
  },
  write: (w, v) => {
    w.varint(v.length, Number.MAX_SAFE_INTEGER, 'length');
    for (const x of v) type.write(w, x);
  },
});

const option = (type) => ({
  read: (r) => {
    const tag = r.u8();
    if (tag === 0) return null;
    if (tag === 1) return type.read(r);
    r.pos -= 1;
    return r.fail(`invalid Option tag 0x${tag.toString(16)}`);
  },
  write: (w, v) => {
    if (v === null || v === undefined) {
      w.u8(0);
    } else {
      w.u8(1);
      type.write(w, v);
    }
  },
});

/** A struct: its fields in declaration order, nothing between them. */
const struct = (fields) => ({
  fields,
  read: (r) => {
    const out = {};
    for (const [name, type] of fields) out[name] = type.read(r);
    return out;
  },
  write: (w, v) => {
    for (const [name, type] of fields) {
      if (!(name in v)) throw new RangeError(`missing field "${name}"`);
      type.write(w, v[name]);
    }
  },
});

/** An enum of unit variants, represented by the variant's name. */
const unitEnum = (name, variants) => ({
  read: (r) => {
    const i = r.varint(0xffffffff, 'u32');
    if (i >= variants.length) r.fail(`unknown ${name} variant ${i}`);
    return variants[i];
  },
  write: (w, v) => {
    const i = variants.indexOf(v);
    if (i < 0) throw new RangeError(`unknown ${name} "${v}"`);
    w.varint(i, 0xffffffff, 'u32');
  },
});

/** An enum with data: `{ type: variant, ...fields }`. */
const dataEnum = (name, variants) => ({
  read: (r) => {
    const i = r.varint(0xffffffff, 'u32');
    if (i >= variants.length) r.fail(`unknown ${name} variant ${i}`);
    const [variant, body] = variants[i];
    return { type: variant, ...body.read(r) };
  },
  write: (w, v) => {
    const i = variants.findIndex(([variant]) => variant === v.type);
    if (i < 0) throw new RangeError(`unknown ${name} variant "${v.type}"`);
    w.varint(i, 0xffffffff, 'u32');
    variants[i][1].write(w, v);
  },
});

const Role = unitEnum('Role', ['Viewer', 'Driver', 'Admin']);
const PixelFormat = unitEnum('PixelFormat', ['Rgb9e5', 'Rgba16f']);
const LightType = unitEnum('LightType', ['Point', 'Spot', 'Directional']);
/** Not an enum discriminant: the code's u16 value as a varint (§6). */
const ErrorCode = T.u16;

const Pose = struct([
  ['translation', array(T.f32, 3)],
  ['rotation', array(T.f32, 4)],
  ['scale', T.f32],
]);
const ObjectSeq = struct([
  ['object', T.u32],
  ['seq', T.seq],
]);
/** A dynamic object's pose in a published version (`Poses`); `seq` is the
 * transform seq that set it (0: the scene file's pose). */
const ObjectPose = struct([
  ['object', T.u32],
  ['seq', T.seq],
  ['pose', Pose],
]);
const ObjectInfo = struct([
  ['name', T.string],
  ['dynamic', T.bool],
  ['pose', Pose],
]);
const MaterialInfo = struct([
  ['name', T.string],
  ['albedo', array(T.f32, 3)],
  ['emission', array(T.f32, 3)],
]);
const SurfaceInfo = struct([
  ['name', T.string],
  ['object', T.u32],
  ['material', T.u32],
  ['corners', array(array(T.f32, 3), 4)],
  ['rect', array(T.u32, 4)],
  // Version 3: the corners' lightmap coordinates when they do not follow
  // from `rect` (a triangle on its mesh's own lightmap UVs), else empty.
  ['uvs', vec(array(T.f32, 2))],
]);
/** The part of a light that can change (`SetLight`, `Lights`); see
 * `lightProblem` for what the server accepts. */
const LightState = struct([
  ['on', T.bool],
  ['color', array(T.f32, 3)],
  ['intensity', T.f32],
  ['position', array(T.f32, 3)],
  ['direction', array(T.f32, 3)],
]);
/** Version 4: one light of the scene; `state` as the Welcome was built. */
const LightInfo = struct([
  ['name', T.string],
  ['kind', LightType],
  ['range', option(T.f32)],
  ['cone', array(T.f32, 2)],
  ['angular_radius', T.f32],
  ['state', LightState],
]);
/** A light's state in a published version (`Lights`); `seq` is the
 * SetLight seq that set it (0: the scene file's state). */
const LightStatus = struct([
  ['light', T.u32],
  ['seq', T.seq],
  ['state', LightState],
]);
const SceneInfo = struct([
  ['id', T.string],
  ['atlas_width', T.u32],
  ['atlas_height', T.u32],
  ['tile_size', T.u16],
  ['format', PixelFormat],
  ['objects', vec(ObjectInfo)],
  ['materials', vec(MaterialInfo)],
  ['surfaces', vec(SurfaceInfo)],
  // Version 4: the point, spot and directional lights.
  ['lights', vec(LightInfo)],
]);
const Tile = struct([
  ['index', T.u32],
  ['data', T.bytes],
]);
const Keyframe = struct([
  ['version', T.u64],
  ['reflected', vec(ObjectSeq)],
  ['tiles', vec(Tile)],
]);
const Delta = struct([
  ['base_version', T.u64],
  ['version', T.u64],
  ['reflected', vec(ObjectSeq)],
  /** Empty, or one zstd frame: a tile bitmap, then the residuals of the
   * tiles it sets (PROTOCOL.md §5; `Lightmap.unpackResidual` reads it). */
  ['residual', T.bytes],
]);
const Stats = struct([
  ['version', T.u64],
  ['unshot_fraction', T.f32],
  ['tick_ms', T.f32],
  ['solve_ms', T.f32],
  ['redistribution_ms', T.f32],
  ['clients', T.u32],
  ['server_time_us', T.u64],
]);

const ClientMessage = dataEnum('ClientMessage', [
  [
    'Hello',
    struct([
      ['protocol_version', T.u16],
      ['client', T.string],
      ['token', option(T.string)],
      ['capabilities', T.u32],
    ]),
  ],
  [
    'Transform',
    struct([
      ['object', T.u32],
      ['seq', T.seq],
      ['pose', Pose],
      ['client_time_us', T.u64],
    ]),
  ],
  ['Resync', struct([['have_version', option(T.u64)]])],
  ['Ping', struct([['nonce', T.u64]])],
  /** Version 4: a driver sets light `light`'s whole state. */
  [
    'SetLight',
    struct([
      ['light', T.u32],
      ['seq', T.seq],
      ['state', LightState],
      ['client_time_us', T.u64],
    ]),
  ],
]);

const ServerMessage = dataEnum('ServerMessage', [
  [
    'Welcome',
    struct([
      ['protocol_version', T.u16],
      ['server', T.string],
      ['role', Role],
      ['capabilities', T.u32],
      ['scene', SceneInfo],
    ]),
  ],
  ['Keyframe', Keyframe],
  ['Delta', Delta],
  ['Stats', Stats],
  [
    'Error',
    struct([
      ['code', ErrorCode],
      ['message', T.string],
    ]),
  ],
  ['Pong', struct([['nonce', T.u64]])],
  /** Sent only after a Hello with `HELLO_POSES`, immediately before the
   * Keyframe or Delta of `version`, whenever a pose changed: every dynamic
   * object, in object order. */
  [
    'Poses',
    struct([
      ['version', T.u64],
      ['poses', vec(ObjectPose)],
    ]),
  ],
  /** Version 4, sent only after a Hello with `HELLO_LIGHTS`, immediately
   * before the Keyframe or Delta of `version`, whenever a light's state
   * or seq changed: every light, in light order. */
  [
    'Lights',
    struct([
      ['version', T.u64],
      ['lights', vec(LightStatus)],
    ]),
  ],
]);

function decode(type, what, frame) {
  const bytes = frame instanceof Uint8Array ? frame : new Uint8Array(frame);
  if (bytes.length > MAX_FRAME_BYTES) {
    throw new DecodeError(
      `${what}: frame of ${bytes.length} bytes exceeds the ${MAX_FRAME_BYTES}-byte limit`,
    );
  }
  const r = new Reader(bytes, what);
  const value = type.read(r);
  if (r.pos !== bytes.length) {
    r.fail(`${bytes.length - r.pos} trailing bytes after the message`);
  }
  return value;
}

/** Decodes one server frame (ArrayBuffer or Uint8Array); throws DecodeError. */
export function decodeServer(frame) {
  return decode(ServerMessage, 'ServerMessage', frame);
}

/** Decodes one client frame; throws DecodeError. */
export function decodeClient(frame) {
  return decode(ClientMessage, 'ClientMessage', frame);
}

/** Encodes a client message to one frame's bytes. */
export function encodeClient(message) {
  const w = new Writer();
  ClientMessage.write(w, message);
  return w.finish();
}

/** Encodes a server message (used by tests and tools). */
export function encodeServer(message) {
  const w = new Writer();
  ServerMessage.write(w, message);
  return w.finish();
}

/** The name of an error code, or `Other(n)` for codes this version does not know. */
export function errorName(code) {
  return ERROR_NAMES[code] ?? `Other(${code})`;
}

/** §4: what the server checks before accepting a `Transform`. Returns null
 * when the pose is valid, else the reason. */
export function poseProblem(pose) {
  const { translation, rotation, scale } = pose;
  if (!translation.every(Number.isFinite)) return 'translation is not finite';
  if (!rotation.every(Number.isFinite)) return 'rotation is not finite';
  if (!Number.isFinite(scale)) return 'scale is not finite';
  if (!(scale > 0)) return 'scale is not positive';
  const norm = Math.hypot(...rotation.map((v) => Math.fround(v)));
  if (Math.abs(norm - 1) > 1e-3) return 'rotation is not a unit quaternion';
  return null;
}

/** §4: what the server checks before accepting a `SetLight`, in its order
 * (`LightState::validate`), on the f32 values the state encodes to.
 * Returns null when the state is valid, else the reason. */
export function lightProblem(state) {
  const f = (v) => Math.fround(v);
  const color = state.color.map(f);
  const intensity = f(state.intensity);
  const position = state.position.map(f);
  const direction = state.direction.map(f);
  if (!color.every(Number.isFinite)) return 'color is not finite';
  if (!Number.isFinite(intensity)) return 'intensity is not finite';
  if (!position.every(Number.isFinite)) return 'position is not finite';
  if (!direction.every(Number.isFinite)) return 'direction is not finite';
  if (color.some((c) => !(c >= 0 && c <= 1))) return 'color is out of range (each channel in [0, 1])';
  if (!(intensity >= 0 && intensity <= 1e6)) return 'intensity is out of range (0 to 1e6)';
  if (position.some((v) => Math.abs(v) > 1e5)) {
    return 'position is out of range (each component at most 1e5 in magnitude)';
  }
  const norm = Math.sqrt(direction.reduce((sum, v) => sum + v * v, 0));
  if (Math.abs(norm - 1) > 1e-3) return 'direction is not a unit vector (|d| differs from 1 by more than 1e-3)';
  return null;
}
