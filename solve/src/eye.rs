//! Accuracy where a player looks: the published lightmap read as an engine
//! reads it, at points a player can see, against the path tracer at the
//! same points.
//!
//! [`crate::accuracy`] compares two lightmaps element by element, every
//! element weighted by its area: a metric of the solution. A player sees
//! something else: the image a client draws, bilinearly filtered between
//! texel centres across chart borders, gutters and seams, at the points in
//! view. A texel that holds light from behind a wall, a chart whose
//! border texels are black, a seam that does not meet: these are invisible
//! to the element metric and are what a player notices.
//!
//! [`visible_points`] draws eyes at random inside the scene's bounds, keeps
//! those that see only front faces around them (not inside an object or
//! behind a wall), and from each looks in a random direction: the first
//! surface hit, if its front faces the eye, is a point in view.
//! [`lightmap_at`] reads a published image at such a point as a client
//! reads `scene.glb`'s lightmap coordinates; [`compare`] sets those reads
//! against path-traced estimates of the same points
//! ([`crate::pathtrace::PathTracer::estimate_point`]).

use glam::{DVec3, Vec2, Vec3};
use lightwire_scene::Scene;
use lightwire_scene::atlas::Atlas;
use serde::Serialize;

use crate::pathtrace::Estimate;
use crate::raycast::Raycaster;

/// Directions an eye looks in to decide whether it stands in open space:
/// the six axes and the eight diagonals.
fn probe_directions() -> [DVec3; 14] {
    let d = 1.0 / 3f64.sqrt();
    [
        DVec3::X,
        DVec3::NEG_X,
        DVec3::Y,
        DVec3::NEG_Y,
        DVec3::Z,
        DVec3::NEG_Z,
        DVec3::new(d, d, d),
        DVec3::new(d, d, -d),
        DVec3::new(d, -d, d),
        DVec3::new(d, -d, -d),
        DVec3::new(-d, d, d),
        DVec3::new(-d, d, -d),
        DVec3::new(-d, -d, d),
        DVec3::new(-d, -d, -d),
    ]
}

/// A surface point in view.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct VisiblePoint {
    /// The eye it was seen from.
    pub eye: [f64; 3],
    /// The patch hit.
    pub patch: u32,
    /// Its parameters on the patch.
    pub st: [f64; 2],
    /// World position.
    pub position: [f64; 3],
    /// The patch's front normal.
    pub normal: [f64; 3],
}

/// Up to `count` points in view from eyes drawn uniformly in the bounding
/// box of the static world shrunk by `margin` on every side, with a
/// generator seeded by `seed`. An eye is kept when none of 14 rays around
/// it (axes and diagonals) first meets a back face, and at least half of
/// them meet something: it stands in the open, in the level, not inside
/// an object or behind a wall. Each eye looks once, in a uniformly random
/// direction; a hit on a front face is a point in view. Gives up after
/// `count × 200` eyes (a scene with no open space yields fewer points).
pub fn visible_points(
    scene: &Scene,
    rays: &Raycaster,
    count: usize,
    margin: f64,
    seed: u64,
) -> Vec<VisiblePoint> {
    let (lo, hi) = static_bounds(scene, rays);
    let lo = lo + DVec3::splat(margin);
    let hi = hi - DVec3::splat(margin);
    let mut rng = fastrand::Rng::with_seed(seed);
    let far = rays.extent() * 4.0;
    let mut out = Vec::with_capacity(count);
    for _ in 0..count.saturating_mul(200) {
        if out.len() >= count {
            break;
        }
        let eye = DVec3::new(
            lo.x + (hi.x - lo.x) * rng.f64(),
            lo.y + (hi.y - lo.y) * rng.f64(),
            lo.z + (hi.z - lo.z) * rng.f64(),
        );
        let hits: Vec<_> = probe_directions()
            .iter()
            .filter_map(|&d| rays.closest_hit(eye, d, far))
            .collect();
        if hits.iter().any(|h| !h.front) || hits.len() < 7 {
            continue;
        }
        let dir = uniform_sphere(&mut rng);
        let Some(hit) = rays.closest_hit(eye, dir, far) else {
            continue;
        };
        if !hit.front {
            continue;
        }
        let patch = &rays.patches()[hit.patch as usize];
        let (s, t) = patch.param(hit.point);
        out.push(VisiblePoint {
            eye: eye.to_array(),
            patch: hit.patch,
            st: [s.clamp(0.0, 1.0), t.clamp(0.0, 1.0)],
            position: hit.point.to_array(),
            normal: patch.normal.to_array(),
        });
    }
    out
}

