// The JavaScript decoder against the protocol's golden vectors: the same
// files `protocol/tests/golden_vectors.rs` checks the Rust codec with. Every
// `.bin` must decode to the value in `manifest.json`, and that value must
// encode to the identical bytes. Then the lightmap: the golden keyframe and
// delta applied, texel by texel, to the values PROTOCOL.md §8 spells out,
// the refusals §5 requires, a delta's residual payload (protocol version 2:
// a tile bitmap and the residuals of the tiles it sets, in one zstd frame)
// and the streams of `sequences.json` applied frame by frame and merged.

import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

import {
  CAP_LIGHTS,
  CAP_POSES,
  CAP_SCENE_GLB,
  DecodeError,
  HELLO_LIGHTS,
  HELLO_POSES,
  MAX_FRAME_BYTES,
  PROTOCOL_VERSION,
  decodeClient,
  decodeServer,
  encodeClient,
  encodeServer,
  errorName,
  lightProblem,
  nextSeq,
  poseProblem,
  sceneGlbPath,
  seqIsNewer,
} from '../src/protocol.js';
import { ApplyError, Lightmap, applyResidual, halfToFloat, rgb9e5Decode, zstdFrameProblem } from '../src/lightmap.js';
import { decompress } from '../src/vendor/fzstd.js';
import { cornerUvs } from '../src/view3d.js';

const here = path.dirname(fileURLToPath(import.meta.url));
const vectors = path.resolve(here, '../../../protocol/tests/vectors');
const manifest = JSON.parse(fs.readFileSync(path.join(vectors, 'manifest.json'), 'utf8'));
const bin = (name) => new Uint8Array(fs.readFileSync(path.join(vectors, `${name}.bin`)));
const sequences = JSON.parse(fs.readFileSync(path.join(vectors, 'sequences.json'), 'utf8'));
const fromHex = (hex) => Uint8Array.from(Buffer.from(hex, 'hex'));
const toHex = (bytes) => Buffer.from(bytes).toString('hex');

/** `bytes` as one zstd frame of a single raw block (at most 255 bytes), with
 * its content size declared: what a hand-written tile payload looks like. */
function rawZstd(bytes) {
  assert.ok(bytes.length <= 255);
  const header = (bytes.length << 3) | 1; // last block, raw
  return Uint8Array.from([0x28, 0xb5, 0x2f, 0xfd, 0x20, bytes.length, header & 0xff, header >> 8, 0, ...bytes]);
}

/** A zstd block header (RFC 8878 §3.1.1.2): `type` 0 raw, 1 RLE, 2 compressed. */
const blockHeader = (type, size, last) => {
  const word = (size << 3) | (type << 1) | (last ? 1 : 0);
  return [word & 0xff, (word >> 8) & 0xff, word >> 16];
};

/** `content` as one single-segment zstd frame of raw blocks of at most
 * `blockSize` bytes, declaring `declared` (by default its true length) as its
 * 4-byte content size; `rle` appends RLE blocks of that many zero bytes (each
 * at most 128 KiB) after the raw ones. */
function zstdFrame(content, { declared = content.length, blockSize = 128 * 1024, rle = [] } = {}) {
  const out = [0x28, 0xb5, 0x2f, 0xfd, 0xa0, ...new Uint8Array(Uint32Array.of(declared).buffer)];
  const raw = [];
  for (let at = 0; at < content.length; at += blockSize) raw.push(content.subarray(at, at + blockSize));
  if (raw.length === 0 && rle.length === 0) raw.push(content); // an empty frame: one empty raw block
  raw.forEach((chunk, i) => out.push(...blockHeader(0, chunk.length, i === raw.length - 1 && rle.length === 0), ...chunk));
  rle.forEach((size, i) => out.push(...blockHeader(1, size, i === rle.length - 1), 0));
  return Uint8Array.from(out);
}

/** A delta payload content: the tile bitmap of `bitmapBytes` bytes with the
 * bits of `indices` set, then `tiles` (each a residual's planes). */
function residualContent(bitmapBytes, indices, ...tiles) {
  const bitmap = new Uint8Array(bitmapBytes);
  for (const i of indices) bitmap[i >> 3] |= 1 << (i & 7);
  return Uint8Array.from([...bitmap, ...tiles.flatMap((t) => Array.from(t))]);
}

/** The tile indices a delta's payload sets, read independently of the
 * lightmap code: fzstd's own decompression, then the bitmap's bits. Also
 * checks the payload's length against the tiles it sets. */
function payloadTiles(map, residual) {
  if (residual.length === 0) return [];
  const raw = decompress(residual);
  const bitmap = Math.ceil(map.tileCount / 8);
  const indices = [];
  for (let i = 0; i < bitmap * 8; i++) if ((raw[i >> 3] >> (i & 7)) & 1) indices.push(i);
  const sizes = indices.map((i) => map.tileRect(i).width * map.tileRect(i).height * map.bytesPerTexel);
  assert.equal(raw.length, bitmap + sizes.reduce((a, b) => a + b, 0), 'the payload is the bitmap and its tiles');
  return indices;
}

/** Our JavaScript form -> the serde JSON form the manifest uses. */
function toSerde(message) {
  const { type, ...fields } = message;
  const convert = (v) => {
    if (v instanceof Uint8Array) return Array.from(v);
    if (Array.isArray(v)) return v.map(convert);
    if (v && typeof v === 'object') {
      return Object.fromEntries(Object.entries(v).map(([k, x]) => [k, convert(x)]));
    }
    return v;
  };
  const body = convert(fields);
  if (type === 'Error') {
    const name = errorName(body.code);
    body.code = name.startsWith('Other(') ? { Other: body.code } : name;
  }
  return { [type]: body };
}

/** The serde JSON form -> our JavaScript form (for encoding). */
function fromSerde(serde) {
  const [[type, body]] = Object.entries(serde);
  const message = { type, ...structuredClone(body) };
  if (type === 'Error') {
    const code = message.code;
    message.code =
      typeof code === 'object'
        ? code.Other
        : Number(Object.entries({ ...errorNames() }).find(([, n]) => n === code)[0]);
  }
  for (const tile of message.tiles ?? []) tile.data = Uint8Array.from(tile.data);
  if (message.residual) message.residual = Uint8Array.from(message.residual);
  return message;
}

function errorNames() {
  const out = {};
  for (let i = 1; i < 20; i++) if (!errorName(i).startsWith('Other(')) out[i] = errorName(i);
  return out;
}

