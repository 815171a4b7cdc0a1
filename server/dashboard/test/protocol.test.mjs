// The JavaScript decoder against the protocol's golden vectors: the same
// files `protocol/tests/golden_vectors.rs` checks the Rust codec with. Every
// `.bin` must decode to the value in `manifest.json`, and that value must
// encode to the identical bytes. Then the lightmap: the golden keyframe and
// delta applied, texel by texel, to the values PROTOCOL.md §8 spells out,
// and the refusals §5 requires.

import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

import {
  DecodeError,
  MAX_FRAME_BYTES,
  PROTOCOL_VERSION,
  decodeClient,
  decodeServer,
  encodeClient,
  encodeServer,
  errorName,
  poseProblem,
} from '../src/protocol.js';
import { ApplyError, Lightmap, rgb9e5Decode, zstdFrameProblem } from '../src/lightmap.js';

const here = path.dirname(fileURLToPath(import.meta.url));
const vectors = path.resolve(here, '../../../protocol/tests/vectors');
const manifest = JSON.parse(fs.readFileSync(path.join(vectors, 'manifest.json'), 'utf8'));
const bin = (name) => new Uint8Array(fs.readFileSync(path.join(vectors, `${name}.bin`)));

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
  assert.throws(() => decodeServer(Uint8Array.from([6])), /unknown ServerMessage variant 6/);
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
});

test('bad tiles are refused and leave the lightmap unchanged', () => {
  const welcome = decodeServer(bin('server_welcome'));
  const keyframe = decodeServer(bin('server_keyframe'));
  const delta = decodeServer(bin('server_delta'));
  const fresh = () => {
    const map = Lightmap.forScene(welcome.scene);
    map.applyKeyframe(keyframe);
    return map;
  };
  const cases = [
    ['out of range', { ...delta, tiles: [{ ...delta.tiles[0], index: 2 }] }, /out of range/],
    ['repeated', { ...delta, tiles: [delta.tiles[0], delta.tiles[0]] }, /appears twice/],
    ['not zstd', { ...delta, tiles: [{ index: 1, data: Uint8Array.from([1, 2, 3, 4, 5, 6, 7]) }] }, /no zstd frame magic/],
    // Tile 0's payload (16 bytes) sent as tile 1 (8 bytes).
    ['wrong size', { ...delta, tiles: [{ index: 1, data: keyframe.tiles[0].data }] }, /content size 16, expected 8/],
    ['trailing', { ...delta, tiles: [{ index: 1, data: Uint8Array.from([...delta.tiles[0].data, 0]) }] }, /1 bytes after the zstd frame/],
    ['truncated', { ...delta, tiles: [{ index: 1, data: delta.tiles[0].data.subarray(0, 12) }] }, /truncated block/],
    // A valid tile 0 followed by a bad one: nothing may be written.
    ['partly bad', { ...delta, tiles: [keyframe.tiles[0], { index: 1, data: Uint8Array.from([0x28, 0xb5, 0x2f, 0xfd]) }] }, /tile 1/],
  ];
  for (const [name, bad, message] of cases) {
    const map = fresh();
    const before = Uint8Array.from(map.bytes);
    assert.throws(() => map.applyDelta(bad), (e) => e instanceof ApplyError && e.kind === 'bad-frame' && message.test(e.message), name);
    assert.deepEqual(map.bytes, before, `${name}: texels unchanged`);
    assert.equal(map.version, 1, `${name}: version unchanged`);
  }
  const map = fresh();
  assert.throws(() => map.applyDelta({ ...delta, base_version: 5, version: 6 }), (e) => e.kind === 'wrong-base');
  assert.throws(() => map.applyKeyframe({ ...keyframe, tiles: [keyframe.tiles[0]] }), /keyframe has 1 tiles, the atlas has 2/);
  assert.throws(() => new Lightmap(8193, 8193, 8, 'Rgb9e5'), /more than/);
});

test('zstd frame checks: content size must be declared and exact', () => {
  const frame = decodeServer(bin('server_delta')).tiles[0].data;
  assert.equal(zstdFrameProblem(frame, 8), null);
  const noSize = Uint8Array.from(frame);
  noSize[4] = 0x00; // no single segment, no content size: needs a window byte
  assert.match(zstdFrameProblem(noSize, 8), /does not declare its content size/);
});
