// The tone curve: linear HDR radiosity to 8-bit sRGB. The JavaScript twin
// of `protocol/src/tone.rs`, which documents the curve and which
// `lightwire bake`'s PNGs and the client's renderer use; both are checked
// against the same vectors (`protocol/tests/vectors/tone.json`, see
// `test/tone.test.mjs`). In short:
//
// 1. white point w: the 95th percentile (index floor(n * 95 / 100) of the
//    ascending order) of the Rec. 709 luminance of the n covered texels
//    (luminance > 0), computed in f32 as Rust does; 1 without light; at
//    least MIN_WHITE;
// 2. exposure k = 1 / w, which the page scales by its slider (2^EV);
// 3. y = 1 - exp(-max(B, 0) * k) per channel;
// 4. round(255 * sRGB(clamp(y, 0, 1))).
//
// `toneByte` is the curve as written; `ToneTable` gives the same bytes
// without `exp` or `pow` per texel (the atlas view draws up to millions of
// them per frame). The 3D view's WebGL shader (view3d.js) is the GPU twin.

const f32 = Math.fround;

/** The percentile of covered texels' luminance that becomes the white point. */
export const WHITE_PERCENTILE = 95;

/** The smallest white point (Rust's `1e-12_f32`). */
export const MIN_WHITE = f32(1e-12);

const WR = f32(0.2126);
const WG = f32(0.7152);
const WB = f32(0.0722);

/** Rec. 709 luminance, rounded to f32 after every operation exactly as the
 * Rust `f32` expression `0.2126 * r + 0.7152 * g + 0.0722 * b` is. */
export function luminance(r, g, b) {
  return f32(f32(f32(WR * f32(r)) + f32(WG * f32(g))) + f32(WB * f32(b)));
}

/** The k-th smallest value of `a` (0-based), reordering `a` (quickselect). */
function select(a, k) {
  let lo = 0;
  let hi = a.length - 1;
  while (hi > lo) {
    // Median of three as the pivot, then Hoare partition.
    const mid = (lo + hi) >>> 1;
    const x = a[lo];
    const y = a[mid];
    const z = a[hi];
    const pivot = x < y ? (y < z ? y : x < z ? z : x) : x < z ? x : y < z ? z : y;
    let i = lo;
    let j = hi;
    while (i <= j) {
      while (a[i] < pivot) i++;
      while (a[j] > pivot) j--;
      if (i <= j) {
        const t = a[i];
        a[i] = a[j];
        a[j] = t;
        i++;
        j--;
      }
    }
    if (k <= j) hi = j;
    else if (k >= i) lo = i;
    else return a[k];
  }
  return a[k];
}

/** The white point of interleaved linear RGB (`[r, g, b, r, g, b, ...]`,
 * e.g. `Lightmap.rgb`): the WHITE_PERCENTILE-th percentile of covered
 * texels' luminance, 1 for none; an f32 value, equal to Rust's. */
export function whitePoint(rgb) {
  const lum = new Float32Array(Math.floor(rgb.length / 3));
  let n = 0;
  for (let i = 0; i + 2 < rgb.length; i += 3) {
    const l = luminance(rgb[i], rgb[i + 1], rgb[i + 2]);
    if (l > 0) lum[n++] = l; // NaN is not > 0
  }
  if (n === 0) return 1;
  const v = select(lum.subarray(0, n), Math.floor((n * WHITE_PERCENTILE) / 100));
  return Math.max(v, MIN_WHITE);
}

/** The exposure that puts `white` at the curve's white point: 1 / white (f32). */
export function exposureFor(white) {
  return f32(1 / Math.max(white, MIN_WHITE));
}

/** The sRGB transfer function (IEC 61966-2-1) of a value in [0, 1]. */
export function srgbEncode(y) {
  return y <= 0.0031308 ? 12.92 * y : 1.055 * y ** (1 / 2.4) - 0.055;
}

/** Its inverse, for values in [0, 1]. */
function srgbDecode(s) {
  return s <= 0.04045 ? s / 12.92 : ((s + 0.055) / 1.055) ** 2.4;
}

/** One channel of radiosity to its 8-bit sRGB value at `exposure`
 * (negative and NaN radiosity count as 0). */
export function toneByte(b, exposure) {
  const x = b > 0 ? b : 0;
  const y = 1 - Math.exp(-x * exposure);
  const s = srgbEncode(Math.min(1, Math.max(0, y)));
  return Math.round(Math.min(1, Math.max(0, s)) * 255);
}

/** The curve at one exposure as 255 thresholds in radiosity: a channel's
 * byte is the number of thresholds at or below it, which is `toneByte`'s
 * value (byte >= k exactly when the unrounded 255 * sRGB(y) >= k - 0.5). */
export class ToneTable {
  constructor(exposure) {
    this.exposure = exposure;
    /** thresholds[k - 1]: the least radiosity whose byte is at least k. */
    this.thresholds = new Float64Array(255);
    for (let k = 1; k <= 255; k++) {
      const y = srgbDecode((k - 0.5) / 255);
      this.thresholds[k - 1] = -Math.log1p(-y) / exposure;
    }
  }

  /** `toneByte(b, this.exposure)` by binary search: 8 comparisons. */
  byte(b) {
    const t = this.thresholds;
    let lo = 0; // t[0..lo) are <= b
    let hi = 255; // t[hi..) are > b (or b is NaN)
    while (lo < hi) {
      const mid = (lo + hi) >>> 1;
      if (b >= t[mid]) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }
}