test('the manifest is for the protocol version this decoder speaks', () => {
  assert.equal(manifest.protocol_version, PROTOCOL_VERSION);
  const files = fs.readdirSync(vectors).filter((f) => f.endsWith('.bin')).sort();
  assert.deepEqual(manifest.vectors.map((v) => v.file).sort(), files, 'every .bin is in the manifest');
});

for (const v of manifest.vectors) {
  test(`golden vector ${v.name}: decodes to the manifest value and re-encodes to the same bytes`, () => {
    const bytes = bin(v.name);
    assert.equal(Buffer.from(bytes).toString('hex'), v.hex, 'the file matches the manifest hex');
    const decode = v.decoder === 'client' ? decodeClient : decodeServer;
    const encode = v.decoder === 'client' ? encodeClient : encodeServer;
    const decoded = decode(bytes);
    assert.deepEqual(toSerde(decoded), v.message);
    assert.deepEqual(encode(fromSerde(v.message)), bytes, 'encoding the value gives the golden bytes');
    assert.deepEqual(encode(decoded), bytes, 'decode then encode is the identity');
  });
}

test('a Welcome with CAP_SCENE_GLB says where the scene glTF is, as the Rust crate builds the path', () => {
  const plain = decodeServer(bin('server_welcome'));
  assert.equal(plain.capabilities & CAP_SCENE_GLB, 0);
  const welcome = decodeServer(bin('server_welcome_scene_glb'));
  assert.equal(welcome.capabilities & CAP_SCENE_GLB, CAP_SCENE_GLB);
  assert.equal(sceneGlbPath(welcome.scene.id), '/api/scenes/cornell/scene.glb');
  // The cases of lightwire_protocol's own test.
  assert.equal(sceneGlbPath('cornell-large'), '/api/scenes/cornell-large/scene.glb');
  assert.equal(sceneGlbPath('a b/c'), '/api/scenes/a%20b%2Fc/scene.glb');
  assert.equal(sceneGlbPath('é'), '/api/scenes/%C3%A9/scene.glb');
});

test('Poses: the capability bits of Hello and Welcome, and the golden Poses before the golden delta', () => {
  assert.equal(CAP_SCENE_GLB, 1);
  assert.equal(CAP_POSES, 2);
  assert.equal(HELLO_POSES, 1);
  assert.equal(decodeClient(bin('client_hello')).capabilities & HELLO_POSES, 0);
  assert.equal(decodeClient(bin('client_hello_poses')).capabilities, HELLO_POSES);
  assert.equal(decodeServer(bin('server_welcome_scene_glb')).capabilities & CAP_POSES, 0);
  assert.equal(decodeServer(bin('server_welcome_poses')).capabilities, CAP_SCENE_GLB | CAP_POSES);
  const poses = decodeServer(bin('server_poses'));
  const delta = decodeServer(bin('server_delta'));
  assert.equal(poses.type, 'Poses');
  assert.equal(poses.version, delta.version, 'the poses of the version that follows');
  assert.deepEqual(
    poses.poses.map(({ object, seq }) => ({ object, seq })),
    delta.reflected,
    'each pose carries the seq the delta reflects',
  );
  // The same pose as the golden Transform's.
  assert.deepEqual(poses.poses[0].pose, decodeClient(bin('client_transform')).pose);
  assert.equal(poseProblem(poses.poses[0].pose), null);
  // No poses: tag, version, empty Vec.
  assert.equal(toHex(encodeServer({ type: 'Poses', version: 300, poses: [] })), '06fb2c0100');
  // Truncated anywhere: refused.
  const bytes = bin('server_poses');
  for (let n = 1; n < bytes.length; n++) assert.throws(() => decodeServer(bytes.subarray(0, n)), DecodeError, `prefix of ${n} bytes`);
});

test('Lights (version 4): the capability bits, the lights of the golden Welcome, SetLight byte by byte, Lights before the golden delta', () => {
  assert.equal(CAP_LIGHTS, 4);
  assert.equal(HELLO_LIGHTS, 2);
  assert.equal(decodeClient(bin('client_hello_poses')).capabilities & HELLO_LIGHTS, 0);
  assert.equal(decodeClient(bin('client_hello_lights')).capabilities, HELLO_POSES | HELLO_LIGHTS);
  assert.equal(decodeServer(bin('server_welcome_poses')).capabilities & CAP_LIGHTS, 0);
  const welcome = decodeServer(bin('server_welcome_lights'));
  assert.equal(welcome.capabilities, CAP_SCENE_GLB | CAP_POSES | CAP_LIGHTS);
  assert.deepEqual(
    welcome.scene.lights.map(({ name, kind, range }) => [name, kind, range]),
    [
      ['lamp', 'Spot', 4],
      ['sun', 'Directional', null],
    ],
  );
  for (const light of welcome.scene.lights) assert.equal(lightProblem(light.state), null, light.name);
  // Every scene of the other golden Welcomes has no lights: one 00 byte at the end.
  for (const name of ['server_welcome', 'server_welcome_poses', 'server_welcome_uvs']) {
    const bytes = bin(name);
    assert.deepEqual(decodeServer(bytes).scene.lights, [], name);
    assert.equal(bytes.at(-1), 0, name);
  }
  // SetLight, field by field (PROTOCOL.md §8).
  const setLight = bin('client_set_light');
  assert.equal(
    toHex(setLight),
    [
      '04', // variant 4 (SetLight)
      '00', // light 0
      '05', // seq 5
      '01', // on
      '0000803f0000403f0000003f', // colour (1, 0.75, 0.5)
      '0000a03f', // intensity 1.25
      '0000803e6666663f0000003f', // position (0.25, 0.9, 0.5)
      '9a99193fcdcc4cbf00000000', // direction (0.6, -0.8, 0)
      'fd00401e18240a0600', // client_time_us 1 700 000 000 000 000
    ].join(''),
  );
  const set = decodeClient(setLight);
  assert.equal(set.type, 'SetLight');
  assert.equal(lightProblem(set.state), null);
  // Lights: the version of the delta that follows, every light in order,
  // the lamp as the SetLight set it, the sun at the scene file's seq 0.
  const lights = decodeServer(bin('server_lights'));
  assert.equal(lights.type, 'Lights');
  assert.equal(lights.version, decodeServer(bin('server_delta')).version);
  assert.deepEqual(lights.lights.map((l) => [l.light, l.seq]), [
    [0, set.seq],
    [1, 0],
  ]);
  assert.deepEqual(lights.lights[0].state, set.state);
  assert.deepEqual(lights.lights[1].state, welcome.scene.lights[1].state);
  assert.equal(toHex(encodeServer({ type: 'Lights', version: 300, lights: [] })), '07fb2c0100');
  for (const name of ['client_set_light', 'server_lights', 'server_welcome_lights']) {
    const bytes = bin(name);
    const decode = name.startsWith('client') ? decodeClient : decodeServer;
    for (let n = 1; n < bytes.length; n++) assert.throws(() => decode(bytes.subarray(0, n)), DecodeError, `${name}: prefix of ${n} bytes`);
  }
  // A LightType beyond Directional, and a range's Option tag of 2.
  const bad = Uint8Array.from(bin('server_welcome_lights'));
  const lamp = toHex(bad).indexOf(toHex(new TextEncoder().encode('lamp'))) / 2 + 4;
  assert.equal(bad[lamp], 1, 'Spot');
  bad[lamp] = 3;
  assert.throws(() => decodeServer(bad), /unknown LightType variant 3/);
  bad[lamp] = 1;
  bad[lamp + 1] = 2;
  assert.throws(() => decodeServer(bad), /invalid Option tag/);
});