/// The bounding box of the static world's patches (all patches when the
/// scene has no static one).
fn static_bounds(scene: &Scene, rays: &Raycaster) -> (DVec3, DVec3) {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    let any_static = scene.patches.iter().any(|p| p.object == 0);
    for (p, wp) in scene.patches.iter().zip(rays.patches()) {
        if any_static && p.object != 0 {
            continue;
        }
        for c in wp.corners() {
            lo = lo.min(*c);
            hi = hi.max(*c);
        }
    }
    (lo, hi)
}

fn uniform_sphere(rng: &mut fastrand::Rng) -> DVec3 {
    let z = 2.0 * rng.f64() - 1.0;
    let phi = std::f64::consts::TAU * rng.f64();
    let r = (1.0 - z * z).max(0.0).sqrt();
    DVec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// The published lightmap `image` (row-major, `atlas.width` ×
/// `atlas.height`) at patch parameters `st` of `patch`, read as a client
/// reads it: bilinear between texel centres of the whole image (a point
/// near a chart's border mixes in the gutter and whatever lies beyond),
/// clamped at the image's edges.
pub fn lightmap_at(atlas: &Atlas, image: &[[f32; 3]], patch: u32, st: [f64; 2]) -> Vec3 {
    match texel_at(atlas, patch, st) {
        Some(xy) => bilinear(image, atlas.width, atlas.height, xy),
        None => Vec3::ZERO,
    }
}

/// Where in the atlas image (texel `(x, y)`'s centre at `(x, y)`) a client
/// reads the point at parameters `st` of `patch`; `None` for a patch the
/// atlas does not have.
pub fn texel_at(atlas: &Atlas, patch: u32, st: [f64; 2]) -> Option<Vec2> {
    let chart = atlas.charts.get(patch as usize)?;
    Some(
        atlas
            .chart_map(patch)
            .to_chart(Vec2::new(st[0] as f32, st[1] as f32))
            + Vec2::new(chart.x as f32, chart.y as f32),
    )
}

/// Bilinear read of a row-major image whose texel `(x, y)` has its centre
/// at `(x, y)`, clamped at the edges.
pub fn bilinear(image: &[[f32; 3]], width: u32, height: u32, xy: Vec2) -> Vec3 {
    if width == 0 || height == 0 || image.len() < (width * height) as usize {
        return Vec3::ZERO;
    }
    let axis = |x: f32, n: u32| -> (u32, u32, f32) {
        let x = x.clamp(0.0, (n - 1) as f32);
        let x0 = x.floor() as u32;
        let x1 = (x0 + 1).min(n - 1);
        (x0, x1, x - x0 as f32)
    };
    let (x0, x1, fx) = axis(xy.x, width);
    let (y0, y1, fy) = axis(xy.y, height);
    let at = |x: u32, y: u32| Vec3::from_array(image[(y * width + x) as usize]);
    let top = at(x0, y0).lerp(at(x1, y0), fx);
    let bottom = at(x0, y1).lerp(at(x1, y1), fx);
    top.lerp(bottom, fy)
}

/// How far a lightmap read at points in view is from the truth there.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct EyeReport {
    /// Points compared.
    pub points: usize,
    /// `sqrt(Σ |L − T|² / Σ |T|²)` over the points (each counts alike:
    /// a player's view does not weigh surfaces by area).
    pub nrmse: f64,
    /// Median of `|L − T| / |T|` over the points brighter than 1% of the
    /// mean (`|·|` the norm of the RGB triple).
    pub median_rel: f64,
    /// 95th percentile of the same.
    pub p95_rel: f64,
    /// Share of those points more than 10% off.
    pub over_10: f64,
    /// Share more than 25% off.
    pub over_25: f64,
    /// The truth's own noise: `sqrt(Σ σ² / Σ |T|²)`, σ the norm of each
    /// estimate's standard error (what the NRMSE of a perfect lightmap
    /// would read).
    pub truth_noise: f64,
    /// The median and 95th percentile of the truth's relative standard
    /// error `σ / |T|` over the points [`Self::median_rel`] counts: the
    /// floor under the median and p95 (a dim point of a level lit through
    /// many bounces is where paths are noisiest, and there a perfect
    /// lightmap reads about as far off as the truth is unsure).
    pub noise_rel: [f64; 2],
    /// The 5th and 95th percentiles of the NRMSE over [`BOOTSTRAP`]
    /// resamples of the points (drawn with replacement, seeded): how much
    /// the figure depends on which points were drawn. On a real level a
    /// few points near the lamp, where one texel spans a centimetre of
    /// frame in front of it, carry most of the squared error, and another
    /// draw of 400 points reads 11% or 30% of the same lightmap.
    pub nrmse_interval: [f64; 2],
    /// The share of `Σ |L − T|²` the single worst point carries.
    pub worst_share: f64,
}

