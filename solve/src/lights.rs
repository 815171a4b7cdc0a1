//! Direct light from a scene's point, spot and directional lights and its
//! sky (issue 59), for the radiosity solvers: per element, the irradiance
//! each gives its sample point, with shadow rays. The solvers then treat
//! `ρ D` as light the element sends on, unshot, so every bounce after the
//! first is the radiosity solution's (the reference solver adds it to the
//! source term, the ray solver to its direct irradiance, taking the sky
//! from its own kept rays). The path tracer computes the same irradiance
//! on its own (`pathtrace`), so that it stays an independent oracle.

use glam::{DVec3, Vec3};

use crate::raycast::{CosineGrid, Raycaster};
use lightwire_scene::{LightKind, Scene};

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
            let open = directions
                .iter()
                .filter(|&&d| n.dot(d) > 0.0 && !caster.occluded(x, d, f64::INFINITY))
                .count();
            e += light.intensity * (cos * open as f64 / directions.len() as f64) as f32;
            continue;
        }
        let d = light.position.as_dvec3() - x;
        let r = d.length();
        if r <= 0.0 {
            continue;
        }
        let dir = d / r;
        let cos = n.dot(dir);
        if cos <= 0.0 || caster.occluded(x, dir, r * (1.0 - 1e-9)) {
            continue;
        }
        let i = light.intensity_towards(-dir.as_vec3(), r as f32);
        e += i * (cos / (r * r)) as f32;
    }
    e
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

/// Whether `scene` has lights or a sky that these functions light.
pub fn any(scene: &Scene) -> bool {
    !scene.lights.is_empty() || scene.sky.is_some()
}
