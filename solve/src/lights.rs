//! Direct light from a scene's point, spot and directional lights and its
//! sky (issue 59), for the radiosity solvers: per element, the irradiance
//! each gives its sample point, with shadow rays. The solvers then treat
//! `ρ D` as light the element sends on, unshot, so every bounce after the
//! first is the radiosity solution's (the reference solver adds it to the
//! source term, the ray solver to its direct irradiance, taking the sky
//! from its own kept rays). The path tracer computes the same irradiance
//! on its own (`pathtrace`), so that it stays an independent oracle.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::raycast::{CosineGrid, Raycaster};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LightKind, Pose, Scene};

/// Shadow rays per side of the stratified grid on a directional light's
/// disc (when it has one): 16 directions, so a soft sun's penumbra is
/// resolved to 1/16 of the disc.
pub const SUN_SIDE: usize = 4;

/// Cosine rays per side for the reference solver's sky
/// ([`sky_irradiance_at`]): 1,024 per element.
pub const SKY_SIDE: usize = 32;

/// The irradiance (W/m² per channel) the point, spot and directional
/// lights of `scene` give the point `x` (already off its surface) with unit
/// normal `n`, where `caster` does not hide them: `Σ I(ω) cos θ / d²` over
/// point and spot lights (hard shadows: a light is a point), and
/// `E_n cos θ` times the visible share of its disc ([`SUN_SIDE`]² shadow
/// rays to infinity, one for a disc of no size) over directional ones. Not
/// the sky ([`sky_irradiance_at`]).
pub fn irradiance_at(scene: &Scene, caster: &Raycaster, (x, n): (DVec3, DVec3)) -> Vec3 {
    lights_irradiance(scene, (x, n), |d, max| !caster.occluded(x, d, max))
}

/// [`irradiance_at`] with `open(direction, distance)` saying whether a
/// shadow ray from `x` reaches its light.
fn lights_irradiance(
    scene: &Scene,
    (x, n): (DVec3, DVec3),
    mut open: impl FnMut(DVec3, f64) -> bool,
) -> Vec3 {
    let mut e = Vec3::ZERO;
    for light in &scene.lights {
        if let LightKind::Directional {
            direction,
            angular_radius,
        } = light.kind
        {
            let to_sun = -direction.as_dvec3();
            let cos = n.dot(to_sun);
            if cos <= 0.0 {
                continue;
            }
            let directions = disc_directions(to_sun, f64::from(angular_radius));
            let seen = directions
                .iter()
                .filter(|&&d| n.dot(d) > 0.0 && open(d, f64::INFINITY))
                .count();
            e += light.intensity * (cos * seen as f64 / directions.len() as f64) as f32;
            continue;
        }
        let d = light.position.as_dvec3() - x;
        let r = d.length();
        if r <= 0.0 {
            continue;
        }
        let dir = d / r;
        let cos = n.dot(dir);
        if cos <= 0.0 || !open(dir, r * (1.0 - 1e-9)) {
            continue;
        }
        let i = light.intensity_towards(-dir.as_vec3(), r as f32);
        e += i * (cos / (r * r)) as f32;
    }
    e
}

/// How the irradiance of the lights and the sky at `at` changes when the
/// scene placed as `old` becomes the scene placed as `new`, where all
/// that moved lies in `boxes` (world bounds, `(min, max)`, of the moved
/// objects before and after): `D_new − D_old`. Only the shadow rays
/// ([`irradiance_at`]'s, and [`sky_irradiance_at`]'s over `sky`) that
/// pass through a box are cast again, against both; a point none of whose
/// rays does gets exactly zero, so a far texel is not touched by a move.
pub fn irradiance_change(
    scene: &Scene,
    (old, new): (&Raycaster, &Raycaster),
    (x, n): (DVec3, DVec3),
    boxes: &[(DVec3, DVec3)],
    sky: &CosineGrid,
) -> Vec3 {
    let crosses = |d: DVec3, max: f64| boxes.iter().any(|b| ray_meets_box(x, d, max, b));
    let mut change = Vec3::ZERO;
    if !scene.lights.is_empty() {
        let mut met = false;
        let before = lights_irradiance(scene, (x, n), |d, max| {
            if crosses(d, max) {
                met = true;
                !old.occluded(x, d, max)
            } else {
                true
            }
        });
        if met {
            let after = lights_irradiance(scene, (x, n), |d, max| {
                !crosses(d, max) || !new.occluded(x, d, max)
            });
            change += after - before;
        }
    }
    if let Some(lit) = &scene.sky {
        let mut sum = Vec3::ZERO;
        for d in sky.around(n) {
            if !crosses(d, f64::INFINITY) {
                continue;
            }
            match (
                old.occluded(x, d, f64::INFINITY),
                new.occluded(x, d, f64::INFINITY),
            ) {
                (true, false) => sum += lit.radiance(d.as_vec3()),
                (false, true) => sum -= lit.radiance(d.as_vec3()),
                _ => {}
            }
        }
        change += sum * (std::f32::consts::PI / sky.len().max(1) as f32);
    }
    change
}

