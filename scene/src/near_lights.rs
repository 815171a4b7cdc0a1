//! More texels where a point or spot light is near (issue 58, item 4: the
//! texel budget goes where the light changes).
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
//! `detail / r`, `r` the distance from the triangle to the nearest point
//! or spot light in front of it (within its range, if it has one). Charts
//! take triangles of one level only, so a floor far from the lamps keeps
//! its density and the ring around a lamp gets its own, finer charts.
//! Shadow edges and contacts, whose place only a solve tells (Wallner's
//! shadow-boundary ratio), are not refined here.

use glam::Vec3;

use crate::light::{Light, LightKind};

/// Texels across the distance to a light that the lightmap aims for (the
/// scene file's `lightmap.light_detail` default): texels of `r / 4`.
pub const DEFAULT_DETAIL: f32 = 4.0;

/// The finest refinement: `2^3 = 8` times the mesh's density.
pub const MAX_LEVEL: u8 = 3;

/// Per triangle (world space, counter-clockwise seen from the front), its
/// refinement level under `lights` at `density` texels per metre for
/// `detail` texels across the distance to a light (0: none refined).
pub fn levels(triangles: &[[Vec3; 3]], density: f32, lights: &[Light], detail: f32) -> Vec<u8> {
    let punctual: Vec<&Light> = lights
        .iter()
        .filter(|l| !matches!(l.kind, LightKind::Directional { .. }))
        .filter(|l| l.intensity.max_element() > 0.0)
        .collect();
    if detail <= 0.0 || punctual.is_empty() || density <= 0.0 {
        return vec![0; triangles.len()];
    }
    triangles
        .iter()
        .map(|&[a, b, c]| {
            let normal = (b - a).cross(c - a);
            let nearest = punctual
                .iter()
                .filter(|l| normal.dot(l.position - a) > 0.0)
                .map(|l| {
                    let r = closest_point(l.position, a, b, c).distance(l.position);
                    (r, l.range)
                })
                .filter(|(r, range)| range.is_none_or(|range| *r < range))
                .map(|(r, _)| r)
                .fold(f32::INFINITY, f32::min);
            level_for(density, detail / nearest.max(1e-3))
        })
        .collect()
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

    fn point(position: Vec3) -> Light {
        Light {
            name: "l".into(),
            kind: LightKind::Point,
            position,
            intensity: Vec3::ONE,
            range: None,
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
        // Unit triangles facing +z at x = 0, 4 and 40; a light 0.5 m in
        // front of the first.
        let tri = |x: f32| {
            [
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x + 1.0, 0.0, 0.0),
                Vec3::new(x, 1.0, 0.0),
            ]
        };
        let triangles = [tri(0.0), tri(4.0), tri(40.0)];
        let lights = [point(Vec3::new(0.2, 0.2, 0.5))];
        // At 1 texel/m: 4 / 0.5 = 8 texels/m (level 3); the second is
        // 3.8 m off (1.05 texels/m wanted: level 1); the third none.
        assert_eq!(levels(&triangles, 1.0, &lights, 4.0), vec![3, 1, 0]);
        // The same light behind the triangles refines nothing.
        let behind = [point(Vec3::new(0.2, 0.2, -0.5))];
        assert_eq!(levels(&triangles, 1.0, &behind, 4.0), vec![0, 0, 0]);
        // Nor does a light whose range ends short of them, nor detail 0.
        let short = [Light {
            range: Some(0.4),
            ..point(Vec3::new(0.2, 0.2, 0.5))
        }];
        assert_eq!(levels(&triangles, 1.0, &short, 4.0), vec![0, 0, 0]);
        assert_eq!(levels(&triangles, 1.0, &lights, 0.0), vec![0, 0, 0]);
        // A dense mesh needs no more than it has.
        assert_eq!(levels(&triangles, 10.0, &lights, 4.0), vec![0, 0, 0]);
    }
}