/// Resamples behind [`EyeReport::nrmse_interval`].
pub const BOOTSTRAP: usize = 1000;

/// Compares lightmap reads `values` with path-traced `truth` at the same
/// points.
pub fn compare(values: &[Vec3], truth: &[Estimate]) -> EyeReport {
    let n = values.len().min(truth.len());
    if n == 0 {
        return EyeReport::default();
    }
    let (mut err, mut norm, mut noise) = (0.0f64, 0.0f64, 0.0f64);
    let mut squares = Vec::with_capacity(n);
    for (v, t) in values.iter().zip(truth) {
        let d = (*v - t.mean).as_dvec3().length_squared();
        let m = t.mean.as_dvec3().length_squared();
        err += d;
        norm += m;
        noise += t.std_error.as_dvec3().length_squared();
        squares.push((d, m));
    }
    let mean = truth[..n]
        .iter()
        .map(|t| f64::from(t.mean.length()))
        .sum::<f64>()
        / n as f64;
    let counted = || {
        values
            .iter()
            .zip(truth)
            .filter(|(_, t)| f64::from(t.mean.length()) > 0.01 * mean)
    };
    let mut rel: Vec<f64> = counted()
        .map(|(v, t)| f64::from((*v - t.mean).length() / t.mean.length()))
        .collect();
    rel.sort_by(f64::total_cmp);
    let mut unsure: Vec<f64> = counted()
        .map(|(_, t)| f64::from(t.std_error.length() / t.mean.length()))
        .collect();
    unsure.sort_by(f64::total_cmp);
    let quantile_of = |v: &[f64], q: f64| -> f64 {
        if v.is_empty() {
            return 0.0;
        }
        v[((v.len() - 1) as f64 * q).round() as usize]
    };
    let quantile = |q: f64| quantile_of(&rel, q);
    let share = |limit: f64| -> f64 {
        if rel.is_empty() {
            return 0.0;
        }
        rel.iter().filter(|&&r| r > limit).count() as f64 / rel.len() as f64
    };
    let norm = norm.max(f64::MIN_POSITIVE);
    EyeReport {
        points: n,
        nrmse: (err / norm).sqrt(),
        median_rel: quantile(0.5),
        p95_rel: quantile(0.95),
        over_10: share(0.10),
        over_25: share(0.25),
        truth_noise: (noise / norm).sqrt(),
        noise_rel: [quantile_of(&unsure, 0.5), quantile_of(&unsure, 0.95)],
        nrmse_interval: bootstrap(&squares),
        worst_share: squares.iter().map(|s| s.0).fold(0.0, f64::max) / err.max(f64::MIN_POSITIVE),
    }
}

