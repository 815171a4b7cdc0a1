// The client's lightmap (PROTOCOL.md §5): applies keyframes and deltas tile
// by tile, the JavaScript twin of `protocol/src/lightmap/mod.rs`.
//
// A lightmap holds one version. Every tile of a frame is checked (index in
// range, no repeats, one zstd frame whose declared content size is exactly
// the tile's byte size) and decompressed into a buffer of exactly that size
// before the first texel is written, so a bad frame leaves the lightmap as it
// was. Texels are kept twice: the raw little-endian words as received (for a
// WebGL upload as RGB9_E5 or RGBA16F, no conversion) and decoded linear RGB
// floats (for the atlas view and statistics).

import { decompress } from './vendor/fzstd.js';

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

/** IEEE 754 binary16 to a Number. */
export function halfToFloat(h) {
  const sign = h & 0x8000 ? -1 : 1;
  const exp = (h >>> 10) & 0x1f;
  const frac = h & 0x3ff;
  if (exp === 0) return sign * frac * 2 ** -24;
  if (exp === 31) return frac ? NaN : sign * Infinity;
  return sign * (1024 + frac) * 2 ** (exp - 25);
}

/**
 * Checks that `data` is exactly one zstd frame (RFC 8878 §3.1.1) that
 * declares a content size of `expected` bytes, by walking its header and
 * block headers without decompressing. Returns null if so, else the reason.
 * (The server's zstd always writes the content size; a frame without it
 * could expand without a bound known in advance, so it is refused.)
 */
export function zstdFrameProblem(data, expected) {
  if (data.length < 6) return 'too short for a zstd frame';
  if (data[0] !== 0x28 || data[1] !== 0xb5 || data[2] !== 0x2f || data[3] !== 0xfd) {
    return 'no zstd frame magic';
  }
  const fhd = data[4];
  const fcsFlag = fhd >> 6;
  const singleSegment = (fhd >> 5) & 1;
  if (fhd & 0x08) return 'reserved bit set in the frame header';
  const checksum = (fhd >> 2) & 1;
  const dictBytes = [0, 1, 2, 4][fhd & 3];
  const fcsBytes = fcsFlag === 0 ? singleSegment : [0, 2, 4, 8][fcsFlag];
  let pos = 5 + (singleSegment ? 0 : 1);
  if (pos + dictBytes + fcsBytes > data.length) return 'truncated frame header';
  for (let i = 0; i < dictBytes; i++) {
    if (data[pos + i] !== 0) return 'the frame needs a dictionary';
  }
  pos += dictBytes;
  if (fcsBytes === 0) return 'the frame does not declare its content size';
  let size = 0;
  for (let i = fcsBytes - 1; i >= 0; i--) size = size * 256 + data[pos + i];
  if (fcsBytes === 2) size += 256;
  pos += fcsBytes;
  if (size !== expected) return `content size ${size}, expected ${expected}`;
  for (;;) {
    if (pos + 3 > data.length) return 'truncated block header';
    const header = data[pos] | (data[pos + 1] << 8) | (data[pos + 2] << 16);
    pos += 3;
    const last = header & 1;
    const type = (header >> 1) & 3;
    const blockSize = header >>> 3;
    if (type === 3) return 'reserved block type';
    pos += type === 1 ? 1 : blockSize;
    if (pos > data.length) return 'truncated block';
    if (last) break;
  }
  pos += checksum ? 4 : 0;
  if (pos > data.length) return 'truncated checksum';
  if (pos !== data.length) return `${data.length - pos} bytes after the zstd frame`;
  return null;
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

  /** Applies a delta onto exactly its base version; returns the rectangles
   * written. Throws ApplyError('wrong-base') if this lightmap is not at the
   * delta's base (the client then sends Resync). */
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
    const decoded = this.decodeTiles(delta.tiles);
    for (const [rect, data] of decoded) this.writeTile(rect, data);
    this.version = delta.version;
    return decoded.map(([rect]) => rect);
  }

  /** Checks and decompresses every tile without touching the lightmap. */
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
