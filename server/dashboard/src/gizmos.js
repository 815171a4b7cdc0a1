// The geometry of the scene's lights, for the 3D view and the Lights
// panel. Pure, no WebGL or DOM, so that node checks it
// (test/gizmos.test.mjs, test/sun.test.mjs).
//
// Gizmos: the scene's point, spot and directional lights as line segments,
// which view3d.js draws with gl.LINES after the surfaces. What kind of
// light each is, and a spot's cone, come from `GET /api/scenes/{id}/lights`
// (a solver's route: the scene file's `"lights"`, every direction unit,
// cones in degrees; a relay lists none); where each light is, which way it
// points and its colour come from its current state (`placedLights`: the
// latest `Lights`, or this page's own change), so a gizmo follows a light
// that is moved, turned or recoloured.
//
// - point: a cross of three axis-aligned segments centred on the light;
// - spot: CONE_SIDES lines from the light along its outer cone, each
//   `size * SPOT_LENGTH` long, the circle joining their ends, and the axis
//   to that circle's centre;
// - directional (a sun, which has no position): an arrow along its
//   direction whose tip is `size` above the centre of the top of the scene's
//   bounds, with four barbs.
//
// `size` is GIZMO_SCALE of the bounds' diagonal, so gizmos read alike in a
// box and in a level. Each light's lines are in its colour, normalised to
// its largest channel (white for a black one).
//
// The sun through a day (`sunPath`, `sunDirection`, `sunHour`,
// `timeOfDay`): the Lights panel's time-of-day slider, described below;
// `lightAnchor`: what that slider and the intensity slider are anchored on.

import { sceneGlbPath } from './protocol.js';

/** Lines along a spot's outer cone (and segments of the circle). */
export const CONE_SIDES = 12;
/** A gizmo's size as a share of the scene bounds' diagonal. */
export const GIZMO_SCALE = 0.04;
/** A spot's cone lines, in gizmo sizes. */
export const SPOT_LENGTH = 3;
/** A sun's arrow, in gizmo sizes. */
export const SUN_LENGTH = 4;
/** Floats per vertex: position, then colour. */
export const FLOATS_PER_VERTEX = 6;

/** The sun's highest elevation when the scene's sun is not above the
 * horizon to start with (its state gives no noon to follow), radians. */
export const SUN_DEFAULT_ELEVATION = Math.PI / 3;
/** The hours of sunrise and sunset. */
export const SUNRISE = 6;
export const SUNSET = 18;

/** `GET /api/scenes/{id}/lights`, the id encoded as `sceneGlbPath` does. */
export function lightsPath(id) {
  return sceneGlbPath(id).replace(/scene\.glb$/, 'lights');
}

const finite3 = (v) => Array.isArray(v) && v.length === 3 && v.every(Number.isFinite);
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const unit = (a) => {
  const n = Math.hypot(...a);
  return n > 1e-9 ? scale(a, 1 / n) : null;
};

/** A light's colour with its largest channel 1; white if it has none. */
export function gizmoColor(color) {
  if (!finite3(color)) return [1, 1, 1];
  const peak = Math.max(...color);
  return peak > 0 ? color.map((c) => Math.max(c, 0) / peak) : [1, 1, 1];
}

/** A gizmo's size for the static geometry's box `bounds` ({lo, hi}). */
export function gizmoSize(bounds) {
  const d = bounds ? Math.hypot(...bounds.hi.map((h, a) => h - bounds.lo[a])) : NaN;
  return Number.isFinite(d) && d > 0 ? GIZMO_SCALE * d : GIZMO_SCALE;
}

/** Two unit vectors perpendicular to unit `d` and to each other. */
function basis(d) {
  const u = unit(cross(d, Math.abs(d[1]) < 0.9 ? [0, 1, 0] : [1, 0, 0]));
  return [u, cross(d, u)];
}

/**
 * The lights route's `entries` where `states` (LightStates in SceneInfo
 * order, which is the route's too: both list the scene file's lights in
 * its order) put them: each entry with its state's colour, and its
 * state's position and direction where the entry has one (a point light
 * has no direction to draw, a sun no position). An entry without a state
 * is left as the route gives it.
 */
