// Light gizmos for the 3D view: the scene's point, spot and directional
// lights as line segments. The wire's SceneInfo does not carry lights, so
// they come from `GET /api/scenes/{id}/lights` (a solver's route: the
// scene file's `"lights"`, every direction unit, cones in degrees); a
// relay lists none. Pure geometry, no WebGL, so that node checks it
// (test/gizmos.test.mjs); view3d.js draws the result with gl.LINES after
// the surfaces.
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
