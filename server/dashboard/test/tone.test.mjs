// The dashboard's tone curve (src/tone.js) against the shared vectors in
// protocol/tests/vectors/tone.json, which `protocol/tests/tone.rs` checks
// the Rust curve (bake's PNGs, the client's renderer) with: both must give
// the same white points and the same bytes.

import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

import { MIN_WHITE, ToneTable, exposureFor, luminance, srgbEncode, toneByte, whitePoint } from '../src/tone.js';

const here = path.dirname(fileURLToPath(import.meta.url));
const vectors = JSON.parse(fs.readFileSync(path.resolve(here, '../../../protocol/tests/vectors/tone.json'), 'utf8'));
const f32 = Math.fround;

/** Texels of a vector as the interleaved Float32Array a Lightmap holds. */
const interleaved = (texels) => Float32Array.from(texels.flat());

test('white points match the shared vectors', () => {
  assert.ok(vectors.white_points.length >= 10);
  for (const { name, texels, white } of vectors.white_points) {
    const got = whitePoint(interleaved(texels));
    assert.equal(got, f32(white), name);
    assert.equal(f32(got), got, `${name}: an f32 value`);
  }
});

test('pixels match the shared vectors, by the formula and by the table', () => {
  assert.ok(vectors.pixels.length >= 30);
  for (const { rgb, exposure, bytes } of vectors.pixels) {
    const k = f32(exposure);
    const table = new ToneTable(k);
    const what = JSON.stringify({ rgb, exposure });
    assert.deepEqual(rgb.map((b) => toneByte(f32(b), k)), bytes, `${what} (toneByte)`);
    assert.deepEqual(rgb.map((b) => table.byte(f32(b))), bytes, `${what} (ToneTable)`);
  }
});

test('images match the shared vectors: white point, then bytes at 1 / white', () => {
  assert.ok(vectors.images.length >= 1);
  for (const { name, width, height, texels, white, bytes } of vectors.images) {
    assert.equal(texels.length, width * height, `${name}: size`);
    const rgb = interleaved(texels);
    const w = whitePoint(rgb);
    assert.equal(w, f32(white), `${name}: white point`);
    const table = new ToneTable(exposureFor(w));
    assert.deepEqual(Array.from(rgb, (b) => toneByte(b, exposureFor(w))), bytes, `${name}: toneByte`);
    assert.deepEqual(Array.from(rgb, (b) => table.byte(b)), bytes, `${name}: ToneTable`);
  }
});

test('the table gives the formula\'s byte over the whole range, at several exposures', () => {
  for (const exposure of [1e-3, 0.37, 1, 2 ** 6, 1e4]) {
    const table = new ToneTable(exposure);
    for (let e = -24; e <= 16; e += 1 / 64) {
      const b = f32((2 ** e) / exposure);
      assert.equal(table.byte(b), toneByte(b, exposure), `${b} at exposure ${exposure}`);
    }
    for (const b of [0, -0, -1, -Infinity, NaN, Infinity]) {
      assert.equal(table.byte(b), toneByte(b, exposure), `${b} at exposure ${exposure}`);
    }
  }
  assert.equal(toneByte(NaN, 1), 0);
  assert.equal(toneByte(-5, 1), 0);
  assert.equal(toneByte(Infinity, 1), 255);
});

test('the white point is the exact percentile, not an approximation', () => {
  // Many random texels, half of them uncovered: against a plain sort.
  let seed = 12345;
  const random = () => {
    seed = (seed * 1103515245 + 12345) % 2 ** 31;
    return seed / 2 ** 31;
  };
  for (const n of [1, 2, 19, 20, 21, 100, 1001, 4096]) {
    const rgb = new Float32Array(n * 3);
    for (let i = 0; i < rgb.length; i++) rgb[i] = random() < 0.5 ? 0 : 10 ** (random() * 8 - 4);
    const lum = [];
    for (let i = 0; i < rgb.length; i += 3) lum.push(luminance(rgb[i], rgb[i + 1], rgb[i + 2]));
    const covered = lum.filter((l) => l > 0).sort((a, b) => a - b);
    const want = covered.length ? Math.max(covered[Math.floor((covered.length * 95) / 100)], MIN_WHITE) : 1;
    assert.equal(whitePoint(rgb), want, `${n} texels`);
  }
  // Repeated values (the partition's equal-to-pivot case).
  assert.equal(whitePoint(Float32Array.from({ length: 300 }, (_, i) => [1, 2, 2][i % 3])), luminance(1, 2, 2));
  assert.equal(whitePoint(new Float32Array(0)), 1);
});

test('sRGB encoding', () => {
  assert.equal(srgbEncode(0), 0);
  assert.ok(Math.abs(srgbEncode(1) - 1) < 1e-12);
  assert.ok(Math.abs(srgbEncode(0.0031308) - 0.04045) < 1e-5);
});