export function placedLights(entries, states) {
  return (entries ?? []).map((entry, i) => {
    const state = states?.[i];
    if (!entry || !state) return entry;
    const placed = { ...entry, color: state.color };
    if (entry.position) placed.position = state.position;
    if (entry.direction) placed.direction = state.direction;
    return placed;
  });
}

/**
 * The gizmos of `lights` (entries of the lights route) in a scene whose
 * static geometry spans `bounds` ({lo, hi}): a Float32Array of segments,
 * two vertices each, every vertex [x, y, z, r, g, b]. A light whose
 * position or direction is missing, not finite or of no length is left
 * out.
 */
export function lightGizmos(lights, bounds) {
  const size = gizmoSize(bounds);
  const out = [];
  for (const light of lights ?? []) {
    const rgb = gizmoColor(light?.color);
    const line = (a, b) => out.push(...a, ...rgb, ...b, ...rgb);
    const type = light?.type;
    if (type === 'point' || type === 'spot') {
      const p = light.position;
      if (!finite3(p)) continue;
      if (type === 'point') {
        for (const axis of [
          [1, 0, 0],
          [0, 1, 0],
          [0, 0, 1],
        ]) {
          line(add(p, scale(axis, -size)), add(p, scale(axis, size)));
        }
        continue;
      }
      const d = finite3(light.direction) ? unit(light.direction) : null;
      const outer = ((Number.isFinite(light.outer_cone_deg) ? light.outer_cone_deg : 45) * Math.PI) / 180;
      if (!d) continue;
      const [u, v] = basis(d);
      const length = SPOT_LENGTH * size;
      const centre = add(p, scale(d, length * Math.cos(outer)));
      const rim = [];
      for (let k = 0; k < CONE_SIDES; k++) {
        const phi = (2 * Math.PI * k) / CONE_SIDES;
        const across = add(scale(u, Math.cos(phi)), scale(v, Math.sin(phi)));
        rim.push(add(centre, scale(across, length * Math.sin(outer))));
      }
      rim.forEach((end, k) => {
        line(p, end);
        line(end, rim[(k + 1) % CONE_SIDES]);
      });
      line(p, centre);
    } else if (type === 'directional') {
      const d = finite3(light.direction) ? unit(light.direction) : null;
      if (!d) continue;
      const lo = bounds?.lo ?? [-1, -1, -1];
      const hi = bounds?.hi ?? [1, 1, 1];
      const tip = [(lo[0] + hi[0]) / 2, hi[1] + size, (lo[2] + hi[2]) / 2];
      const length = SUN_LENGTH * size;
      line(add(tip, scale(d, -length)), tip);
      const [u, v] = basis(d);
      const back = add(tip, scale(d, -0.3 * length));
      for (const side of [u, v, scale(u, -1), scale(v, -1)]) line(tip, add(back, scale(side, 0.15 * length)));
    }
  }
  return new Float32Array(out);
}

// --- The sun through a day ---------------------------------------------------
//
// A directional light's time-of-day slider moves it along a day's path
// built around the scene file's sun (`lightAnchor`), which stands where it
// is at noon:
//
// - its azimuth (measured about +y from +x towards +z, clockwise seen from
//   above) turns 15 degrees an hour through the whole day, the noon sun's
//   azimuth at 12:00, so the sun rises 90 degrees before it (at 6:00, in
//   the "east") and sets 90 degrees after it (at 18:00, in the "west"),
//   as on an equinox; the scene's own axes decide where east is;
// - its elevation is `peak * sin(pi * (hour - 6) / 12)`: 0 at sunrise and
//   sunset, `peak` at noon (the scene file's sun's elevation, or
//   SUN_DEFAULT_ELEVATION when that sun is not above the horizon), below
//   0 at night, lowest at midnight.
//
// Below the horizon the sun has nothing to light from above: its
// direction is clamped to the horizon (elevation 0, still on the path's
// azimuth) and `timeOfDay` switches the light off as the sun sets and on
// again as it rises. Between those, the Lights panel's on box decides.

const RADIANS_PER_HOUR = Math.PI / 12; // 15 degrees an hour

