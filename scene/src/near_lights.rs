//! More texels where a light is near (issue 58, item 4: the texel budget
//! goes where the light changes).
//!
//! A point light's irradiance falls off as `cos θ / r²`: over a texel of
//! side `h` at distance `r` it changes by about `2 h / r`, and a lightmap
//! read bilinearly between texel centres misses its curvature by about
//! `(3/4) (h / r)²` of its value (the second derivative of `1 / r²` is
//! `6 / r⁴`, a linear interpolant is off by `h² f'' / 8`). Texels of
//! `r / 4` keep that under 5%; at a level's one texel per metre a wall
//! a metre from a lamp holds the lamp's falloff in one texel, and reads
//! twice what a player sees (BENCHMARKS.md §1, the levels under lights).
//!
//! This is the a-priori half of Coombe's gradient criterion (GPU Gems 2
//! §39.3, subdivide where radiosity changes fast): the falloff of a light
//! is known before any solve, so the atlas built from the scene alone —
//! by `bake`, `serve` and `bench eye` alike — already has the texels. Per
//! triangle of a generated lightmap (`unwrap.rs`), the level `k` (0 to
//! [`MAX_LEVEL`]) whose density `2^k × density` first reaches
//! `detail / r`, `r` the distance that stands for the triangle's lights
//! (point and spot lights in front of it, within their range, and the
//! import's emitting triangles; [`budgeted_levels`], [`distances`]).
//! Charts take triangles of one level only, so a floor far from the lamps
//! keeps its density and the ring around a lamp gets its own, finer
//! charts; a mesh gains at most [`MAX_EXTRA`] of its texels. Where a
//! sun's shadow edge crosses a triangle (Wallner's shadow-boundary
//! criterion, by shadow rays from its corners), its texels are a quarter
//! as large ([`SHADOW_LEVEL`]). Contacts, and the shadow edges of point and
//! spot lights, are not refined here.

use glam::Vec3;

use crate::light::{Light, LightKind};

/// Texels refinement may always add, whatever [`MAX_EXTRA`] says: a small
/// scene can afford them.
pub const MIN_EXTRA: f32 = 65_536.0;

/// Texels across the distance to a light that the lightmap aims for (the
/// scene file's `lightmap.light_detail` default): texels of `r / 4`.
pub const DEFAULT_DETAIL: f32 = 4.0;

/// The finest refinement: `2^3 = 8` times the mesh's density.
pub const MAX_LEVEL: u8 = 3;

/// The most texels refinement may add to a mesh, as a share of what it
/// has at its density (estimated by area, which overcounts triangles
/// smaller than a texel): a level lit by many panels would otherwise be
/// refined all over (pandora's 179 panels asked for 1.7 times its
/// elements).
pub const MAX_EXTRA: f32 = 0.5;

/// The refinement of a mesh: per triangle its level, and what the budget
/// left of the asked detail and of [`SHADOW_LEVEL`].
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement {
    pub levels: Vec<u8>,
    /// `light_detail` after the budget (the asked one if it fitted).
    pub detail: f32,
    /// The level of triangles a sun's shadow edge crosses after the budget.
    pub shadow_level: u8,
}

/// The level of a triangle a sun's shadow edge crosses (Wallner's
/// shadow-boundary criterion: its corners and centroid see the sun
/// otherwise): texels of a quarter of the mesh's, so that the band a
/// client reads blurred along the edge is a quarter as wide.
pub const SHADOW_LEVEL: u8 = 2;

