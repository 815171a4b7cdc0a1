//! Direct light from a scene's point and spot lights (issue 59), for the
//! radiosity solvers: per element, the irradiance each light gives its
//! sample point, with a shadow ray. The solvers then treat `ρ D` as light
//! the element sends on, unshot, so every bounce after the first is the
//! radiosity solution's (the reference solver adds it to the source term,
//! the ray solver to its direct irradiance). The path tracer computes the
//! same irradiance on its own (`pathtrace`), so that it stays an
//! independent oracle.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::direct::sample_point;
use crate::raycast::Raycaster;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

/// The irradiance (W/m² per channel) the lights of `scene` give the point
/// `x` (already off its surface) with unit normal `n`:
/// `Σ I(ω) cos θ / d²` over the lights in front of it that `caster` does
/// not hide (hard shadows: a light is a point).
pub fn irradiance_at(scene: &Scene, caster: &Raycaster, (x, n): (DVec3, DVec3)) -> Vec3 {
    let mut e = Vec3::ZERO;
    for light in &scene.lights {
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

/// [`irradiance_at`] at every element's sample point (placed by `poses`,
/// against the whole scene there); zero for all when the scene has no
/// lights.
pub fn element_irradiance(scene: &Scene, atlas: &Atlas, poses: &[Pose]) -> Vec<Vec3> {
    if scene.lights.is_empty() {
        return vec![Vec3::ZERO; atlas.elements.len()];
    }
    let caster = Raycaster::new(scene, poses);
    (0..atlas.elements.len())
        .into_par_iter()
        .map(|i| {
            irradiance_at(
                scene,
                &caster,
                sample_point(scene, &caster, atlas, poses, i),
            )
        })
        .collect()
}