test('error codes 11 and 12 are named; later ones are kept as numbers', () => {
  assert.equal(errorName(11), 'UnknownLight');
  assert.equal(errorName(12), 'InvalidLight');
  assert.equal(errorName(13), 'Other(13)');
});

test('seqs compare in serial-number order, so no seq freezes an object or a light', () => {
  // The cases of lightwire_protocol's own test.
  assert.ok(seqIsNewer(1n, 0n));
  assert.ok(seqIsNewer(8n, 7n));
  assert.ok(!seqIsNewer(7n, 7n));
  assert.ok(!seqIsNewer(6n, 7n));
  assert.ok(!seqIsNewer(0n, 0n), 'the first seq is at least 1');
  const max = (1n << 64n) - 1n;
  assert.ok(seqIsNewer(max / 2n, 1n));
  assert.ok(seqIsNewer(0n, max));
  assert.ok(seqIsNewer(5n, max));
  assert.ok(seqIsNewer(max, max - 1n));
  assert.ok(!seqIsNewer(1n << 63n, 0n));
  assert.ok(!seqIsNewer(0n, 1n << 63n), 'exactly half way round is not newer either way');
  for (const latest of [0n, 1n, 1n << 62n, (1n << 63n) - 1n, 1n << 63n, max - 1n, max]) {
    assert.ok(seqIsNewer((latest + 1n) % (1n << 64n), latest), `${latest}`);
  }
  // Numbers, as the decoder gives seqs.
  assert.ok(seqIsNewer(1_700_000_000_000_001, 1_700_000_000_000_000));
  assert.ok(!seqIsNewer(5, 300));
  assert.ok(seqIsNewer(0, max), 'mixed: a Number after a BigInt');
  // The seq after: a Number while it fits, 0 after 2^64 - 1.
  assert.equal(nextSeq(0), 1);
  assert.equal(nextSeq(Number.MAX_SAFE_INTEGER - 1), Number.MAX_SAFE_INTEGER);
  assert.equal(nextSeq(Number.MAX_SAFE_INTEGER), 2n ** 53n);
  assert.equal(nextSeq(2n ** 60n), 2n ** 60n + 1n);
  assert.equal(nextSeq(max), 0);
  assert.equal(nextSeq(5n), 6);
  for (const seq of [0, 7, Number.MAX_SAFE_INTEGER, 2n ** 63n, max]) assert.ok(seqIsNewer(nextSeq(seq), seq), `${seq}`);
});

test('any u64 seq decodes (a BigInt above 2^53 - 1) and re-encodes to the same bytes; other u64s above it are refused', () => {
  const transform = decodeClient(bin('client_transform'));
  const max = (1n << 64n) - 1n;
  for (const seq of [Number.MAX_SAFE_INTEGER, 2n ** 53n, 2n ** 63n, max]) {
    const bytes = encodeClient({ ...transform, seq });
    assert.equal(toHex(bytes.subarray(2, 11)), `fd${Buffer.from(new BigUint64Array([BigInt(seq)]).buffer).toString('hex')}`);
    const back = decodeClient(bytes);
    assert.equal(back.seq, seq, `${seq}`);
    assert.deepEqual(encodeClient(back), bytes);
  }
  assert.equal(typeof decodeClient(encodeClient({ ...transform, seq: 2n ** 40n })).seq, 'number', 'a BigInt that fits decodes as a Number');
  assert.deepEqual(encodeClient({ ...transform, seq: 300n }), bin('client_transform'));
  assert.throws(() => encodeClient({ ...transform, seq: max + 1n }), RangeError);
  assert.throws(() => encodeClient({ ...transform, seq: -1 }), RangeError);
  // Seqs in every message that carries one: Lights, Poses, a keyframe's reflected.
  const lights = decodeServer(bin('server_lights'));
  const wrapped = { ...lights, lights: lights.lights.map((l) => ({ ...l, seq: max })) };
  assert.deepEqual(decodeServer(encodeServer(wrapped)), wrapped);
  const keyframe = decodeServer(bin('server_keyframe'));
  assert.equal(decodeServer(encodeServer({ ...keyframe, reflected: [{ object: 0, seq: max }] })).reflected[0].seq, max);
  // A version, a nonce, a clock: still refused above 2^53 - 1.
  const version = Uint8Array.from([7, 0xfd, ...new Uint8Array(new BigUint64Array([2n ** 53n]).buffer), 0]); // Lights, no lights
  assert.throws(() => decodeServer(version), /above 2\^53 - 1/);
  assert.throws(() => encodeServer({ ...wrapped, version: 2n ** 60n }), RangeError);
});