/// Whether the ray `x + t d`, `0 < t < max`, meets the box `(lo, hi)`
/// (slabs).
fn ray_meets_box(x: DVec3, d: DVec3, max: f64, (lo, hi): &(DVec3, DVec3)) -> bool {
    let (mut near, mut far) = (0.0f64, max);
    for axis in 0..3 {
        let (o, v) = (x[axis], d[axis]);
        if v.abs() < 1e-300 {
            if o < lo[axis] || o > hi[axis] {
                return false;
            }
            continue;
        }
        let (a, b) = ((lo[axis] - o) / v, (hi[axis] - o) / v);
        near = near.max(a.min(b));
        far = far.min(a.max(b));
        if near > far {
            return false;
        }
    }
    true
}

/// Directions towards a disc of angular radius `radius` about the unit
/// direction `centre`: [`SUN_SIDE`]² stratified over the disc (uniform in
/// its area: radius `√u`), or `centre` alone for a disc of no size.
pub fn disc_directions(centre: DVec3, radius: f64) -> Vec<DVec3> {
    if radius <= 0.0 {
        return vec![centre];
    }
    let t1 = centre.any_orthonormal_vector();
    let t2 = centre.cross(t1);
    let side = SUN_SIDE as f64;
    let spread = radius.tan();
    (0..SUN_SIDE * SUN_SIDE)
        .map(|k| {
            let (j, i) = ((k / SUN_SIDE) as f64, (k % SUN_SIDE) as f64);
            let r = ((j + 0.5) / side).sqrt() * spread;
            let phi = std::f64::consts::TAU * (i + 0.5) / side;
            (centre + (t1 * phi.cos() + t2 * phi.sin()) * r).normalize()
        })
        .collect()
}

/// The sky's irradiance at `x` (off its surface) with unit normal `n`:
/// `π` times the mean sky radiance over `directions` (cosine-distributed
/// about `n`) that leave the scene (any face of any patch blocks). Zero
/// without a sky.
pub fn sky_irradiance_at(
    scene: &Scene,
    caster: &Raycaster,
    (x, n): (DVec3, DVec3),
    directions: &CosineGrid,
) -> Vec3 {
    let Some(sky) = &scene.sky else {
        return Vec3::ZERO;
    };
    let sum: Vec3 = directions
        .around(n)
        .filter(|&d| !caster.occluded(x, d, f64::INFINITY))
        .map(|d| sky.radiance(d.as_vec3()))
        .sum();
    sum * (std::f32::consts::PI / directions.len().max(1) as f32)
}

/// The irradiance the lights and the sky give `at` (a point off its
/// surface and its unit normal): [`irradiance_at`] plus
/// [`sky_irradiance_at`] over `sky`.
pub fn direct_at(scene: &Scene, caster: &Raycaster, at: (DVec3, DVec3), sky: &CosineGrid) -> Vec3 {
    irradiance_at(scene, caster, at) + sky_irradiance_at(scene, caster, at, sky)
}

/// The irradiance `D + D_sky` the lights and the sky give each of
/// `elements` ([`direct_at`] at the element's sample point,
/// `crate::direct::sample_point`), against the scene at `poses` without
/// the objects flagged in `absent`, in parallel; zeros for a scene without
/// lights. The GPU solvers take `ρ` times it as reflected light the
/// elements start with (the progressive solver's radiosity and unshot
/// radiosity, the gather solver's direct irradiance), while their emission
/// stays the materials'.
pub fn element_irradiance(
    scene: &Scene,
    atlas: &Atlas,
    (poses, absent): (&[Pose], &[bool]),
    elements: &[usize],
) -> Vec<Vec3> {
    if !any(scene) {
        return vec![Vec3::ZERO; elements.len()];
    }
    let caster = Raycaster::with_absent(scene, poses, absent);
    let sky = CosineGrid::new(SKY_SIDE);
    elements
        .par_iter()
        .map(|&i| {
            let at = crate::direct::sample_point(scene, &caster, atlas, poses, i);
            direct_at(scene, &caster, at, &sky)
        })
        .collect()
}

/// `Σ A ρ D` over the elements of `atlas`: the power the lights' direct
/// light `irradiance` ([`element_irradiance`], one per element) puts into
/// the scene as reflected light, with `areas` the elements' world areas.
/// The solvers count it with the emitted power in their convergence
/// measures.
pub fn reflected_power(atlas: &Atlas, irradiance: &[Vec3], areas: &[f32]) -> f64 {
    atlas
        .elements
        .iter()
        .zip(irradiance)
        .zip(areas)
        .map(|((e, d), a)| f64::from(*a) * f64::from((e.albedo * *d).element_sum()))
        .sum()
}

/// Whether `scene` has lights or a sky that these functions light.
pub fn any(scene: &Scene) -> bool {
    !scene.lights.is_empty() || scene.sky.is_some()
}
