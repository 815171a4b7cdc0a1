// The client's lightmap (PROTOCOL.md §5): applies keyframes and deltas, the
// JavaScript twin of `protocol/src/lightmap/mod.rs` and
// `protocol/src/lightmap/residual.rs`.
//
// A lightmap holds one version, and a frame is checked completely before the
// first texel is written, so a bad frame leaves the lightmap as it was.
//
// - A keyframe carries every tile, each one zstd frame of the tile's texels:
//   every tile is checked (index in range, no repeats, one zstd frame whose
//   declared content size is exactly the tile's byte size) and decompressed
//   into a buffer of exactly that size.
// - A delta (protocol version 2) carries one `residual` payload: empty when
//   no tile changed, else one zstd frame that declares its content size,
//   holding a bitmap of the tiles it carries (`ceil(tile_count / 8)` bytes,
//   bit `i % 8` of byte `i / 8` for tile `i`) and then, in ascending tile
//   order, the residual of every tile set, each exactly the tile's size.
//   `unpackResidual` refuses a declared size above the bitmap plus the whole
//   atlas before allocating anything, a frame with trailing bytes, content
//   not exactly as long as declared, bits past the last tile, and content
//   that is not exactly the bitmap plus the tiles it sets. Each residual is
//   then added field by field onto the texels held (see `applyResidual`).
//
// Texels are kept twice: the raw little-endian words as received or
// reconstructed (for a WebGL upload as RGB9_E5 or RGBA16F, no conversion) and
// decoded linear RGB floats (for the atlas view and statistics).

import { Decompress, decompress } from './vendor/fzstd.js';

/** Largest atlas a client accepts (§7). */
export const MAX_ATLAS_TEXELS = 8192 * 8192;

/** Why a frame was not applied. `kind` is 'wrong-base' when the client must
 * send `Resync`, else the frame itself is bad. */
export class ApplyError extends Error {
  constructor(kind, message) {
    super(message);
    this.name = 'ApplyError';
    this.kind = kind;
  }
}

const BYTES_PER_TEXEL = { Rgb9e5: 4, Rgba16f: 8 };

/** RGB9E5 word to linear RGB: `mantissa * 2^(exp - 24)` (§5). */
export function rgb9e5Decode(v) {
  const scale = 2 ** ((v >>> 27) - 24);
  return [(v & 0x1ff) * scale, ((v >>> 9) & 0x1ff) * scale, ((v >>> 18) & 0x1ff) * scale];
}

/** `w`-bit two's-complement residual field from its zig-zag form `z`
 * (0, 1, 2, 3, ... -> 0, -1, 1, -2, ..., masked to `w` bits). */
function unzigzag(z, w) {
  return ((z >>> 1) ^ -(z & 1)) & ((1 << w) - 1);
}

/**
 * Applies a delta tile's residual `planes` onto `texels` (one tile's
 * little-endian texels in `format`, same length) in place, PROTOCOL.md §5.
 * Each texel field (Rgb9e5: red, green, blue mantissas of 9 bits and the
 * 5-bit exponent; Rgba16f: the four binary16 bit patterns) becomes
 * `(old + s) mod 2^w`, where `s` is the field's zig-zagged residual read from
 * byte planes of one byte per texel, row-major:
 *
 * - Rgb9e5, 4 planes: low 8 bits of red's, green's, blue's zig-zag, then
 *   `zr >> 8 | (zg >> 8) << 1 | (zb >> 8) << 2 | ze << 3`;
 * - Rgba16f, 8 planes: low bytes of R, G, B, A, then their high bytes.
 *
 * Every byte string of the tile's length is a valid residual.
 */