test('light state validity follows PROTOCOL.md §4, checked in the server\'s order', () => {
  const state = { on: true, color: [1, 0.75, 0.5], intensity: 2.5, position: [0.5, 0.9, 0.5], direction: [0, -1, 0] };
  assert.equal(lightProblem(state), null);
  assert.equal(lightProblem({ ...state, on: false, color: [0, 0, 0], intensity: 0 }), null);
  assert.equal(lightProblem({ ...state, intensity: 1e6, position: [1e5, -1e5, 0] }), null);
  assert.equal(lightProblem({ ...state, direction: [0, -1.0009, 0] }), null);
  assert.equal(lightProblem({ ...state, color: [NaN, 0, 0] }), 'color is not finite');
  assert.equal(lightProblem({ ...state, intensity: Infinity }), 'intensity is not finite');
  assert.equal(lightProblem({ ...state, intensity: 1e39 }), 'intensity is not finite', 'beyond f32: infinite on the wire');
  assert.equal(lightProblem({ ...state, position: [0, -Infinity, 0] }), 'position is not finite');
  assert.equal(lightProblem({ ...state, direction: [NaN, 0, 0] }), 'direction is not finite');
  assert.match(lightProblem({ ...state, color: [1.01, 0, 0] }), /^color is out of range/);
  assert.match(lightProblem({ ...state, color: [0, -0.1, 0] }), /^color is out of range/);
  assert.match(lightProblem({ ...state, intensity: -1 }), /^intensity is out of range/);
  assert.match(lightProblem({ ...state, intensity: 1.1e6 }), /^intensity is out of range/);
  assert.match(lightProblem({ ...state, position: [0, 0, 1.01e5] }), /^position is out of range/);
  assert.match(lightProblem({ ...state, direction: [0, -1.002, 0] }), /^direction is not a unit vector/);
  assert.match(lightProblem({ ...state, direction: [0, 0, 0] }), /^direction is not a unit vector/);
  // The first failing check names the problem: a NaN direction and a bad colour -> the NaN.
  assert.equal(lightProblem({ ...state, color: [2, 0, 0], direction: [NaN, 0, 0] }), 'direction is not finite');
  assert.match(lightProblem({ ...state, color: [2, 0, 0], intensity: -1 }), /^color/);
});

test('varints use the shortest form and all four lengths (PROTOCOL.md §2 examples)', () => {
  const ping = (nonce) => Buffer.from(encodeClient({ type: 'Ping', nonce })).toString('hex');
  assert.equal(ping(5), '0305');
  assert.equal(ping(250), '03fa');
  assert.equal(ping(300), '03fb2c01');
  assert.equal(ping(0xdeadbeef), '03fcefbeadde');
  assert.equal(ping(1_700_000_000_000_000), '03fd00401e18240a0600');
  // bincode accepts longer forms when decoding; so do we.
  assert.equal(decodeClient(Uint8Array.from([3, 0xfb, 5, 0])).nonce, 5);
});

test('a truncated frame at every length is a DecodeError naming the position', () => {
  const bytes = bin('server_welcome');
  for (let n = 0; n < bytes.length; n++) {
    assert.throws(() => decodeServer(bytes.subarray(0, n)), DecodeError, `prefix of ${n} bytes`);
  }
  assert.throws(() => decodeServer(bytes.subarray(0, 5)), /ServerMessage at byte \d+ of 5: /);
});

test('trailing bytes, bad tags, bad bools, invalid UTF-8 and unknown variants are refused', () => {
  const ping = bin('client_ping');
  assert.throws(() => decodeClient(Uint8Array.from([...ping, 0])), /1 trailing bytes/);
  assert.throws(() => decodeClient(Uint8Array.from([3, 0xfe])), /invalid varint tag 0xfe/);
  assert.throws(() => decodeClient(Uint8Array.from([3, 0xff])), /invalid varint tag 0xff/);
  assert.throws(() => decodeClient(Uint8Array.from([9])), /unknown ClientMessage variant 9/);
  assert.throws(() => decodeClient(Uint8Array.from([5])), /unknown ClientMessage variant 5/);
  assert.throws(() => decodeServer(Uint8Array.from([8])), /unknown ServerMessage variant 8/);
  // Hello with protocol_version 0x10000: does not fit a u16.
  assert.throws(() => decodeClient(Uint8Array.from([0, 0xfc, 0, 0, 1, 0])), /does not fit a u16/);
  // Hello whose client name is invalid UTF-8.
  assert.throws(() => decodeClient(Uint8Array.from([0, 1, 1, 0xff, 0, 0])), /not valid UTF-8/);
  // Hello whose token Option tag is 2.
  assert.throws(() => decodeClient(Uint8Array.from([0, 1, 0, 2])), /invalid Option tag/);
  // Welcome with an ObjectInfo.dynamic byte of 2.
  const welcome = bin('server_welcome');
  const dyn = welcome.indexOf(0x62, 20) + 3; // after "box"
  assert.equal(welcome[dyn], 1);
  const bad = Uint8Array.from(welcome);
  bad[dyn] = 2;
  assert.throws(() => decodeServer(bad), /invalid bool/);
});

test('length prefixes beyond the frame are refused before allocating', () => {
  // A Keyframe claiming a billion tiles in 8 bytes.
  const frame = Uint8Array.from([1, 1, 0, 0xfc, 0x00, 0xca, 0x9a, 0x3b]);
  assert.throws(() => decodeServer(frame), /length 1000000000 exceeds the 0 bytes left/);
});

test('frames above MAX_FRAME_BYTES are refused before parsing', () => {
  assert.throws(() => decodeServer(new Uint8Array(MAX_FRAME_BYTES + 1)), /exceeds the 8388608-byte limit/);
});

test('u64 values above 2^53 - 1 are refused, never rounded', () => {
  const pong = Uint8Array.from([5, 0xfd, 0, 0, 0, 0, 0, 0, 0x20, 0]); // 2^53
  assert.throws(() => decodeServer(pong), /above 2\^53 - 1/);
  const ok = Uint8Array.from([5, 0xfd, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x1f, 0]);
  assert.equal(decodeServer(ok).nonce, Number.MAX_SAFE_INTEGER);
});

test('pose validity follows PROTOCOL.md §4', () => {
  const pose = { translation: [1, 2, 3], rotation: [0, Math.SQRT1_2, 0, Math.SQRT1_2], scale: 1 };
  assert.equal(poseProblem(pose), null);
  assert.match(poseProblem({ ...pose, translation: [NaN, 0, 0] }), /translation/);
  assert.match(poseProblem({ ...pose, scale: 0 }), /scale/);
  assert.match(poseProblem({ ...pose, rotation: [0, 0, 0, 1.01] }), /unit quaternion/);
});

test('RGB9E5 decodes the worked example of §5 and the extremes', () => {
  assert.deepEqual(rgb9e5Decode(0x81010100), [1, 0.5, 0.25]);
  assert.deepEqual(rgb9e5Decode(0), [0, 0, 0]);
  assert.deepEqual(rgb9e5Decode(0xf80001ff), [65408, 0, 0]);
});

const close = (a, b) => a.every((x, i) => x === b[i]);