/// The 5th and 95th percentiles of `sqrt(Σ d / Σ m)` over [`BOOTSTRAP`]
/// resamples (with replacement, a fixed seed) of the points' `(d, m)`:
/// squared error and squared truth.
fn bootstrap(squares: &[(f64, f64)]) -> [f64; 2] {
    if squares.is_empty() {
        return [0.0; 2];
    }
    let mut rng = fastrand::Rng::with_seed(0x5eed);
    let mut nrmse: Vec<f64> = (0..BOOTSTRAP)
        .map(|_| {
            let (mut d, mut m) = (0.0, 0.0);
            for _ in 0..squares.len() {
                let s = squares[rng.usize(..squares.len())];
                d += s.0;
                m += s.1;
            }
            (d / m.max(f64::MIN_POSITIVE)).sqrt()
        })
        .collect();
    nrmse.sort_by(f64::total_cmp);
    let at = |q: f64| nrmse[((nrmse.len() - 1) as f64 * q).round() as usize];
    [at(0.05), at(0.95)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_reads_texel_centres_exactly_and_between_them_linearly() {
        // 2 x 2: (0,0) 0, (1,0) 1, (0,1) 2, (1,1) 3 in every channel.
        let image: Vec<[f32; 3]> = (0..4).map(|i| [i as f32; 3]).collect();
        let at = |x: f32, y: f32| bilinear(&image, 2, 2, Vec2::new(x, y)).x;
        assert_eq!(at(0.0, 0.0), 0.0);
        assert_eq!(at(1.0, 1.0), 3.0);
        assert_eq!(at(0.5, 0.0), 0.5);
        assert_eq!(at(0.5, 0.5), 1.5);
        // Clamped beyond the edges.
        assert_eq!(at(-3.0, 7.0), 2.0);
    }

    fn estimate(v: f32) -> Estimate {
        Estimate {
            mean: Vec3::splat(v),
            std_error: Vec3::ZERO,
            irradiance: Vec3::ZERO,
            lights: Vec3::ZERO,
        }
    }

    #[test]
    fn compare_says_how_far_off_the_reads_are() {
        let truth: Vec<Estimate> = (1..=100).map(|i| estimate(i as f32)).collect();
        let exact: Vec<Vec3> = truth.iter().map(|t| t.mean).collect();
        let r = compare(&exact, &truth);
        assert_eq!((r.nrmse, r.median_rel, r.over_10), (0.0, 0.0, 0.0));
        // Every read 20% bright: 20% at every quantile, all over 10%, none
        // over 25%.
        let bright: Vec<Vec3> = exact.iter().map(|v| *v * 1.2).collect();
        let r = compare(&bright, &truth);
        assert!((r.nrmse - 0.2).abs() < 1e-6, "{r:?}");
        // Every point equally off: any resample reads the same, and the
        // worst point carries its share, not more.
        assert!(
            r.nrmse_interval.iter().all(|x| (x - 0.2).abs() < 1e-6),
            "{r:?}"
        );
        assert!(r.worst_share < 0.05, "{r:?}");
        assert!((r.median_rel - 0.2).abs() < 1e-6 && (r.p95_rel - 0.2).abs() < 1e-6);
        assert_eq!((r.over_10, r.over_25), (1.0, 0.0));
        // One black point in a hundred: 1% of points off, and the NRMSE
        // says how much light it lacks.
        let mut one_black = exact.clone();
        one_black[99] = Vec3::ZERO;
        let r = compare(&one_black, &truth);
        assert!((r.over_25 - 0.01).abs() < 1e-9, "{r:?}");
        assert!(r.nrmse > 0.1, "{r:?}");
        // ... all of it at one point: a third of the resamples miss it
        // (0.99^100) and read 0, others draw it twice.
        assert_eq!(r.worst_share, 1.0, "{r:?}");
        assert_eq!(r.nrmse_interval[0], 0.0, "{r:?}");
        assert!(r.nrmse_interval[1] > r.nrmse, "{r:?}");
        assert_eq!(r.noise_rel, [0.0, 0.0], "exact truth: no floor");
        // Truths unsure by 1% to 100% of themselves: the floor's median
        // and p95 are theirs.
        let unsure: Vec<Estimate> = truth
            .iter()
            .enumerate()
            .map(|(i, t)| Estimate {
                std_error: t.mean * ((i + 1) as f32 / 100.0),
                ..*t
            })
            .collect();
        let r = compare(&exact, &unsure);
        assert!((r.noise_rel[0] - 0.50).abs() < 0.011, "{r:?}");
        assert!((r.noise_rel[1] - 0.95).abs() < 0.011, "{r:?}");
    }

    #[test]
    fn points_in_view_are_front_faces_seen_from_the_open() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/cornell-large.json");
        let scene = Scene::load(std::path::Path::new(path)).expect("scene");
        let poses = scene.initial_poses();
        let rays = Raycaster::new(&scene, &poses);
        let points = visible_points(&scene, &rays, 200, 0.05, 7);
        assert_eq!(points.len(), 200);
        let pose = poses[1];
        let block = |x: DVec3| {
            let local = (x - pose.translation.as_dvec3()).abs();
            local.x < 0.8 && local.y < 0.85 && local.z < 0.8
        };
        for p in &points {
            let eye = DVec3::from_array(p.eye);
            assert!(!block(eye), "an eye inside the box: {p:?}");
            let (x, n) = (DVec3::from_array(p.position), DVec3::from_array(p.normal));
            assert!((eye - x).dot(n) > 0.0, "the point faces its eye: {p:?}");
            assert!(!rays.occluded(eye, (x - eye).normalize(), (x - eye).length() * 0.999));
        }
        // The box is seen too, and points differ.
        assert!(
            points
                .iter()
                .any(|p| scene.patches[p.patch as usize].object == 1)
        );
        assert!(points.windows(2).any(|w| w[0].patch != w[1].patch));
    }
}