export function applyResidual(format, texels, planes) {
  const bpt = BYTES_PER_TEXEL[format];
  if (!bpt) throw new ApplyError('layout', `unknown pixel format ${format}`);
  if (texels.length !== planes.length || texels.length % bpt !== 0) {
    throw new RangeError(`residual of ${planes.length} bytes for ${texels.length} bytes of texels`);
  }
  const n = texels.length / bpt;
  if (format === 'Rgb9e5') {
    for (let t = 0; t < n; t++) {
      const o = t * 4;
      const v = (texels[o] | (texels[o + 1] << 8) | (texels[o + 2] << 16) | (texels[o + 3] << 24)) >>> 0;
      const high = planes[3 * n + t];
      const r = ((v & 0x1ff) + unzigzag(planes[t] | ((high & 1) << 8), 9)) & 0x1ff;
      const g = (((v >>> 9) & 0x1ff) + unzigzag(planes[n + t] | (((high >>> 1) & 1) << 8), 9)) & 0x1ff;
      const b = (((v >>> 18) & 0x1ff) + unzigzag(planes[2 * n + t] | (((high >>> 2) & 1) << 8), 9)) & 0x1ff;
      const e = ((v >>> 27) + unzigzag(high >>> 3, 5)) & 0x1f;
      const w = (r | (g << 9) | (b << 18) | (e << 27)) >>> 0;
      texels[o] = w & 0xff;
      texels[o + 1] = (w >>> 8) & 0xff;
      texels[o + 2] = (w >>> 16) & 0xff;
      texels[o + 3] = w >>> 24;
    }
  } else {
    for (let t = 0; t < n; t++) {
      for (let c = 0; c < 4; c++) {
        const o = t * 8 + c * 2;
        const h = texels[o] | (texels[o + 1] << 8);
        const z = planes[c * n + t] | (planes[(c + 4) * n + t] << 8);
        const x = (h + unzigzag(z, 16)) & 0xffff;
        texels[o] = x & 0xff;
        texels[o + 1] = x >>> 8;
      }
    }
  }
}

/** IEEE 754 binary16 to a Number. */
export function halfToFloat(h) {
  const sign = h & 0x8000 ? -1 : 1;
  const exp = (h >>> 10) & 0x1f;
  const frac = h & 0x3ff;
  if (exp === 0) return sign * frac * 2 ** -24;
  if (exp === 31) return frac ? NaN : sign * Infinity;
  return sign * (1024 + frac) * 2 ** (exp - 25);
}

/** The largest block a zstd frame may hold (RFC 8878 §3.1.1.2.4). */
const ZSTD_MAX_BLOCK = 128 * 1024;

/**
 * The frame header of `data` (RFC 8878 §3.1.1.1), read without
 * decompressing: `{ size, checksum, blocks }` (`size` is Frame_Content_Size,
 * null when the frame does not declare it; `blocks` is the offset of the
 * first block header), or `{ problem }`.
 */
function zstdHeader(data) {
  if (data.length < 6) return { problem: 'too short for a zstd frame' };
  if (data[0] !== 0x28 || data[1] !== 0xb5 || data[2] !== 0x2f || data[3] !== 0xfd) {
    return { problem: 'no zstd frame magic' };
  }
  const fhd = data[4];
  const fcsFlag = fhd >> 6;
  const singleSegment = (fhd >> 5) & 1;
  if (fhd & 0x08) return { problem: 'reserved bit set in the frame header' };
  const checksum = (fhd >> 2) & 1;
  const dictBytes = [0, 1, 2, 4][fhd & 3];
  const fcsBytes = fcsFlag === 0 ? singleSegment : [0, 2, 4, 8][fcsFlag];
  let pos = 5 + (singleSegment ? 0 : 1);
  if (pos + dictBytes + fcsBytes > data.length) return { problem: 'truncated frame header' };
  for (let i = 0; i < dictBytes; i++) {
    if (data[pos + i] !== 0) return { problem: 'the frame needs a dictionary' };
  }
  pos += dictBytes;
  if (fcsBytes === 0) return { size: null, checksum, blocks: pos };
  // Above 2^53 this loses precision but stays above every size accepted.
  let size = 0;
  for (let i = fcsBytes - 1; i >= 0; i--) size = size * 256 + data[pos + i];
  if (fcsBytes === 2) size += 256;
  return { size, checksum, blocks: pos + fcsBytes };
}

/** Walks the block headers of the frame whose header is `header`: null if
 * the blocks (and the checksum) end exactly at the end of `data`, else the
 * reason. */
