// What the Lights panel's sliders are anchored on (src/gizmos.js:
// lightAnchor): the scene file's state from the lights route's `file`, so
// that two pages that connected before and after a driver moved and dimmed
// the sun give the same hour the same direction and the same stop the
// same intensity; the Welcome's state where the route gives none (a
// relay). Pure, checked without a browser.

import assert from 'node:assert/strict';
import test from 'node:test';

import { SUN_DEFAULT_ELEVATION, lightAnchor, sunDirection, sunHour, sunPath } from '../src/gizmos.js';

const len = (a) => Math.hypot(...a);
const unit = (a) => a.map((x) => x / len(a));
const close = (a, b, eps = 1e-9) => a.every((x, i) => Math.abs(x - b[i]) <= eps);

// courtyard.json's sun, as the scene file puts it.
const fileDirection = unit([0.54, -0.64, -0.54]);
const fileState = { on: true, color: [1, 0.95, 0.85], intensity: 700, position: [0, 0, 0], direction: fileDirection };
/** The same sun after a driver moved it to late afternoon and dimmed it. */
const movedState = { ...fileState, intensity: 175, direction: sunDirection(sunPath(fileDirection), 16.5) };

const sunInfo = (state) => ({ name: 'sun', kind: 'Directional', state });
/** The lights route's entry of the moved sun, with the file's state. */
const sunEntry = {
  name: 'sun',
  type: 'directional',
  direction: movedState.direction,
  color: [1, 0.95, 0.85],
  intensity: 175,
  angular_diameter_deg: 0.53,
  on: true,
  seq: 4,
  file: { on: true, color: [1, 0.95, 0.85], intensity: 700, direction: fileDirection },
};

test('a page that connects after the sun was moved anchors on the scene file, as an early page does', () => {
  const early = lightAnchor(sunInfo(fileState), undefined); // welcomed before the move
  const late = lightAnchor(sunInfo(movedState), sunEntry); // welcomed after it, route answered
  assert.equal(early.fromFile, false);
  assert.equal(late.fromFile, true);
  assert.equal(late.reference, 700, 'the intensity slider counts stops from the file intensity');
  assert.equal(early.reference, late.reference);
  for (const hour of [6, 9, 12, 16.5, 20]) {
    assert.ok(close(sunDirection(late.path, hour), sunDirection(early.path, hour)), `at ${hour} h`);
  }
  // Noon is the file's sun, and the moved sun shows as half past four.
  assert.ok(close(sunDirection(late.path, 12), fileDirection));
  assert.ok(Math.abs(sunHour(late.path, movedState.direction) - 16.5) < 1e-9);
});

test("without the route's file state (a relay), the Welcome's state is the anchor", () => {
  const anchor = lightAnchor(sunInfo(movedState), undefined);
  assert.equal(anchor.fromFile, false);
  assert.equal(anchor.reference, 175);
  assert.ok(close(sunDirection(anchor.path, 12), movedState.direction));
  // An entry of an older solver, without `file`, is the same.
  const { file: _, ...older } = sunEntry;
  assert.deepEqual(lightAnchor(sunInfo(movedState), older), anchor);
});

test('an entry of another light, or a file state without a direction for a sun, is not used', () => {
  assert.equal(lightAnchor(sunInfo(movedState), { ...sunEntry, name: 'moon' }).fromFile, false);
  const broken = { ...sunEntry, file: { ...sunEntry.file, direction: [0, 0, 0] } };
  assert.equal(lightAnchor(sunInfo(movedState), broken).fromFile, false);
  const noIntensity = { ...sunEntry, file: { ...sunEntry.file, intensity: null } };
  assert.equal(lightAnchor(sunInfo(movedState), noIntensity).reference, 175);
});

test('a point light has no day path; a black light in the file counts stops from 1', () => {
  const bulb = { name: 'bulb', kind: 'Point', state: { on: true, color: [1, 1, 1], intensity: 2, position: [1, 2, 3], direction: [0, -1, 0] } };
  const entry = { name: 'bulb', type: 'point', position: [1, 2, 3], color: [1, 1, 1], intensity: 2, on: true, seq: 1, file: { on: true, color: [1, 1, 1], intensity: 8, position: [2, 2, 2] } };
  assert.deepEqual(lightAnchor(bulb, entry), { reference: 8, path: null, fromFile: true });
  const black = { ...entry, file: { on: false, color: [1, 1, 1], intensity: 0, position: [2, 2, 2] } };
  assert.deepEqual(lightAnchor(bulb, black), { reference: 1, path: null, fromFile: true });
});

test("a sun that the file puts below the horizon keeps the default noon elevation", () => {
  const below = { ...sunEntry, file: { ...sunEntry.file, direction: [0, 1, 0] } };
  assert.equal(lightAnchor(sunInfo(movedState), below).path.peak, SUN_DEFAULT_ELEVATION);
});