/**
 * The day's path around a sun that at noon sends its light along the
 * unit `direction` (the scene file's state): `{ azimuth, peak }`, radians,
 * the noon sun's azimuth and elevation as seen from the ground (the sun is
 * at `-direction`). A sun at the zenith has no azimuth; 0 is taken.
 */
export function sunPath(direction) {
  const [x, y, z] = direction.map((v) => -v); // towards the sun
  const horizontal = Math.hypot(x, z);
  const elevation = Math.atan2(y, horizontal);
  return {
    azimuth: horizontal > 1e-9 ? Math.atan2(z, x) : 0,
    peak: elevation > 0 ? elevation : SUN_DEFAULT_ELEVATION,
  };
}

/** The sun's elevation on `path` at `hour` (0 to 24), radians; below 0 at night. */
export function sunElevation(path, hour) {
  return path.peak * Math.sin((Math.PI * (hour - SUNRISE)) / (SUNSET - SUNRISE));
}

/** The unit direction the light of the sun on `path` travels at `hour`,
 * its elevation clamped to the horizon at night. */
export function sunDirection(path, hour) {
  const elevation = Math.max(sunElevation(path, hour), 0);
  const azimuth = path.azimuth + (hour - 12) * RADIANS_PER_HOUR;
  const c = Math.cos(elevation);
  return [-c * Math.cos(azimuth), -Math.sin(elevation), -c * Math.sin(azimuth)];
}

/** The hour in [0, 24) at which the sun on `path` has the azimuth of unit
 * `direction` (the inverse of `sunDirection`; 12 for a light straight down). */
export function sunHour(path, direction) {
  const [x, , z] = direction.map((v) => -v);
  const azimuth = Math.hypot(x, z) > 1e-9 ? Math.atan2(z, x) : path.azimuth;
  const hour = 12 + (azimuth - path.azimuth) / RADIANS_PER_HOUR;
  return ((hour % 24) + 24) % 24;
}

/**
 * A sun's whole `state` (a LightState) at `hour` on `path`: its direction
 * there, switched off if the sun has just set (it was above the horizon
 * in `state`, it is not at `hour`), on if it has just risen, and `on` left
 * as it was otherwise.
 */
export function timeOfDay(path, hour, state) {
  const direction = sunDirection(path, hour);
  const wasUp = state.direction[1] < 0;
  const up = direction[1] < 0;
  return { ...state, direction, on: up === wasUp ? state.on : up };
}

// --- What the Lights panel's sliders are anchored on -------------------------
//
// A light's intensity slider counts stops from a reference intensity, and
// a sun's time-of-day slider follows the day's path around a noon
// direction. Both are the scene file's, so that every page gives the same
// hour the same direction and the same stop the same intensity however
// the lights were changed before it connected: the lights route's `file`
// (`GET /api/scenes/{id}/lights`, a solver's; PROTOCOL.md §7). A Welcome
// tells the lights as they are when it is written, which is the scene
// file's state only until a driver changes them; it is the fallback where
// the route has no `file` for the light: on a relay (which holds no scene
// file and has no lights route), on an older solver, or until the route
// has answered.

/**
 * What light `light`'s sliders (a Welcome's LightInfo: `name`, `kind`,
 * `state`) are anchored on, given `entry`, the lights route's entry at the
 * same index (or undefined): `{ reference, path, fromFile }`: the
 * intensity of the slider's 0 stop (1 for a black light), a sun's day path
 * (`sunPath`; null for a point or spot light) and whether they come from
 * the scene file's state (`entry.file`, used when the entry names the same
 * light and gives what is needed) or from `light.state`.
 */
export function lightAnchor(light, entry) {
  const file = entry?.name === light.name ? entry.file : undefined;
  const sun = light.kind === 'Directional';
  const usable =
    file &&
    Number.isFinite(file.intensity) &&
    file.intensity >= 0 &&
    (!sun || (finite3(file.direction) && unit(file.direction) !== null));
  const state = usable ? file : light.state;
  return {
    reference: state.intensity > 0 ? state.intensity : 1,
    path: sun ? sunPath(unit(state.direction) ?? [0, -1, 0]) : null,
    fromFile: Boolean(usable),
  };
}