/// Per triangle (world space, counter-clockwise seen from the front), its
/// refinement level at `density` texels per metre: [`SHADOW_LEVEL`] where
/// the shadow edge of a directional light (the sun) crosses it, as the
/// mesh itself casts it ([`sun_edges`]), and at least the level for
/// `detail` texels across the distance to the nearest point or spot light
/// in front of it (within its range) or emitting triangle (`emitters`,
/// world space) ([`distances`]); `detail` 0 refines nothing. Within a
/// budget: if the levels would add more than [`MAX_EXTRA`] of the mesh's
/// texels (by area) and more than [`MIN_EXTRA`], `detail` is lowered in
/// steps of 10% until they do not, and if even none does not fit, the
/// shadow level steps down.
///
/// An emitter is a light when each of the two triangles lies in front of
/// the other. Its light spreads over its radius `R` where it faces a
/// receiver (a disc's irradiance on its axis is `π L R² / (r² + R²)`, which
/// changes over `sqrt(r² + R²)`), but not along a receiver at right angles
/// to it (the frame around a lamp, lit from the lamp's edge): the distance
/// that counts is `sqrt(r² + (R cos)²)`, `cos` between the two normals and
/// `r` the least distance between the triangles. An emitter itself is not
/// refined (its light is its own, uniform).
pub fn budgeted_levels(
    triangles: &[[Vec3; 3]],
    density: f32,
    (lights, emitters): (&[Light], &[[Vec3; 3]]),
    detail: f32,
) -> Refinement {
    let near = distances(triangles, density, (lights, emitters), detail);
    let edges = if detail > 0.0 {
        sun_edges(triangles, lights)
    } else {
        vec![false; triangles.len()]
    };
    let areas: Vec<f32> = triangles
        .iter()
        .map(|[a, b, c]| 0.5 * (*b - *a).cross(*c - *a).length())
        .collect();
    let total: f32 = areas.iter().sum();
    let budget = (MAX_EXTRA * total * density * density).max(MIN_EXTRA);
    let mut last = None;
    for shadow_level in (0..=SHADOW_LEVEL).rev() {
        let mut d = detail;
        loop {
            let levels: Vec<u8> = near
                .iter()
                .zip(&edges)
                .map(|(r, edge)| {
                    let light = level_for(density, d / r.max(MIN_DISTANCE));
                    if *edge {
                        light.max(shadow_level)
                    } else {
                        light
                    }
                })
                .collect();
            let extra: f32 = levels
                .iter()
                .zip(&areas)
                .map(|(l, a)| a * (f32::from(1u16 << (2 * l)) - 1.0))
                .sum();
            let refinement = Refinement {
                levels,
                detail: d,
                shadow_level,
            };
            if extra * density * density <= budget {
                return refinement;
            }
            last = Some(refinement);
            if d < 1e-3 {
                break;
            }
            d *= 0.9;
        }
    }
    last.unwrap_or(Refinement {
        levels: vec![0; triangles.len()],
        detail: 0.0,
        shadow_level: 0,
    })
}

/// Per triangle, whether the shadow edge of a directional light crosses
/// it: of its three corners (pulled 1% towards the centroid) and its
/// centroid, lifted a millimetre off its front, some see the light's
/// centre and some do not, the mesh's own triangles the occluders (a BVH,
/// shadow rays cast in parallel). A triangle that faces away from a light
/// is in its own shadow, no edge.
pub fn sun_edges(triangles: &[[Vec3; 3]], lights: &[Light]) -> Vec<bool> {
    use rayon::prelude::*;
    let suns: Vec<glam::DVec3> = lights
        .iter()
        .filter(|l| l.intensity.max_element() > 0.0)
        .filter_map(|l| match l.kind {
            LightKind::Directional { direction, .. } => Some(-direction.as_dvec3()),
            _ => None,
        })
        .collect();
    if suns.is_empty() || triangles.is_empty() {
        return vec![false; triangles.len()];
    }
    let bvh = crate::bvh::Bvh::new(
        triangles
            .iter()
            .map(|[a, b, c]| {
                let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
                crate::bvh::Primitive::triangle(a, b - a, c - b)
            })
            .collect(),
    );
    let (lo, hi) = triangles
        .iter()
        .flatten()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
    let far = 2.0 * f64::from((hi - lo).length()) + 1.0;
    triangles
        .par_iter()
        .enumerate()
        .map(|(k, t)| {
            let [a, b, c] = t.map(|p| p.as_dvec3());
            let normal = (b - a).cross(c - a).normalize_or_zero();
            let centroid = (a + b + c) / 3.0;
            let probes = [a, b, c].map(|p| p + (centroid - p) * 0.01 + normal * 1e-3);
            let centre = centroid + normal * 1e-3;
            let skip = [k as u32; 2];
            suns.iter().filter(|to| normal.dot(**to) > 0.0).any(|to| {
                let sees = |p: glam::DVec3| !bvh.occluded(p, p + *to * far, skip);
                let first = sees(centre);
                probes.iter().any(|p| sees(*p) != first)
            })
        })
        .collect()
}

