// The sun's path through a day (src/gizmos.js: sunPath, sunDirection,
// sunHour, timeOfDay), the Lights panel's time-of-day slider: pure
// geometry, checked without a browser.

import assert from 'node:assert/strict';
import test from 'node:test';

import { SUNRISE, SUNSET, SUN_DEFAULT_ELEVATION, sunDirection, sunElevation, sunHour, sunPath, timeOfDay } from '../src/gizmos.js';

const len = (a) => Math.hypot(...a);
const unit = (a) => a.map((x) => x / len(a));
const close = (a, b, eps = 1e-9) => a.every((x, i) => Math.abs(x - b[i]) <= eps);
/** The sun's elevation (radians) for a light travelling along `d`. */
const elevation = (d) => Math.asin(-d[1]);
/** The azimuth (radians, from +x towards +z) of the sun for a light along `d`. */
const azimuth = (d) => Math.atan2(-d[2], -d[0]);
const angleBetween = (a, b) => Math.acos(Math.max(-1, Math.min(1, a.reduce((s, x, i) => s + x * b[i], 0))));

// courtyard.json's sun.
const noon = unit([0.54, -0.64, -0.54]);
const path = sunPath(noon);

test("at noon the sun stands where the scene file puts it", () => {
  assert.ok(close(sunDirection(path, 12), noon), `${sunDirection(path, 12)} vs ${noon}`);
  assert.ok(Math.abs(path.peak - elevation(noon)) < 1e-12);
  assert.equal(sunHour(path, noon), 12);
});

test('every direction is a unit vector', () => {
  for (let hour = 0; hour <= 24; hour += 0.25) {
    assert.ok(Math.abs(len(sunDirection(path, hour)) - 1) < 1e-12, `at ${hour} h`);
  }
});

test('the sun rises 90 degrees before its noon azimuth and sets 90 degrees after', () => {
  for (const [hour, turn] of [
    [SUNRISE, -Math.PI / 2],
    [SUNSET, Math.PI / 2],
  ]) {
    const d = sunDirection(path, hour);
    assert.ok(Math.abs(d[1]) < 1e-12, `on the horizon at ${hour} h: ${d}`);
    assert.ok(Math.abs(angleBetween([Math.cos(azimuth(d)), Math.sin(azimuth(d))], [Math.cos(path.azimuth + turn), Math.sin(path.azimuth + turn)])) < 1e-9);
  }
  // Clockwise seen from above: 9:00 is between sunrise and noon.
  const nine = azimuth(sunDirection(path, 9));
  assert.ok(Math.abs(nine - (path.azimuth - Math.PI / 4)) < 1e-9, `${nine}`);
});

test('the elevation follows a sine, highest at noon, symmetric about it', () => {
  assert.ok(Math.abs(sunElevation(path, 12) - path.peak) < 1e-12);
  for (const h of [7, 8.5, 10, 11.75]) {
    const morning = elevation(sunDirection(path, h));
    const afternoon = elevation(sunDirection(path, 24 - h));
    assert.ok(Math.abs(morning - afternoon) < 1e-9, `${h} h and ${24 - h} h`);
    assert.ok(Math.abs(morning - path.peak * Math.sin((Math.PI * (h - 6)) / 12)) < 1e-9);
    assert.ok(morning > 0 && morning < path.peak);
  }
  assert.ok(sunElevation(path, 0) < 0 && sunElevation(path, 21) < 0, 'night is below the horizon');
});

test('at night the direction is clamped to the horizon, still turning', () => {
  for (const hour of [0, 3, 5.9, 18.1, 23]) {
    const d = sunDirection(path, hour);
    assert.ok(d[1] === 0 || Object.is(d[1], -0), `horizontal at ${hour} h: ${d}`);
    assert.ok(Math.abs(sunHour(path, d) - hour) < 1e-9, `${sunHour(path, d)} vs ${hour}`);
  }
});

test('sunHour inverts sunDirection through the whole day', () => {
  for (let hour = 0; hour < 24; hour += 0.25) {
    assert.ok(Math.abs(sunHour(path, sunDirection(path, hour)) - hour) < 1e-9, `${hour} h`);
  }
});

test('a sun that starts below the horizon or at the zenith still has a day', () => {
  const under = sunPath([0, 0.6, 0.8]);
  assert.equal(under.peak, SUN_DEFAULT_ELEVATION);
  assert.ok(Math.abs(elevation(sunDirection(under, 12)) - SUN_DEFAULT_ELEVATION) < 1e-12);
  const zenith = sunPath([0, -1, 0]);
  assert.equal(zenith.azimuth, 0);
  assert.ok(Math.abs(zenith.peak - Math.PI / 2) < 1e-12);
  assert.ok(close(sunDirection(zenith, 12), [0, -1, 0], 1e-12));
  assert.equal(sunHour(zenith, [0, -1, 0]), 12);
});

test('timeOfDay switches the sun off as it sets and on as it rises, else keeps the on box', () => {
  const state = { on: true, color: [1, 0.95, 0.85], intensity: 700, position: [0, 0, 0], direction: noon };
  const evening = timeOfDay(path, 17, state);
  assert.equal(evening.on, true);
  assert.equal(evening.intensity, 700, 'the rest of the state is kept');
  assert.deepEqual(evening.color, state.color);
  const night = timeOfDay(path, 20, evening);
  assert.equal(night.on, false, 'set');
  assert.ok(close(night.direction, sunDirection(path, 20)));
  assert.equal(timeOfDay(path, 2, night).on, false, 'still night');
  assert.equal(timeOfDay(path, 7, night).on, true, 'risen');
  // Switched off by hand during the day, the sun stays off as it moves.
  assert.equal(timeOfDay(path, 15, { ...state, on: false }).on, false);
  // Switched on by hand at night, it stays on until it sets again.
  assert.equal(timeOfDay(path, 3, { ...night, on: true }).on, true);
});
