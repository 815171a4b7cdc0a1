// The 3D view's light gizmos (src/gizmos.js): pure geometry, checked
// without a browser, and where the lights' states put them.

import assert from 'node:assert/strict';
import test from 'node:test';

import {
  CONE_SIDES,
  FLOATS_PER_VERTEX,
  SPOT_LENGTH,
  SUN_LENGTH,
  gizmoColor,
  gizmoSize,
  lightGizmos,
  lightsPath,
  placedLights,
} from '../src/gizmos.js';

/** A 10 x 4 x 6 room from the origin: diagonal sqrt(152). */
const bounds = { lo: [0, 0, 0], hi: [10, 4, 6] };
const size = gizmoSize(bounds);

/** The segments of a gizmo array: [[a, b, colour], ...]. */
function segments(data) {
  assert.equal(data.length % (2 * FLOATS_PER_VERTEX), 0);
  const out = [];
  for (let i = 0; i < data.length; i += 2 * FLOATS_PER_VERTEX) {
    const v = (k) => Array.from(data.slice(i + k * FLOATS_PER_VERTEX, i + k * FLOATS_PER_VERTEX + 3));
    out.push([v(0), v(1), Array.from(data.slice(i + 3, i + 6))]);
  }
  return out;
}

const sub = (a, b) => a.map((x, i) => x - b[i]);
const len = (a) => Math.hypot(...a);
const dot = (a, b) => a.reduce((s, x, i) => s + x * b[i], 0);
const close = (a, b, eps = 1e-5) => a.every((x, i) => Math.abs(x - b[i]) <= eps);
const degrees = (a, b) => (Math.acos(Math.max(-1, Math.min(1, dot(a, b) / (len(a) * len(b))))) * 180) / Math.PI;

test('the gizmo size follows the bounds', () => {
  assert.ok(Math.abs(size - 0.04 * Math.sqrt(152)) < 1e-12);
  assert.ok(gizmoSize(undefined) > 0, 'a size without bounds');
  assert.ok(gizmoSize({ lo: [1, 1, 1], hi: [1, 1, 1] }) > 0, 'a size for a point');
});

test("a point light's cross is centred on it, one segment per axis, in its colour", () => {
  const p = [2, 3.5, 1];
  const s = segments(lightGizmos([{ name: 'bulb', type: 'point', position: p, color: [1, 0.5, 0.25], intensity: 8 }], bounds));
  assert.equal(s.length, 3);
  s.forEach(([a, b, colour], axis) => {
    assert.ok(close(a.map((x, i) => (x + b[i]) / 2), p), `centre of ${a} - ${b}`);
    const d = sub(b, a);
    assert.ok(Math.abs(len(d) - 2 * size) < 1e-5);
    assert.ok(Math.abs(Math.abs(d[axis]) - 2 * size) < 1e-5, `along axis ${axis}: ${d}`);
    assert.ok(close(colour, [1, 0.5, 0.25]));
  });
});

test("a spot's cone lines end at its outer angle from its axis, the circle joins them", () => {
  const p = [5, 3.9, 3];
  const direction = [0.3, -2, 0.1];
  const axis = direction.map((x) => x / len(direction));
  const spot = { name: 's', type: 'spot', position: p, direction, color: [0, 2, 1], intensity: 5, inner_cone_deg: 20, outer_cone_deg: 35 };
  const s = segments(lightGizmos([spot], bounds));
  assert.equal(s.length, 2 * CONE_SIDES + 1);
  const rays = s.filter(([a]) => close(a, p));
  assert.equal(rays.length, CONE_SIDES + 1, 'the cone lines and the axis start at the light');
  const [axisLine, ...cone] = [rays[rays.length - 1], ...rays.slice(0, -1)];
  for (const [, end] of cone) {
    const ray = sub(end, p);
    assert.ok(Math.abs(degrees(ray, axis) - 35) < 1e-3, `${degrees(ray, axis)} degrees from the axis`);
    assert.ok(Math.abs(len(ray) - SPOT_LENGTH * size) < 1e-4);
  }
  assert.ok(degrees(sub(axisLine[1], p), axis) < 1e-3, 'the axis line runs along the direction');
  // The circle: each end joined to the next, all as far from the axis.
  const rim = s.filter(([a]) => !close(a, p));
  assert.equal(rim.length, CONE_SIDES);
  const ends = new Set(cone.map(([, e]) => e.join()));
  for (const [a, b] of rim) assert.ok(ends.has(a.join()) && ends.has(b.join()));
  for (const [, , colour] of s) assert.ok(close(colour, [0, 1, 0.5]));
});