/// Per triangle, the distance that stands for its lights' (the point and
/// spot lights in front of it, within their range, and the emitters in
/// [`budgeted_levels`]): `sqrt(A / ∫ dA / d²)`, `d` at each point of the
/// triangle the distance to its nearest light. The error of a texel of
/// side `h` goes as `(h / d)²` (module notes), so this is the distance at
/// which a uniform texel keeps the triangle's mean error where `detail`
/// asks: a small triangle's own distance, but a large floor with a lamp
/// over one corner is not refined all over for that corner (its integral
/// grows only as the logarithm of its size). Infinity where no light is
/// within `detail / density` (none could refine it). The integral is
/// taken over [`SUB`]² sub-triangles at their centroids.
fn distances(
    triangles: &[[Vec3; 3]],
    density: f32,
    (lights, emitters): (&[Light], &[[Vec3; 3]]),
    detail: f32,
) -> Vec<f32> {
    let punctual: Vec<&Light> = lights
        .iter()
        .filter(|l| !matches!(l.kind, LightKind::Directional { .. }))
        .filter(|l| l.intensity.max_element() > 0.0)
        .collect();
    if detail <= 0.0 || (punctual.is_empty() && emitters.is_empty()) || density <= 0.0 {
        return vec![f32::INFINITY; triangles.len()];
    }
    // Beyond this distance nothing is refined.
    let reach = detail / density;
    let bounds = |t: &[Vec3; 3]| {
        let centre = (t[0] + t[1] + t[2]) / 3.0;
        let radius = t.iter().map(|p| p.distance(centre)).fold(0.0, f32::max);
        (centre, radius)
    };
    let emitters: Vec<([Vec3; 3], Vec3, Vec3, f32)> = emitters
        .iter()
        .map(|e| {
            let (centre, radius) = bounds(e);
            (*e, (e[1] - e[0]).cross(e[2] - e[0]), centre, radius)
        })
        .collect();
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = *t;
            let normal = (b - a).cross(c - a);
            let unit = normal.normalize_or_zero();
            let (centre, radius) = bounds(t);
            let lights: Vec<&&Light> = punctual
                .iter()
                .filter(|l| normal.dot(l.position - a) > 0.0)
                .filter(|l| l.position.distance(centre) - radius < reach)
                .filter(|l| {
                    l.range.is_none_or(|range| {
                        closest_point(l.position, a, b, c).distance(l.position) < range
                    })
                })
                .collect();
            let near_emitters: Vec<&([Vec3; 3], Vec3, Vec3, f32)> = emitters
                .iter()
                .filter(|(e, _, c, r)| *e != *t && c.distance(centre) - r - radius < reach)
                .filter(|(e, n, _, _)| {
                    // Each in front of the other (an emitter's coplanar
                    // neighbours and what lies behind it get nothing).
                    t.iter().any(|p| n.dot(*p - e[0]) > 1e-6 * n.length())
                        && e.iter()
                            .any(|p| normal.dot(*p - a) > 1e-6 * normal.length())
                })
                .collect();
            if lights.is_empty() && near_emitters.is_empty() {
                return f32::INFINITY;
            }
            let nearest = |p: Vec3| -> f32 {
                let to_lights = lights
                    .iter()
                    .map(|l| l.position.distance(p))
                    .fold(f32::INFINITY, f32::min);
                let to_emitters = near_emitters
                    .iter()
                    .map(|(e, n, _, r)| {
                        let facing = n.normalize_or_zero().dot(unit).abs();
                        closest_point(p, e[0], e[1], e[2])
                            .distance(p)
                            .hypot(r * facing)
                    })
                    .fold(f32::INFINITY, f32::min);
                to_lights.min(to_emitters).max(MIN_DISTANCE)
            };
            let centroids = sub_centroids(t);
            let inverse_square = centroids.iter().map(|p| nearest(*p).powi(-2)).sum::<f32>()
                / centroids.len() as f32;
            inverse_square.powf(-0.5)
        })
        .collect()
}

/// A triangle is cut into `SUB × SUB` equal sub-triangles for the
/// integral of [`distances`].
pub const SUB: usize = 4;

/// Distances below this (m) count as this: a light touching a surface.
const MIN_DISTANCE: f32 = 0.01;

/// The centroids of the `SUB²` equal sub-triangles of `t` (by lines
/// parallel to its sides).
fn sub_centroids(t: &[Vec3; 3]) -> Vec<Vec3> {
    let [a, b, c] = *t;
    let at = |u: f32, v: f32| a + (b - a) * u + (c - a) * v;
    let n = SUB as f32;
    let mut out = Vec::with_capacity(SUB * SUB);
    for i in 0..SUB {
        for j in 0..SUB - i {
            let (u, v) = (i as f32, j as f32);
            out.push(at((u + 1.0 / 3.0) / n, (v + 1.0 / 3.0) / n));
            if i + j + 1 < SUB {
                out.push(at((u + 2.0 / 3.0) / n, (v + 2.0 / 3.0) / n));
            }
        }
    }
    out
}