test('the golden keyframe then delta reconstruct the texels of §8', () => {
  const welcome = decodeServer(bin('server_welcome'));
  const map = Lightmap.forScene(welcome.scene);
  assert.equal(map.tileCount, 2);
  assert.deepEqual(map.tileRect(1), { x: 2, y: 0, width: 1, height: 2 });
  const keyframe = decodeServer(bin('server_keyframe'));
  const rects = map.applyKeyframe(keyframe);
  assert.equal(rects.length, 2);
  assert.equal(map.version, 1);
  const expect = {
    '0,0': [1, 0.5, 0.25],
    '1,0': [0, 0, 0],
    '0,1': [2, 2, 2],
    '1,1': [65408, 0, 0],
    '2,0': [0.125, 0.0625, 1],
    '2,1': [3, 0, 0],
  };
  for (const [key, rgb] of Object.entries(expect)) {
    const [x, y] = key.split(',').map(Number);
    assert.ok(close(map.texel(x, y), rgb), `texel ${key}: ${map.texel(x, y)} != ${rgb}`);
  }
  map.applyDelta(decodeServer(bin('server_delta')));
  assert.equal(map.version, 2);
  assert.ok(close(map.texel(2, 0), [1, 1, 1]));
  assert.ok(close(map.texel(2, 1), [0, 0, 0]));
  assert.ok(close(map.texel(0, 0), [1, 0.5, 0.25]), 'tiles not in the delta keep their texels');
  // Row-major words: (0,0) (1,0) (2,0) / (0,1) (1,1) (2,1); (2,0) is (1, 1, 1), (2,1) is 0.
  assert.deepEqual(Array.from(new Uint32Array(map.bytes.buffer)), [0x81010100, 0, 0x84020100, 0x8c020100, 0xf80001ff, 0]);
});

/** Asserts that `apply` throws ApplyError('bad-frame') matching `message`
 * and leaves `map`'s texels, decoded texels and version as they were. */
function assertRefused(map, apply, message, name) {
  const bytes = Uint8Array.from(map.bytes);
  const rgb = Float32Array.from(map.rgb);
  const version = map.version;
  assert.throws(
    apply,
    (e) => {
      assert.ok(e instanceof ApplyError, `${name}: ${e}`);
      assert.equal(e.kind, 'bad-frame', `${name}: ${e.message}`);
      assert.match(e.message, message, name);
      return true;
    },
    name,
  );
  assert.deepEqual(map.bytes, bytes, `${name}: texels unchanged`);
  assert.deepEqual(map.rgb, rgb, `${name}: decoded texels unchanged`);
  assert.equal(map.version, version, `${name}: version unchanged`);
}

test('bad keyframe tiles are refused and leave the lightmap unchanged', () => {
  const welcome = decodeServer(bin('server_welcome'));
  const keyframe = decodeServer(bin('server_keyframe'));
  const [tile0, tile1] = keyframe.tiles;
  const next = (tiles) => ({ ...keyframe, version: 2, tiles });
  const cases = [
    ['out of range', [tile0, { ...tile1, index: 2 }], /tile 2 is out of range/],
    ['repeated', [tile0, tile0], /tile 0 appears twice/],
    ['not zstd', [tile0, { index: 1, data: Uint8Array.from([1, 2, 3, 4, 5, 6, 7]) }], /no zstd frame magic/],
    // Tile 0's payload (16 bytes) sent as tile 1 (8 bytes).
    ['wrong size', [tile0, { index: 1, data: tile0.data }], /content size 16, expected 8/],
    ['trailing', [tile0, { index: 1, data: Uint8Array.from([...tile1.data, 0]) }], /1 bytes after the zstd frame/],
    ['truncated', [tile0, { index: 1, data: tile1.data.subarray(0, tile1.data.length - 1) }], /truncated block/],
    // A valid tile 0 followed by a bad one: nothing may be written.
    ['partly bad', [tile0, { index: 1, data: Uint8Array.from([0x28, 0xb5, 0x2f, 0xfd]) }], /tile 1/],
  ];
  for (const [name, tiles, message] of cases) {
    const map = Lightmap.forScene(welcome.scene);
    map.applyKeyframe(keyframe);
    map.bytes.fill(7); // so that rewriting tile 0 with its keyframe texels would show
    assertRefused(map, () => map.applyKeyframe(next(tiles)), message, name);
  }
  const map = Lightmap.forScene(welcome.scene);
  map.applyKeyframe(keyframe);
  assert.throws(() => map.applyDelta({ ...decodeServer(bin('server_delta')), base_version: 5, version: 6 }), (e) => e.kind === 'wrong-base');
  assert.throws(() => map.applyKeyframe({ ...keyframe, tiles: [tile0] }), /keyframe has 1 tiles, the atlas has 2/);
  assert.throws(() => new Lightmap(8193, 8193, 8, 'Rgb9e5'), /more than/);
});

test('zstd frame checks: content size must be declared and exact, blocks at most 128 KiB', () => {
  const frame = decodeServer(bin('server_keyframe')).tiles[1].data;
  assert.equal(zstdFrameProblem(frame, 8), null);
  assert.match(zstdFrameProblem(frame, 9), /content size 8, expected 9/);
  const noSize = Uint8Array.from(frame);
  noSize[4] = 0x00; // no single segment, no content size: needs a window byte
  assert.match(zstdFrameProblem(noSize, 8), /does not declare its content size/);
  assert.equal(zstdFrameProblem(zstdFrame(new Uint8Array(300), { blockSize: 100 }), 300), null, 'several blocks');
  const huge = Uint8Array.from([0x28, 0xb5, 0x2f, 0xfd, 0xa0, 1, 0, 2, 0, ...blockHeader(1, 128 * 1024 + 1, true), 0]);
  assert.match(zstdFrameProblem(huge, 128 * 1024 + 1), /block of 131073 bytes, above the 131072-byte maximum/);
});

