//! Point-to-polygon form factors, computed analytically.
//!
//! The form factor from a differential area at `x` with normal `n` to a
//! planar polygon with vertices `p_0 … p_{k-1}` that lies entirely above the
//! tangent plane of `x` and is fully visible is (Lambert's contour integral,
//! thesis §2.2.1 gives the general double-area integral it solves):
//!
//! `F = 1/(2π) · | Σ_e γ_e · n · (R_e × R_{e+1}) / |R_e × R_{e+1}| |`
//!
//! with `R_e = p_e − x` and `γ_e` the angle between `R_e` and `R_{e+1}`.
//! Polygons that straddle the tangent plane are first clipped against it
//! (only the upper hemisphere receives). The formula is exact, so the
//! reference solver needs no sub-sampling of the source for the unoccluded
//! part; partial occlusion is estimated separately by shadow rays.

use glam::DVec3;

/// Clipped polygons have at most the 4 input vertices plus one per clip.
const MAX_VERTICES: usize = 8;

/// Form factor from the differential area at `x` (normal `n`, unit) to the
/// convex polygon `poly`, ignoring occlusion.
pub fn point_to_polygon(x: DVec3, n: DVec3, poly: &[DVec3]) -> f64 {
    let mut clipped = [DVec3::ZERO; MAX_VERTICES];
    let count = clip_above(x, n, poly, &mut clipped);
    if count < 3 {
        return 0.0;
    }
    let mut sum = 0.0;
    for e in 0..count {
        let a = clipped[e] - x;
        let b = clipped[(e + 1) % count] - x;
        let c = a.cross(b);
        let len = c.length();
        if len <= 1e-300 {
            continue; // The edge points straight at x: no contribution.
        }
        let gamma = len.atan2(a.dot(b));
        sum += gamma * n.dot(c) / len;
    }
    (sum / (2.0 * std::f64::consts::PI)).abs()
}

/// Sutherland–Hodgman clip of a convex polygon to the half-space
/// `n · (p − x) >= 0`. Returns the number of vertices written.
fn clip_above(x: DVec3, n: DVec3, poly: &[DVec3], out: &mut [DVec3; MAX_VERTICES]) -> usize {
    let mut count = 0;
    let k = poly.len();
    for i in 0..k {
        let p = poly[i];
        let q = poly[(i + 1) % k];
        let dp = n.dot(p - x);
        let dq = n.dot(q - x);
        if dp >= 0.0 && count < MAX_VERTICES {
            out[count] = p;
            count += 1;
        }
        if (dp >= 0.0) != (dq >= 0.0) && count < MAX_VERTICES {
            let t = dp / (dp - dq);
            out[count] = p + (q - p) * t;
            count += 1;
        }
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Analytic form factor between two directly opposed parallel unit
    /// squares one unit apart (Howell's catalogue, configuration C-11).
    pub const OPPOSED_UNIT_SQUARES: f64 = 0.199_824_895_611_072;

    fn square(z: f64, size: f64) -> [DVec3; 4] {
        let h = size / 2.0;
        [
            DVec3::new(-h, -h, z),
            DVec3::new(h, -h, z),
            DVec3::new(h, h, z),
            DVec3::new(-h, h, z),
        ]
    }

    #[test]
    fn a_point_under_a_huge_plane_sees_it_fully() {
        let f = point_to_polygon(DVec3::ZERO, DVec3::Z, &square(1.0, 1.0e6));
        assert!((f - 1.0).abs() < 1e-5, "{f}");
    }

    #[test]
    fn a_point_to_a_coaxial_disk_like_square_matches_the_closed_form() {
        // Point under the corner of an a × b rectangle at distance c
        // (Howell B-3): F = 1/(2π) [A/√(1+A²) atan(B/√(1+A²))
        //                         + B/√(1+B²) atan(A/√(1+B²))], A = a/c, B = b/c.
        // A centred square of half-side a is four such rectangles with
        // A = B, so F = (4/π) S atan(S) with S = A/√(1+A²) = a/√(a²+c²).
        let (a, h) = (0.5f64, 1.0f64);
        let s = a / (a * a + h * h).sqrt();
        let expected = 4.0 / std::f64::consts::PI * s * s.atan();
        let f = point_to_polygon(DVec3::ZERO, DVec3::Z, &square(h, 2.0 * a));
        assert!((f - expected).abs() < 1e-12, "{f} vs {expected}");
    }

    #[test]
    fn polygons_behind_the_tangent_plane_contribute_nothing() {
        assert_eq!(
            point_to_polygon(DVec3::ZERO, DVec3::Z, &square(-1.0, 1.0)),
            0.0
        );
    }

    #[test]
    fn a_straddling_polygon_is_clipped_to_the_hemisphere() {
        // A vertical wall through the tangent plane: only its upper half
        // counts, so it equals the form factor of the upper half alone.
        let wall = [
            DVec3::new(1.0, -1.0, -1.0),
            DVec3::new(1.0, 1.0, -1.0),
            DVec3::new(1.0, 1.0, 1.0),
            DVec3::new(1.0, -1.0, 1.0),
        ];
        let upper = [
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(1.0, 1.0, 1.0),
            DVec3::new(1.0, -1.0, 1.0),
        ];
        let f = point_to_polygon(DVec3::ZERO, DVec3::Z, &wall);
        let g = point_to_polygon(DVec3::ZERO, DVec3::Z, &upper);
        assert!(f > 0.0 && (f - g).abs() < 1e-12, "{f} vs {g}");
    }

    #[test]
    fn integrating_over_one_square_gives_the_square_to_square_form_factor() {
        // Midpoint rule over the receiver: the mean of the point form
        // factors is the area-to-area form factor.
        let n = 64;
        let target = square(1.0, 1.0);
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                let x = DVec3::new(
                    (i as f64 + 0.5) / n as f64 - 0.5,
                    (j as f64 + 0.5) / n as f64 - 0.5,
                    0.0,
                );
                sum += point_to_polygon(x, DVec3::Z, &target);
            }
        }
        let f = sum / (n * n) as f64;
        assert!((f - OPPOSED_UNIT_SQUARES).abs() < 1e-4, "{f}");
    }
}