/// The smallest level whose density reaches `wanted` (at most
/// [`MAX_LEVEL`]).
fn level_for(density: f32, wanted: f32) -> u8 {
    let mut level = 0;
    while level < MAX_LEVEL && density * f32::from(1u8 << level) < wanted {
        level += 1;
    }
    level
}

/// The point of triangle `a b c` nearest to `p` (Ericson, Real-Time
/// Collision Detection §5.1.5: by the Voronoi region of `p`).
pub fn closest_point(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The levels without the budget: the criterion alone.
    fn levels(
        triangles: &[[Vec3; 3]],
        density: f32,
        (lights, emitters): (&[Light], &[[Vec3; 3]]),
        detail: f32,
    ) -> Vec<u8> {
        distances(triangles, density, (lights, emitters), detail)
            .iter()
            .map(|r| level_for(density, detail / r.max(MIN_DISTANCE)))
            .collect()
    }

    fn point(position: Vec3) -> Light {
        Light {
            name: "l".into(),
            kind: LightKind::Point,
            position,
            intensity: Vec3::ONE,
            range: None,
            object: crate::STATIC_OBJECT,
        }
    }

    #[test]
    fn sub_triangles_tile_the_triangle() {
        let t = [
            Vec3::ZERO,
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(0.0, 2.0, 1.0),
        ];
        let c = sub_centroids(&t);
        assert_eq!(c.len(), SUB * SUB);
        let mean = c.iter().copied().sum::<Vec3>() / c.len() as f32;
        assert!(mean.distance((t[0] + t[1] + t[2]) / 3.0) < 1e-5, "{mean}");
        // All distinct and inside.
        for (k, p) in c.iter().enumerate() {
            assert!(c[..k].iter().all(|q| q.distance(*p) > 0.1), "{p} twice");
            assert!(closest_point(*p, t[0], t[1], t[2]).distance(*p) < 1e-5);
        }
    }

    #[test]
    fn the_nearest_point_of_a_triangle_is_found_in_every_region() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let cases = [
            (Vec3::new(0.25, 0.25, 2.0), Vec3::new(0.25, 0.25, 0.0)),
            (Vec3::new(-1.0, -1.0, 0.0), a),
            (Vec3::new(2.0, -0.5, 0.0), b),
            (Vec3::new(-0.5, 2.0, 0.0), c),
            (Vec3::new(0.5, -1.0, 1.0), Vec3::new(0.5, 0.0, 0.0)),
            (Vec3::new(-1.0, 0.5, 0.0), Vec3::new(0.0, 0.5, 0.0)),
            (Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.5, 0.5, 0.0)),
        ];
        for (p, want) in cases {
            let got = closest_point(p, a, b, c);
            assert!(got.distance(want) < 1e-6, "{p}: {got} != {want}");
        }
    }

    #[test]
    fn triangles_near_a_light_in_front_get_finer_levels_and_far_or_behind_ones_none() {
        // Unit triangles facing +z at x = 0, 2 and 40; a light 0.5 m in
        // front of the first.
        let tri = |x: f32| {
            [
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x + 1.0, 0.0, 0.0),
                Vec3::new(x, 1.0, 0.0),
            ]
        };
        let triangles = [tri(0.0), tri(2.0), tri(40.0)];
        let lights = [point(Vec3::new(0.2, 0.2, 0.5))];
        // At 1 texel/m: the first, 0.5 to 1.1 m from the light, wants
        // more than 4 texels/m (level 3); the second, 1.9 to 2.9 m off,
        // between 1 and 2 (level 1); the third none.
        assert_eq!(levels(&triangles, 1.0, (&lights, &[]), 4.0), vec![3, 1, 0]);
        // The same light behind the triangles refines nothing.
        let behind = [point(Vec3::new(0.2, 0.2, -0.5))];
        assert_eq!(levels(&triangles, 1.0, (&behind, &[]), 4.0), vec![0, 0, 0]);
        // Nor does a light whose range ends short of them, nor detail 0.
        let short = [Light {
            range: Some(0.4),
            object: crate::STATIC_OBJECT,
            ..point(Vec3::new(0.2, 0.2, 0.5))
        }];
        assert_eq!(levels(&triangles, 1.0, (&short, &[]), 4.0), vec![0, 0, 0]);
        assert_eq!(levels(&triangles, 1.0, (&lights, &[]), 0.0), vec![0, 0, 0]);
        // A dense mesh needs no more than it has.
        assert_eq!(levels(&triangles, 10.0, (&lights, &[]), 4.0), vec![0, 0, 0]);
    }

    #[test]
    fn triangles_a_suns_shadow_edge_crosses_are_found_by_their_corners() {
        // A floor of 1 m cells facing up, and a 1.5 m square 1 m over it
        // from (0.25, 0.25) to (1.75, 1.75): under a sun straight down its
        // shadow's edge crosses the cells of the first two rows and
        // columns, not the far ones, nor the square itself.
        let up = |x: f32, y: f32, z: f32, s: f32| {
            let (a, b, c, d) = (
                Vec3::new(x, y, z),
                Vec3::new(x, y, z + s),
                Vec3::new(x + s, y, z + s),
                Vec3::new(x + s, y, z),
            );
            [[a, b, c], [a, c, d]]
        };
        let mut triangles = Vec::new();
        for i in 0..4 {
            for j in 0..4 {
                triangles.extend(up(i as f32, 0.0, j as f32, 1.0));
            }
        }
        triangles.extend(up(0.25, 1.0, 0.25, 1.5));
        let sun = |direction: Vec3| Light {
            name: "sun".into(),
            kind: LightKind::Directional {
                direction,
                angular_radius: 0.0,
            },
            position: Vec3::ZERO,
            intensity: Vec3::splat(800.0),
            range: None,
            object: crate::STATIC_OBJECT,
        };
        let edges = sun_edges(&triangles, &[sun(Vec3::NEG_Y)]);
        // Cell (i, j) holds triangles 8 i + 2 j and 8 i + 2 j + 1.
        let cell = |i: usize, j: usize| edges[8 * i + 2 * j] || edges[8 * i + 2 * j + 1];
        assert!(cell(0, 0) && cell(1, 1) && cell(0, 1), "{edges:?}");
        assert!(!cell(3, 3) && !cell(2, 3) && !cell(3, 0), "{edges:?}");
        assert!(!edges[32] && !edges[33], "the square is lit all over");
        // No sun, no edge; a sun from below lights nothing here.
        assert!(sun_edges(&triangles, &[]).iter().all(|e| !e));
        assert!(sun_edges(&triangles, &[sun(Vec3::Y)]).iter().all(|e| !e));
        // The budget: a mesh this small may always take them.
        let refined = budgeted_levels(&triangles, 1.0, (&[sun(Vec3::NEG_Y)], &[]), 4.0);
        assert_eq!(refined.shadow_level, SHADOW_LEVEL);
        assert_eq!(refined.levels[0], SHADOW_LEVEL);
        assert_eq!(refined.levels[30], 0);
    }

    #[test]
    fn emitting_triangles_refine_what_faces_them_by_their_size_and_distance() {
        // Receivers facing +z at z = 0; a small emitter (0.2 m) facing
        // down 0.3 m over the first, a coplanar neighbour beside it, and
        // the emitter itself among the triangles.
        let at = |x: f32, z: f32, size: f32, up: bool| {
            let (a, b, c) = (
                Vec3::new(x, 0.0, z),
                Vec3::new(x + size, 0.0, z),
                Vec3::new(x, size, z),
            );
            if up { [a, b, c] } else { [a, c, b] }
        };
        let small = at(0.0, 0.3, 0.2, false);
        let triangles = [
            at(0.0, 0.0, 1.0, true),
            at(20.0, 0.0, 1.0, true),
            at(0.2, 0.3, 0.2, true),
            small,
        ];
        let none: [Light; 0] = [];
        // At 1 texel/m: 4 / sqrt(0.3² + 0.13²) = 12 wanted, level 3; the
        // far receiver, the coplanar one (facing away: the emitter is
        // behind it) and the emitter itself get nothing.
        assert_eq!(
            levels(&triangles, 1.0, (&none, &[small]), 4.0),
            vec![3, 0, 0, 0]
        );
        // A 4 m emitter at the same height spreads its light: level 1
        // (4 / sqrt(0.3² + 2.98²) = 1.3 texels per metre wanted), where a
        // small one there asks for the most.
        let big = at(-2.0, 0.3, 4.0, false);
        assert_eq!(
            levels(&triangles[..2], 1.0, (&none, &[big]), 4.0),
            vec![1, 0]
        );
    }
}