test('the golden delta is the hand-computed residual of §5 and applies bit for bit', () => {
  // One 1x2 tile of (0.125, 0.0625, 1), (3, 0, 0), as in server_keyframe's tile 1.
  const word = (r, g, b, e) => (r | (g << 9) | (b << 18) | (e << 27)) >>> 0;
  const le = (...words) => new Uint8Array(Uint32Array.from(words).buffer);
  const held = le(word(32, 16, 256, 16), word(384, 0, 0, 17));
  assert.deepEqual(rgb9e5Decode(word(32, 16, 256, 16)), [0.125, 0.0625, 1]);
  assert.deepEqual(rgb9e5Decode(word(384, 0, 0, 17)), [3, 0, 0]);
  // To (1, 1, 1) = (256, 256, 256, 16) and (0, 0, 0) = all zero:
  // texel 0: dr +224 -> z 448, dg +240 -> z 480, db 0, de 0;
  // texel 1: dr -384 = +128 mod 512 -> z 256, dg db 0, de -17 = +15 mod 32 -> z 30.
  const planes = fromHex('c000e000000003f1');
  const map = new Lightmap(1, 2, 2, 'Rgb9e5');
  map.applyKeyframe({ version: 1, reflected: [], tiles: [{ index: 0, data: rawZstd(held) }] });
  assert.deepEqual(map.bytes, held);
  // A one-tile atlas: bitmap 0x01, then the tile's planes.
  const rects = map.applyDelta({ base_version: 1, version: 2, reflected: [], residual: rawZstd([0x01, ...planes]) });
  assert.deepEqual(rects, [{ x: 0, y: 0, width: 1, height: 2 }]);
  assert.deepEqual(map.bytes, le(word(256, 256, 256, 16), 0));
  assert.deepEqual(map.texel(0, 0), [1, 1, 1]);
  assert.deepEqual(map.texel(0, 1), [0, 0, 0]);
  assert.equal(map.version, 2);
  // The golden server_delta carries exactly this residual as tile 1 of two:
  // a raw-block frame of bitmap 0x02 and the planes.
  const golden = decodeServer(bin('server_delta'));
  assert.deepEqual(golden.residual, fromHex('28b52ffd200949000002c000e000000003f1'));
  assert.deepEqual(golden.residual, rawZstd([0x02, ...planes]));
  assert.equal(golden.tiles, undefined, 'a delta carries no tile list');
  // An all-zero residual changes nothing; Rgba16f fields wrap modulo 2^16.
  const same = Uint8Array.from(held);
  applyResidual('Rgb9e5', same, new Uint8Array(8));
  assert.deepEqual(same, held);
  const half = Uint8Array.from([0x00, 0x3c, 0xff, 0xff, 0, 0, 0x00, 0x3c]); // R 1.0, G 0xffff, B 0, A 1.0
  // zR = 0x800 (+0x400: 1.0 -> 2.0), zG = 2 (+1: wraps to 0), zB = 1 (-1: wraps to 0xffff), zA = 0.
  applyResidual('Rgba16f', half, Uint8Array.from([0x00, 0x02, 0x01, 0x00, 0x08, 0x00, 0x00, 0x00]));
  assert.deepEqual(half, Uint8Array.from([0x00, 0x40, 0, 0, 0xff, 0xff, 0x00, 0x3c]));
});

test('a delta payload applies its tiles in bitmap order, from any block layout', () => {
  const welcome = decodeServer(bin('server_welcome'));
  const keyframe = decodeServer(bin('server_keyframe'));
  const fresh = () => {
    const map = Lightmap.forScene(welcome.scene);
    map.applyKeyframe(keyframe);
    return map;
  };
  // Tile 0 is 2x2 (16 bytes), tile 1 is 1x2 (8 bytes); the bitmap is 1 byte.
  const base = fresh();
  const old0 = base.readTile(base.tileRect(0));
  const old1 = base.readTile(base.tileRect(1));
  const new0 = Uint8Array.from({ length: 16 }, (_, i) => (i * 37 + 11) & 0xff);
  const new1 = Uint8Array.from({ length: 8 }, (_, i) => (i * 53 + 5) & 0xff);
  const r0 = encodeResidual('Rgb9e5', old0, new0);
  const r1 = encodeResidual('Rgb9e5', old1, new1);
  const both = residualContent(1, [0, 1], r0, r1);
  for (const [name, residual] of [
    ['one raw block', zstdFrame(both)],
    ['raw blocks of 5 bytes', zstdFrame(both, { blockSize: 5 })],
    ['1-byte content size', rawZstd(both)],
  ]) {
    const map = fresh();
    const rects = map.applyDelta({ base_version: 1, version: 3, reflected: [], residual });
    assert.deepEqual(rects, [map.tileRect(0), map.tileRect(1)], name);
    assert.deepEqual(map.readTile(map.tileRect(0)), new0, `${name}: tile 0`);
    assert.deepEqual(map.readTile(map.tileRect(1)), new1, `${name}: tile 1`);
    assert.deepEqual(map.rgb, decodeAll('Rgb9e5', map.bytes), `${name}: decoded texels follow`);
    assert.equal(map.version, 3);
  }
  // Tile 1 alone: tile 0 keeps its texels.
  const map = fresh();
  const rects = map.applyDelta({ base_version: 1, version: 2, reflected: [], residual: zstdFrame(residualContent(1, [1], r1)) });
  assert.deepEqual(rects, [map.tileRect(1)]);
  assert.deepEqual(map.readTile(map.tileRect(0)), old0);
  assert.deepEqual(map.readTile(map.tileRect(1)), new1);
  // A bitmap spanning two bytes: tile 8 of a 3x3-tile atlas.
  const big = new Lightmap(9, 9, 3, 'Rgb9e5');
  assert.equal(big.tileCount, 9);
  const planes = Uint8Array.from({ length: 36 }, (_, i) => i);
  const expected = new Uint8Array(36); // the residual applied onto all-zero texels
  applyResidual('Rgb9e5', expected, planes);
  assert.deepEqual(big.applyDelta({ base_version: 0, version: 1, reflected: [], residual: zstdFrame(residualContent(2, [8], planes)) }), [big.tileRect(8)]);
  assert.deepEqual(big.readTile(big.tileRect(8)), expected);
  assert.ok(big.readTile(big.tileRect(7)).every((b) => b === 0), 'tile 7 untouched');
});

test('an empty residual payload only moves the version', () => {
  const welcome = decodeServer(bin('server_welcome'));
  const map = Lightmap.forScene(welcome.scene);
  map.applyKeyframe(decodeServer(bin('server_keyframe')));
  const bytes = Uint8Array.from(map.bytes);
  const rgb = Float32Array.from(map.rgb);
  const frame = encodeServer({ type: 'Delta', base_version: 1, version: 4, reflected: [], residual: new Uint8Array(0) });
  assert.equal(toHex(frame), '0201040000', 'tag, base, version, no reflected, empty residual');
  assert.deepEqual(map.applyDelta(decodeServer(frame)), []);
  assert.equal(map.version, 4);
  assert.deepEqual(map.bytes, bytes);
  assert.deepEqual(map.rgb, rgb);
});