test("a sun's arrow points along its direction, its tip above the bounds' centre", () => {
  const direction = [0.54, -0.64, -0.54];
  const d = direction.map((x) => x / len(direction));
  const s = segments(lightGizmos([{ name: 'sun', type: 'directional', direction, color: [1, 0.95, 0.85], intensity: 700, angular_diameter_deg: 0.53 }], bounds));
  assert.equal(s.length, 5, 'a shaft and four barbs');
  const [[tail, tip], ...barbs] = s;
  assert.ok(close(tip, [5, 4 + size, 3]), `tip ${tip}`);
  assert.ok(degrees(sub(tip, tail), d) < 1e-3, 'the shaft points along the light');
  assert.ok(Math.abs(len(sub(tip, tail)) - SUN_LENGTH * size) < 1e-4);
  for (const [a, b] of barbs) {
    assert.ok(close(a, tip));
    const back = degrees(sub(b, a), d.map((x) => -x));
    assert.ok(back > 10 && back < 60, `a barb turns back from the tip: ${back} degrees`);
  }
});

test('lights that cannot be placed are left out; colours are normalised', () => {
  const bad = [
    { type: 'point' },
    { type: 'point', position: [0, NaN, 0] },
    { type: 'spot', position: [0, 1, 0], direction: [0, 0, 0], outer_cone_deg: 30 },
    { type: 'directional' },
    { type: 'area', position: [0, 1, 0] },
    null,
  ];
  assert.equal(lightGizmos(bad, bounds).length, 0);
  assert.equal(lightGizmos(undefined, bounds).length, 0);
  assert.deepEqual(gizmoColor([0, 0, 0]), [1, 1, 1]);
  assert.deepEqual(gizmoColor(undefined), [1, 1, 1]);
  assert.deepEqual(gizmoColor([2, 1, 0]), [1, 0.5, 0]);
});

test('the lights route encodes the scene id as scene.glb does', () => {
  assert.equal(lightsPath('cornell-point'), '/api/scenes/cornell-point/lights');
  assert.equal(lightsPath('a b/é'), '/api/scenes/a%20b%2F%C3%A9/lights');
});

test('placedLights puts each entry where its state has it, in its colour', () => {
  const entries = [
    { name: 'bulb', type: 'point', position: [1, 2, 3], color: [1, 1, 1], intensity: 8 },
    { name: 'spot', type: 'spot', position: [0, 1, 0], direction: [0, -1, 0], color: [1, 1, 1], intensity: 5, outer_cone_deg: 30 },
    { name: 'sun', type: 'directional', direction: [0, -1, 0], color: [1, 1, 1], intensity: 700 },
    { name: 'unknown', type: 'point', position: [4, 4, 4], color: [1, 0, 0], intensity: 1 },
  ];
  const state = (position, direction) => ({ on: true, color: [0.5, 0.25, 0], intensity: 1, position, direction });
  const states = [state([2, 2, 2], [0, 0, 1]), state([3, 1, 0], [1, 0, 0]), state([9, 9, 9], [0.6, -0.8, 0])];
  const placed = placedLights(entries, states);
  assert.deepEqual(placed[0], { ...entries[0], position: [2, 2, 2], color: [0.5, 0.25, 0] });
  assert.equal(placed[0].direction, undefined, 'a point light gets no direction');
  assert.deepEqual(placed[1].position, [3, 1, 0]);
  assert.deepEqual(placed[1].direction, [1, 0, 0]);
  assert.deepEqual(placed[2].direction, [0.6, -0.8, 0]);
  assert.equal(placed[2].position, undefined, 'a sun gets no position');
  assert.equal(placed[3], entries[3], 'no state: as the route gives it');
  assert.equal(entries[0].position[0], 1, 'the entries are not changed');
  // The gizmos follow: the bulb's cross is centred on its new position.
  const cross = lightGizmos([placed[0]], bounds);
  assert.deepEqual(Array.from(cross.slice(0, 3)).map((x, i) => x + cross[FLOATS_PER_VERTEX + i]), [4, 4, 4]);
  assert.deepEqual(placedLights(undefined, states), []);
  assert.deepEqual(placedLights(entries, undefined), entries);
});