function zstdBlocksProblem(data, header) {
  let pos = header.blocks;
  for (;;) {
    if (pos + 3 > data.length) return 'truncated block header';
    const word = data[pos] | (data[pos + 1] << 8) | (data[pos + 2] << 16);
    pos += 3;
    const last = word & 1;
    const type = (word >> 1) & 3;
    const blockSize = word >>> 3;
    if (type === 3) return 'reserved block type';
    if (blockSize > ZSTD_MAX_BLOCK) return `block of ${blockSize} bytes, above the ${ZSTD_MAX_BLOCK}-byte maximum`;
    pos += type === 1 ? 1 : blockSize;
    if (pos > data.length) return 'truncated block';
    if (last) break;
  }
  pos += header.checksum ? 4 : 0;
  if (pos > data.length) return 'truncated checksum';
  if (pos !== data.length) return `${data.length - pos} bytes after the zstd frame`;
  return null;
}

/**
 * Checks that `data` is exactly one zstd frame (RFC 8878 §3.1.1) that
 * declares a content size of `expected` bytes, by walking its header and
 * block headers without decompressing. Returns null if so, else the reason.
 * (The server's zstd always writes the content size; a frame without it
 * could expand without a bound known in advance, so it is refused.)
 */
export function zstdFrameProblem(data, expected) {
  const header = zstdHeader(data);
  if (header.problem) return header.problem;
  if (header.size === null) return 'the frame does not declare its content size';
  if (header.size !== expected) return `content size ${header.size}, expected ${expected}`;
  return zstdBlocksProblem(data, header);
}

/**
 * How many bytes the blocks of `data` regenerate (a frame `zstdHeader` and
 * `zstdBlocksProblem` accepted), or `limit + 1` as soon as they pass `limit`.
 *
 * fzstd decompresses into a caller's buffer without saying how much it
 * wrote, so a frame holding fewer bytes than it declares would go unnoticed.
 * This counts them instead, with fzstd's streaming decoder run on a copy of
 * the frame whose header declares no content size and a 128 KiB window (the
 * largest block): the length of every block follows from its headers and
 * sequences alone, never from the window's contents (fzstd copies a match
 * reaching past its window as zeros rather than failing), so the count is
 * exact, while the window costs 128 KiB whatever the frame declares and the
 * count stops at `limit` (a frame of a few kilobytes can regenerate
 * gigabytes). fzstd's own streaming of the original frame would be exact too
 * but shifts a window of the whole content per block, quadratic in the
 * content. The texels themselves are decompressed afterwards into a buffer
 * of the declared size. Throws fzstd's error for a corrupt frame.
 */
function zstdContentLength(data, header, limit) {
  const frame = new Uint8Array(6 + data.length - header.blocks);
  // Magic; frame header: checksum flag as in `data`, no content size, no
  // dictionary, not single segment; window descriptor 2^(10 + 7) bytes.
  frame.set([0x28, 0xb5, 0x2f, 0xfd, header.checksum << 2, 7 << 3]);
  frame.set(data.subarray(header.blocks), 6);
  let n = 0;
  const over = {};
  const stream = new Decompress((chunk) => {
    n += chunk.length;
    if (n > limit) throw over;
  });
  try {
    stream.push(frame, true);
  } catch (e) {
    if (e === over) return limit + 1;
    throw e;
  }
  return n;
}

export class Lightmap {
  /** An all-zero lightmap at version 0. Throws ApplyError('layout') for a
   * layout no well-behaved server sends. */
  constructor(width, height, tileSize, format) {
    if (!(format in BYTES_PER_TEXEL)) throw new ApplyError('layout', `unknown pixel format ${format}`);
    if (!(tileSize > 0)) throw new ApplyError('layout', 'tile size is 0');
    if (width * height > MAX_ATLAS_TEXELS) {
      throw new ApplyError('layout', `atlas ${width}x${height} has more than ${MAX_ATLAS_TEXELS} texels`);
    }
    this.width = width;
    this.height = height;
    this.tileSize = tileSize;
    this.format = format;
    this.bytesPerTexel = BYTES_PER_TEXEL[format];
    this.version = 0;
    /** Raw texels, little-endian words as on the wire. */
    this.bytes = new Uint8Array(width * height * this.bytesPerTexel);
    /** Decoded linear RGB, 3 floats per texel, row-major. */
    this.rgb = new Float32Array(width * height * 3);
    this.tilesX = Math.ceil(width / tileSize);
    this.tilesY = Math.ceil(height / tileSize);
    this.tileCount = this.tilesX * this.tilesY;
  }