test('a bad residual payload is refused whole and leaves the lightmap unchanged', () => {
  const welcome = decodeServer(bin('server_welcome'));
  const keyframe = decodeServer(bin('server_keyframe'));
  // 2 tiles (16 + 8 bytes of residual), a 1-byte bitmap: at most 25 bytes.
  const t0 = Uint8Array.from({ length: 16 }, (_, i) => i + 1); // a nonzero residual for tile 0
  const t1 = Uint8Array.from({ length: 8 }, (_, i) => 0x80 + i);
  const good = zstdFrame(residualContent(1, [0, 1], t0, t1));
  const noSize = Uint8Array.from([0x28, 0xb5, 0x2f, 0xfd, 0x00, 0x00, ...blockHeader(0, 25, true), ...residualContent(1, [0, 1], t0, t1)]);
  const cases = [
    // Tile 0 is valid and read before the bad bit: it must not be written.
    ['bit beyond the last tile', zstdFrame(residualContent(1, [0, 2], t0)), /sets tile 2 in its bitmap; the atlas has 2 tiles/],
    ['the last bit of the bitmap byte', zstdFrame(residualContent(1, [0, 1, 7], t0, t1)), /sets tile 7/],
    ['ending inside a tile', zstdFrame(residualContent(1, [0, 1], t0, t1.subarray(0, 4))), /ends inside tile 1 \(21 bytes, 8 needed from byte 17\)/],
    ['ending inside the first tile', zstdFrame(residualContent(1, [0], t0.subarray(0, 15))), /ends inside tile 0/],
    ['bytes left over', zstdFrame(Uint8Array.from([...residualContent(1, [0], t0), 0])), /1 bytes left over after the tiles its bitmap sets/],
    ['a tile not in the bitmap', zstdFrame(residualContent(1, [0], t0, t1)), /8 bytes left over/],
    ['an empty bitmap with a tile', zstdFrame(residualContent(1, [], t1)), /8 bytes left over/],
    ['shorter than the bitmap', zstdFrame(new Uint8Array(0)), /of 0 bytes cannot hold the 1-byte tile bitmap/],
    ['zip bomb declared one byte too large', zstdFrame(residualContent(1, [0, 1], t0, t1), { declared: 26 }), /declares 26 bytes; a delta of this atlas holds at most 25/],
    // 2^52 bytes, 8-byte content size: allocating it would throw a RangeError, not an ApplyError.
    ['zip bomb of 2^52 bytes', Uint8Array.from([0x28, 0xb5, 0x2f, 0xfd, 0xe0, 0, 0, 0, 0, 0, 0, 0x10, 0, ...blockHeader(1, 128 * 1024, true), 0]), /declares 4503599627370496 bytes/],
    ['holding more than it declares', zstdFrame(residualContent(1, [0], t0), { rle: Array(64).fill(128 * 1024) }), /holds more than the 17 bytes it declares/],
    ['holding one byte more than it declares', zstdFrame(residualContent(1, [0, 1], t0, t1), { declared: 24 }), /holds more than the 24 bytes it declares/],
    ['holding less than it declares', zstdFrame(residualContent(1, [0], t0), { declared: 25 }), /holds 17 bytes but declares 25/],
    ['not zstd', Uint8Array.from([1, 2, 3, 4, 5, 6, 7]), /is not a zstd frame: no zstd frame magic/],
    ['too short for a frame', Uint8Array.from([0x28, 0xb5, 0x2f]), /is not a zstd frame/],
    ['no declared content size', noSize, /does not declare its content size/],
    ['trailing bytes after the frame', Uint8Array.from([...good, 0]), /1 bytes after the zstd frame/],
    ['a second frame after the frame', Uint8Array.from([...good, ...good]), /bytes after the zstd frame/],
    ['truncated', good.subarray(0, good.length - 1), /truncated block/],
    ['reserved block type', Uint8Array.from([...good.subarray(0, 9), ...blockHeader(3, 25, true), ...good.subarray(12)]), /reserved block type/],
    ['a corrupt compressed block', Uint8Array.from([0x28, 0xb5, 0x2f, 0xfd, 0xa0, 17, 0, 0, 0, ...blockHeader(2, 4, true), 0xff, 0xff, 0xff, 0xff]), /is not a valid zstd frame/],
  ];
  for (const [name, residual, message] of cases) {
    const map = Lightmap.forScene(welcome.scene);
    map.applyKeyframe(keyframe);
    assertRefused(map, () => map.applyDelta({ base_version: 1, version: 2, reflected: [], residual }), message, name);
  }
  // The good payload applies, and a delta in the old shape (a tile list) is refused.
  const map = Lightmap.forScene(welcome.scene);
  map.applyKeyframe(keyframe);
  const before = Uint8Array.from(map.bytes);
  assert.equal(map.applyDelta({ base_version: 1, version: 2, reflected: [], residual: good }).length, 2);
  assert.notDeepEqual(map.bytes, before);
  const old = Lightmap.forScene(welcome.scene);
  old.applyKeyframe(keyframe);
  assertRefused(old, () => old.applyDelta({ base_version: 1, version: 2, reflected: [], tiles: [] }), /no residual payload/, 'tile list');
  assertRefused(old, () => old.applyDelta({ base_version: 1, version: 1, reflected: [], residual: good }), /not above its base/, 'version not above base');
});

test('real zstd residual payloads whose declared size is off by one are refused', () => {
  // sequences.json holds payloads compressed by the real zstd (compressed
  // blocks, Huffman literals, sequences): the content length must be counted
  // exactly, not taken from the header. Every delta of every sequence, one
  // byte short and one byte long, then the delta itself.
  let checked = 0;
  for (const seq of sequences.sequences) {
    const [keyframe, ...deltas] = seq.frames.map((hex) => decodeServer(fromHex(hex)));
    const map = new Lightmap(seq.atlas_width, seq.atlas_height, seq.tile_size, seq.format);
    const most = Math.ceil(map.tileCount / 8) + map.bytes.length;
    map.applyKeyframe(keyframe);
    for (const delta of deltas) {
      const payload = delta.residual;
      assert.equal(payload[4] & 0xc0, 0x40, `${seq.name}: a 2-byte content size`);
      const declared = payload[5] + (payload[6] << 8) + 256;
      for (const [change, message] of [
        [+1, declared < most ? new RegExp(`holds ${declared} bytes but declares ${declared + 1}`) : /a delta of this atlas holds at most/],
        [-1, new RegExp(`holds more than the ${declared - 1} bytes it declares`)],
      ]) {
        const bad = Uint8Array.from(payload);
        const size = declared + change - 256;
        [bad[5], bad[6]] = [size & 0xff, size >> 8];
        assertRefused(map, () => map.applyDelta({ ...delta, residual: bad }), message, `${seq.name} ${delta.version} ${change}`);
        checked++;
      }
      map.applyDelta(delta);
    }
    assert.equal(toHex(map.bytes), seq.final_texels);
  }
  assert.ok(checked > 40);
});