  /** The lightmap of a scene announced in `Welcome`. */
  static forScene(scene) {
    return new Lightmap(scene.atlas_width, scene.atlas_height, scene.tile_size, scene.format);
  }

  /** Texel rectangle `{x, y, width, height}` of tile `index`, clipped at the border. */
  tileRect(index) {
    if (!(index >= 0 && index < this.tileCount)) return null;
    const ts = this.tileSize;
    const x = (index % this.tilesX) * ts;
    const y = Math.floor(index / this.tilesX) * ts;
    return { x, y, width: Math.min(ts, this.width - x), height: Math.min(ts, this.height - y) };
  }

  /** Linear RGB of texel (x, y). */
  texel(x, y) {
    const i = (y * this.width + x) * 3;
    return [this.rgb[i], this.rgb[i + 1], this.rgb[i + 2]];
  }

  /** Replaces every tile and takes the keyframe's version. Returns the
   * rectangles written. */
  applyKeyframe(keyframe) {
    if (keyframe.tiles.length !== this.tileCount) {
      throw new ApplyError(
        'bad-frame',
        `keyframe has ${keyframe.tiles.length} tiles, the atlas has ${this.tileCount}`,
      );
    }
    const decoded = this.decodeTiles(keyframe.tiles);
    for (const [rect, data] of decoded) this.writeTile(rect, data);
    this.version = keyframe.version;
    return decoded.map(([rect]) => rect);
  }

  /** Applies a delta onto exactly its base version: the residual of each
   * tile its payload carries is added onto the tile held (PROTOCOL.md §5).
   * The whole payload is checked and decompressed before the first texel
   * changes, so on error nothing does; an empty payload only moves the
   * version. Returns the rectangles written, in ascending tile order. Throws
   * ApplyError('wrong-base') if this lightmap is not at the delta's base (the
   * client then sends Resync), ApplyError('bad-frame') for a bad payload. */
  applyDelta(delta) {
    if (delta.base_version !== this.version) {
      throw new ApplyError(
        'wrong-base',
        `delta ${delta.base_version} -> ${delta.version} does not apply to version ${this.version}`,
      );
    }
    if (!(delta.version > delta.base_version)) {
      throw new ApplyError('bad-frame', `delta version ${delta.version} is not above its base ${delta.base_version}`);
    }
    const tiles = this.unpackResidual(delta.residual);
    for (const { rect, planes } of tiles) {
      const texels = this.readTile(rect);
      applyResidual(this.format, texels, planes);
      this.writeTile(rect, texels);
    }
    this.version = delta.version;
    return tiles.map(({ rect }) => rect);
  }

  /**
   * Reads a delta's `residual` payload without touching the lightmap: the
   * tiles it carries, ascending, as `{ index, rect, planes }` (`planes` the
   * tile's residual, exactly its size). Empty for an empty payload. Throws
   * ApplyError('bad-frame'), allocating nothing beyond the atlas's size, for
   * a payload that is not one zstd frame declaring its content size, that
   * declares more than the bitmap plus every tile, whose content is not as
   * long as declared, whose bitmap sets a bit past the last tile, or whose
   * length is not exactly the bitmap plus the tiles it sets (the checks of
   * `residual::unpack` in Rust).
   */
  unpackResidual(payload) {
    if (!(payload instanceof Uint8Array)) {
      throw new ApplyError('bad-frame', 'the delta has no residual payload');
    }
    if (payload.length === 0) return [];
    const bad = (reason) => new ApplyError('bad-frame', `the delta's residual payload ${reason}`);
    const bitmap = Math.ceil(this.tileCount / 8);
    const most = bitmap + this.bytes.length;
    const header = zstdHeader(payload);
    if (header.problem) throw bad(`is not a zstd frame: ${header.problem}`);
    if (header.size === null) throw bad('is a zstd frame that does not declare its content size');
    const declared = header.size;
    if (declared > most) throw bad(`declares ${declared} bytes; a delta of this atlas holds at most ${most}`);
    const problem = zstdBlocksProblem(payload, header);
    if (problem) throw bad(`is not a valid zstd frame: ${problem}`);
    let raw;
    try {
      const held = zstdContentLength(payload, header, declared);
      if (held > declared) throw bad(`holds more than the ${declared} bytes it declares`);
      if (held < declared) throw bad(`holds ${held} bytes but declares ${declared}`);
      raw = decompress(payload, new Uint8Array(declared));
    } catch (e) {
      if (e instanceof ApplyError) throw e;
      throw bad(`is not a valid zstd frame: ${e.message}`);
    }
    if (raw.length < bitmap) {
      throw bad(`of ${raw.length} bytes cannot hold the ${bitmap}-byte tile bitmap`);
    }
    const tiles = [];
    let at = bitmap;
    for (let byte = 0; byte < bitmap; byte++) {
      for (let bit = 0; bit < 8; bit++) {
        if (!((raw[byte] >> bit) & 1)) continue;
        const index = byte * 8 + bit;
        if (index >= this.tileCount) {
          throw bad(`sets tile ${index} in its bitmap; the atlas has ${this.tileCount} tiles`);
        }
        const rect = this.tileRect(index);
        const len = rect.width * rect.height * this.bytesPerTexel;
        if (at + len > raw.length) {
          throw bad(`ends inside tile ${index} (${raw.length} bytes, ${len} needed from byte ${at})`);
        }
        tiles.push({ index, rect, planes: raw.subarray(at, at + len) });
        at += len;
      }
    }
    if (at !== raw.length) {
      throw bad(`has ${raw.length - at} bytes left over after the tiles its bitmap sets`);
    }
    return tiles;
  }

  /** Checks and decompresses every keyframe tile without touching the
   * lightmap. */
  decodeTiles(tiles) {
    const seen = new Uint8Array(this.tileCount);
    for (const t of tiles) {
      if (!(t.index < this.tileCount)) {
        throw new ApplyError('bad-frame', `tile ${t.index} is out of range (${this.tileCount} tiles)`);
      }
      if (seen[t.index]) throw new ApplyError('bad-frame', `tile ${t.index} appears twice`);
      seen[t.index] = 1;
    }
    return tiles.map((t) => {
      const rect = this.tileRect(t.index);
      const expected = rect.width * rect.height * this.bytesPerTexel;
      const problem = zstdFrameProblem(t.data, expected);
      if (problem) throw new ApplyError('bad-frame', `tile ${t.index}: ${problem}`);
      const out = new Uint8Array(expected);
      try {
        decompress(t.data, out);
      } catch (e) {
        throw new ApplyError('bad-frame', `tile ${t.index} is not a valid zstd frame: ${e.message}`);
      }
      return [rect, out];
    });
  }

  /** A copy of the texels of `rect`, row-major, as on the wire. */
  readTile(rect) {
    const bpt = this.bytesPerTexel;
    const rowBytes = rect.width * bpt;
    const out = new Uint8Array(rect.height * rowBytes);
    for (let row = 0; row < rect.height; row++) {
      const src = ((rect.y + row) * this.width + rect.x) * bpt;
      out.set(this.bytes.subarray(src, src + rowBytes), row * rowBytes);
    }
    return out;
  }

  /** Writes a tile's texels (row-major, as on the wire) and their decoded
   * linear RGB. */
  writeTile(rect, data) {
    const bpt = this.bytesPerTexel;
    const view = new DataView(data.buffer, data.byteOffset, data.byteLength);
    for (let row = 0; row < rect.height; row++) {
      const y = rect.y + row;
      const src = row * rect.width * bpt;
      this.bytes.set(data.subarray(src, src + rect.width * bpt), (y * this.width + rect.x) * bpt);
      for (let col = 0; col < rect.width; col++) {
        const o = (y * this.width + rect.x + col) * 3;
        const s = src + col * bpt;
        let rgb;
        if (this.format === 'Rgb9e5') {
          rgb = rgb9e5Decode(view.getUint32(s, true));
        } else {
          rgb = [0, 2, 4].map((k) => halfToFloat(view.getUint16(s + k, true)));
        }
        this.rgb[o] = rgb[0];
        this.rgb[o + 1] = rgb[1];
        this.rgb[o + 2] = rgb[2];
      }
    }
  }
}