/** Test-side encoder, straight from the definition in PROTOCOL.md §5: the
 * residual that takes `old` to `new`. */
function encodeResidual(format, old, next) {
  const widths = format === 'Rgb9e5' ? [9, 9, 9, 5] : [16, 16, 16, 16];
  const bpt = format === 'Rgb9e5' ? 4 : 8;
  const fields = (b, t) => {
    const v = new DataView(b.buffer, b.byteOffset + t * bpt, bpt);
    if (format === 'Rgb9e5') {
      const w = v.getUint32(0, true);
      return [w & 0x1ff, (w >>> 9) & 0x1ff, (w >>> 18) & 0x1ff, w >>> 27];
    }
    return [0, 2, 4, 6].map((k) => v.getUint16(k, true));
  };
  const n = old.length / bpt;
  const planes = new Uint8Array(old.length);
  for (let t = 0; t < n; t++) {
    const [a, b] = [fields(old, t), fields(next, t)];
    const z = widths.map((w, i) => {
      const m = 2 ** w;
      let s = (((b[i] - a[i]) % m) + m) % m;
      if (s >= m / 2) s -= m;
      return s >= 0 ? 2 * s : -2 * s - 1;
    });
    if (format === 'Rgb9e5') {
      for (let c = 0; c < 3; c++) planes[c * n + t] = z[c] & 0xff;
      planes[3 * n + t] = (z[0] >> 8) | ((z[1] >> 8) << 1) | ((z[2] >> 8) << 2) | (z[3] << 3);
    } else {
      for (let c = 0; c < 4; c++) {
        planes[c * n + t] = z[c] & 0xff;
        planes[(c + 4) * n + t] = z[c] >> 8;
      }
    }
  }
  return planes;
}

test('residuals of random texels, extremes included, take old to new exactly', () => {
  let seed = 12345;
  const random = () => (seed = (Math.imul(seed, 1103515245) + 12345) >>> 0) >>> 24;
  for (const format of ['Rgb9e5', 'Rgba16f']) {
    for (let round = 0; round < 50; round++) {
      const len = (format === 'Rgb9e5' ? 4 : 8) * (1 + (round % 7));
      const pick = () => (round % 5 === 0 ? [0, 0xff][random() & 1] : random());
      const old = Uint8Array.from({ length: len }, pick);
      const next = Uint8Array.from({ length: len }, pick);
      const texels = Uint8Array.from(old);
      applyResidual(format, texels, encodeResidual(format, old, next));
      assert.deepEqual(texels, next, `${format} round ${round}`);
    }
  }
  assert.throws(() => applyResidual('Rgb9e5', new Uint8Array(8), new Uint8Array(4)), RangeError);
});

/** Linear RGB of every texel of `bytes`, decoded afresh. */
function decodeAll(format, bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const bpt = format === 'Rgb9e5' ? 4 : 8;
  const out = new Float32Array((bytes.length / bpt) * 3);
  for (let t = 0; t < bytes.length / bpt; t++) {
    const rgb =
      format === 'Rgb9e5'
        ? rgb9e5Decode(view.getUint32(t * bpt, true))
        : [0, 2, 4].map((k) => halfToFloat(view.getUint16(t * bpt + k, true)));
    out.set(rgb, t * 3);
  }
  return out;
}

test('sequences.json is for the protocol version this decoder speaks', () => {
  assert.equal(sequences.protocol_version, PROTOCOL_VERSION);
  assert.ok(sequences.sequences.length >= 2);
  assert.deepEqual(new Set(sequences.sequences.map((s) => s.format)), new Set(['Rgb9e5', 'Rgba16f']));
});

for (const seq of sequences.sequences) {
  const fresh = () => new Lightmap(seq.atlas_width, seq.atlas_height, seq.tile_size, seq.format);

  test(`sequence ${seq.name}: a keyframe then residual deltas, in order, end at final_texels`, () => {
    const frames = seq.frames.map((hex) => decodeServer(fromHex(hex)));
    assert.equal(frames[0].type, 'Keyframe');
    assert.ok(frames.length > 2 && frames.slice(1).every((f) => f.type === 'Delta'));
    const map = fresh();
    map.applyKeyframe(frames[0]);
    for (const delta of frames.slice(1)) {
      const indices = payloadTiles(map, delta.residual);
      const rects = map.applyDelta(delta);
      assert.deepEqual(rects, indices.map((i) => map.tileRect(i)), 'the rectangles of the tiles the bitmap sets');
      assert.equal(map.version, delta.version);
    }
    assert.equal(map.version, seq.final_version);
    assert.equal(toHex(map.bytes), seq.final_texels);
    assert.deepEqual(map.rgb, decodeAll(seq.format, map.bytes), 'the decoded cache follows the texels');
  });

  test(`sequence ${seq.name}: the keyframe then the merged delta end at final_texels`, () => {
    const keyframe = decodeServer(fromHex(seq.frames[0]));
    const merged = decodeServer(fromHex(seq.merged));
    assert.equal(merged.type, 'Delta');
    assert.equal(merged.base_version, keyframe.version);
    assert.equal(merged.version, seq.final_version);
    const map = fresh();
    map.applyKeyframe(keyframe);
    const indices = payloadTiles(map, merged.residual);
    assert.deepEqual(map.applyDelta(merged), indices.map((i) => map.tileRect(i)));
    assert.equal(map.version, seq.final_version);
    assert.equal(toHex(map.bytes), seq.final_texels);
    assert.deepEqual(map.rgb, decodeAll(seq.format, map.bytes));
  });
}

test('a surface on its own lightmap UVs is drawn with them, any other with its rect (version 3)', () => {
  const welcome = decodeServer(bin('server_welcome_uvs'));
  assert.equal(welcome.type, 'Welcome');
  const { scene } = welcome;
  const [quad, triangle] = scene.surfaces;
  assert.deepEqual(quad.uvs, []);
  const W = scene.atlas_width;
  const H = scene.atlas_height;
  // The 3x2 chart's corner texel centres.
  assert.deepEqual(cornerUvs(quad, W, H), [
    [0.5 / W, 0.5 / H],
    [2.5 / W, 0.5 / H],
    [2.5 / W, 1.5 / H],
    [0.5 / W, 1.5 / H],
  ]);
  assert.deepEqual(cornerUvs(triangle, W, H), [
    [0.25, 0.75],
    [0.75, 0.75],
    [0.5, 0.25],
    [0.5, 0.25],
  ]);
});
