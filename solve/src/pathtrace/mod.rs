//! The path tracer: a second, independent accuracy oracle (Monte Carlo).
//!
//! The reference solver ([`crate::reference`]) discretises the scene into
//! elements and solves the radiosity system; its answers carry the
//! discretisation's error (constant radiosity per region, quadrature of the
//! form factors and of partial visibility). This module estimates the same
//! quantity without any discretisation: it integrates the rendering
//! equation (Kajiya, "The rendering equation", SIGGRAPH 1986) at a point by
//! Monte Carlo, so that its error is noise only, and it reports that noise.
//! When the two oracles disagree by more than the noise, one of them is
//! wrong (DESIGN.md, "Accuracy"). It reads only the validated [`Scene`]
//! and, for [`PathTracer::estimate_elements`], the atlas's element list,
//! and shares no code with any solver; its ray casting is
//! [`crate::raycast`].
//!
//! # What is estimated
//!
//! Every surface is Lambertian and one-sided: it reflects and emits only
//! from its front face (the side `u × v` points to). Radiosity at a point
//! `x` with normal `n` is
//!
//! `B(x) = E(x) + ρ(x) H(x)`,  `H(x) = ∫_Ω L_in(x, ω) cos θ dω`,
//!
//! where `E` is the self-emitted radiant exitance (W/m², the scene's
//! `emission`), `ρ` the albedo and `H` the irradiance. A Lambertian
//! surface of radiosity `B` has radiance `L = B / π` in every direction,
//! so an emitter's own radiance is `L_e = E / π`. A ray that arrives on a
//! back face brings no light (nothing leaves a back face), and ends the
//! path.
//!
//! # The estimator
//!
//! One sample of `H(x)` is one path `x = x_0, x_1, x_2, …`:
//!
//! - **Next-event estimation** at every vertex `x_k` (direct lighting by
//!   light-source sampling; Shirley, Wang and Zimmerman, "Monte Carlo
//!   techniques for direct lighting calculations", ACM TOG 1996): pick
//!   one emitter patch with probability proportional to its power
//!   `A_j Σ_c E_j,c`, a point `y` uniformly on it (a parallelogram or a
//!   triangle, the latter by folding the unit square onto it), and cast a
//!   shadow ray (either face of any patch blocks it). The contribution to the
//!   irradiance at `x_k` is `(E_j / π) cos θ_x cos θ_y / |y − x_k|² / p(y)`
//!   with the area density `p(y) = P(j) / A_j`, times the weight of the
//!   third point below, and zero when `y` is behind `x_k` or `x_k` is
//!   behind the emitter's front face.
//! - **A bounce**: a direction drawn with density `cos θ / π` about the
//!   normal (Malley's method). For a Lambertian surface the cosine and the
//!   `1/π` of the BRDF cancel the density, so the path's throughput is
//!   simply multiplied by the albedo of the surface it lands on: the
//!   irradiance at `x_k` gathers `ρ(x_{k+1}) H(x_{k+1})` through that one
//!   ray. A bounce that leaves the scene or lands on a back face ends the
//!   path.
//! - **Emission found by a bounce** is not simply added (next-event
//!   estimation already counts every emitter's direct light; adding it too
//!   would count it twice), nor simply dropped: both strategies can reach
//!   the same emitter point, and the two contributions are weighted by
//!   Veach and Guibas's power heuristic (multiple importance sampling,
//!   "Optimally combining sampling techniques for Monte Carlo rendering",
//!   SIGGRAPH 1995; Veach's thesis, 1997, ch. 9), with weights that add up to one for every emitter
//!   point, so each is counted exactly once. The reason is variance: plain
//!   next-event estimation has *infinite* variance where an emitter meets
//!   another surface at an angle (every edge of the furnace). A vertex at
//!   distance `d` from such an edge samples emitter points at distances
//!   down to `d`, the second moment of its estimate grows like `1/d²`, and
//!   bounce vertices land arbitrarily close to edges; the mean is right
//!   but the standard error is meaningless (measured: 3.5× the standard
//!   error of the weighted estimator at a furnace face centre, 4096 paths).
//!   Weighted, every contribution is bounded: at most `E/2` from a
//!   next-event sample and `E` from a bounce.
//! - **Lights and sky** (issue 59): a point or spot light is a point that
//!   no bounce can hit, so every vertex adds each one's `I(ω) cos θ / d²`
//!   through one shadow ray, nothing to weigh; a directional light (the
//!   sun) adds `E cos θ` if the shadow ray towards one direction drawn
//!   uniformly over its disc leaves the scene; a bounce that leaves the
//!   scene adds the sky's `π L` in its direction (its radiance over the
//!   cosine density). The sky holds no sun, so nothing is counted twice.
//! - **Russian roulette** (Arvo and Kirk, "Particle transport and image
//!   synthesis", SIGGRAPH 1990) after [`ROULETTE_AFTER`] bounces: the
//!   path continues with probability `q = min(max_c throughput_c, 0.95)`
//!   and its throughput is divided by `q`, which keeps the estimate
//!   unbiased while every path ends (albedo < 1). [`MAX_BOUNCES`] is a
//!   safety stop that the roulette makes irrelevant (`0.95^512 < 1e-11`).
//!
//! The sample of the radiosity is `E + ρ ⊙ H_sample`. An estimate averages
//! `spp` independent samples and reports their mean and standard error
//! `s / √spp` per channel (`s` the sample standard deviation): the mean is
//! within 3 standard errors of the truth with high probability, which is
//! how the tests and the bake's `std_error.json` judge it.
//!
//! This is the estimator of the reference path tracer of Barak's thesis
//! (Instant radiosity with imperfect shadow maps, 2012, §8.2.4: one
//! shadow ray and one reflection ray per bounce, incoming radiance sampled
//! by BRDF times cosine), which §9.4 uses to judge its solver; here it
//! judges a lightmap at its texel sample points instead of pixels.
//!
//! # Points on surfaces
//!
//! Rays start at `x + n ·` [`SURFACE_OFFSET`] so that they do not hit the
//! surface they leave. The atlas puts border samples exactly on patch
//! edges, where a perpendicular wall may meet the patch; such a sample is
//! first moved [`SURFACE_OFFSET`] towards its patch's centre
//! ([`PathTracer::surface_point`]), as the reference solver does, so that
//! its rays leave from in front of its own patch and not from inside the
//! wall.
//!
//! Estimates are deterministic: point `i` of a batch draws from its own
//! generator seeded from `i` (and the batch seed), so results do not depend
//! on threads or scheduling. Batches run in parallel with rayon.

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use serde::Serialize;

use crate::raycast::{Raycaster, WorldPatch};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::texture::AlbedoMap;
use lightwire_scene::{Pose, Scene};

/// Distance (m) by which ray origins leave their surface along the normal,
/// and by which edge samples move towards their patch's centre.
pub const SURFACE_OFFSET: f64 = 1e-5;
/// Samples per point of `lightwire bake --solver pathtrace` by default.
pub const DEFAULT_SPP: u32 = 256;
/// Bounces before Russian roulette starts.
pub const ROULETTE_AFTER: u32 = 3;
/// Longest path (bounces); see the module doc.
pub const MAX_BOUNCES: u32 = 512;
/// Elements whose `|B|` is below this fraction of the area-weighted mean
/// `|B|` are left out of the relative standard errors of [`NoiseSummary`]
/// (the same floor as the p95 of [`crate::accuracy`]), so that a black
/// texel does not divide by zero.
pub const RELATIVE_FLOOR: f64 = 0.01;

/// A Monte Carlo estimate of radiosity at one point, per channel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Estimate {
    /// Mean of the samples of `B = E + ρ H` (W/m²).
    pub mean: Vec3,
    /// Standard error of the mean, `s / √spp` (W/m²).
    pub std_error: Vec3,
    /// Mean of the samples of the irradiance `H` (W/m²), whose standard
    /// error is `std_error / ρ`.
    pub irradiance: Vec3,
    /// The part of `irradiance` that comes straight from the point, spot
    /// and directional lights and the sky (W/m²): the power they deliver
    /// ([`energy_balance`]).
    pub lights: Vec3,
}

impl Estimate {
    /// `|std_error| / |mean|` (Euclidean norms of the RGB triples); 0 when
    /// both are 0, infinite when only the mean is.
    pub fn relative_std_error(&self) -> f64 {
        let (m, s) = (
            f64::from(self.mean.length()),
            f64::from(self.std_error.length()),
        );
        if s == 0.0 { 0.0 } else { s / m }
    }
}

/// A point to estimate: on a surface (not yet offset along the normal),
/// with that surface's normal and material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// World-space position on the surface.
    pub position: DVec3,
    /// World-space unit normal of the front face.
    pub normal: DVec3,
    /// Albedo at the point; `Vec3::ONE` makes the estimate the irradiance.
    pub albedo: Vec3,
    /// Self-emitted radiant exitance at the point (W/m²).
    pub emission: Vec3,
}

/// Receives progress of a batch (e.g. prints to stderr).
pub trait Progress: Sync {
    /// `done` of `total` points estimated; called about every 1%.
    fn points(&self, done: usize, total: usize);
}

/// Progress that goes nowhere.
pub struct Silent;

impl Progress for Silent {
    fn points(&self, _: usize, _: usize) {}
}

#[derive(Debug, Clone, Copy)]
struct Emitter {
    patch: u32,
    /// Cumulative selection probability up to and including this one.
    cdf: f64,
    /// Selection probability.
    probability: f64,
}

/// A scene placed at fixed poses, ready to estimate radiosity anywhere.
pub struct PathTracer {
    rays: Raycaster,
    /// Per patch: albedo and emission of its material.
    albedo: Vec<DVec3>,
    emission: Vec<DVec3>,
    /// Per patch: its base colour texture, looked up where a path bounces
    /// (the albedo above is then the material's factor).
    textures: Vec<Option<AlbedoMap>>,
    emitters: Vec<Emitter>,
    /// Per patch: the probability that next-event estimation picks it.
    selection: Vec<f64>,
    /// The scene's point, spot and directional lights, and its sky.
    lights: Vec<lightwire_scene::Light>,
    sky: Option<lightwire_scene::Sky>,
}

impl PathTracer {
    /// Places every patch of `scene` at `poses` (one per object, indexed
    /// like [`Scene::objects`]; e.g. [`Scene::initial_poses`]).
    pub fn new(scene: &Scene, poses: &[Pose]) -> Self {
        let rays = Raycaster::new(scene, poses);
        let material = |p: usize| &scene.materials[scene.patches[p].material as usize];
        let albedo: Vec<DVec3> = (0..scene.patches.len())
            .map(|p| material(p).albedo.as_dvec3())
            .collect();
        let emission: Vec<DVec3> = (0..scene.patches.len())
            .map(|p| material(p).emission.as_dvec3())
            .collect();
        let textures = scene.patches.iter().map(|p| p.albedo_map.clone()).collect();
        let power: Vec<f64> = rays
            .patches()
            .iter()
            .zip(&emission)
            .map(|(wp, e)| wp.area * e.element_sum())
            .collect();
        let total: f64 = power.iter().sum();
        let mut emitters = Vec::new();
        let mut cdf = 0.0;
        for (p, w) in power.iter().enumerate() {
            if *w > 0.0 && total > 0.0 {
                cdf += w / total;
                emitters.push(Emitter {
                    patch: p as u32,
                    cdf,
                    probability: w / total,
                });
            }
        }
        if let Some(last) = emitters.last_mut() {
            last.cdf = 1.0;
        }
        let mut selection = vec![0.0; power.len()];
        for e in &emitters {
            selection[e.patch as usize] = e.probability;
        }
        Self {
            rays,
            albedo,
            emission,
            textures,
            emitters,
            selection,
            lights: scene.lights.clone(),
            sky: scene.sky,
        }
    }

    /// The ray caster over the placed patches.
    pub fn raycaster(&self) -> &Raycaster {
        &self.rays
    }

    /// The point at parameters `(s, t)` of patch `patch` (as
    /// [`lightwire_scene::atlas::Element::st`]), moved [`SURFACE_OFFSET`] towards the
    /// patch's centre, with the patch's normal and material. `None` for a
    /// patch id that is not in the scene.
    pub fn surface_point(&self, patch: u32, s: f64, t: f64) -> Option<SurfacePoint> {
        let wp: &WorldPatch = self.rays.patches().get(patch as usize)?;
        let sample = wp.at(s, t);
        let inward = (wp.centre() - sample).normalize_or_zero();
        Some(SurfacePoint {
            position: sample + inward * SURFACE_OFFSET,
            normal: wp.normal,
            albedo: self.albedo_at(patch as usize, sample).as_vec3(),
            emission: self.emission[patch as usize].as_vec3(),
        })
    }

    /// Estimates `B(x) = E + ρ H(x)` at the surface point `x` with unit
    /// normal `n` from `spp` paths (at least 2, so that the standard error
    /// is defined), drawing from a generator seeded with `seed`. Pass
    /// `albedo = Vec3::ONE, emission = Vec3::ZERO` for the irradiance
    /// ([`Self::estimate_irradiance`]). Rays leave from
    /// `x + n · SURFACE_OFFSET`; a point on a patch edge should first be
    /// moved onto its patch ([`Self::surface_point`]). A non-finite or zero
    /// normal receives nothing.
    pub fn estimate_point(
        &self,
        x: DVec3,
        n: DVec3,
        albedo: Vec3,
        emission: Vec3,
        spp: u32,
        seed: u64,
    ) -> Estimate {
        let n = n.normalize_or_zero();
        if !x.is_finite() {
            return self.estimate_over(DVec3::ZERO, (albedo, emission), (spp, seed), |_| x);
        }
        let origin = x + n * SURFACE_OFFSET;
        self.estimate_over(n, (albedo, emission), (spp, seed), |_| origin)
    }

    /// [`Self::estimate_point`] with each path leaving from its own point,
    /// `origin(rng)` (already off the surface), all with unit normal `n`:
    /// the mean of `B` over the points `origin` draws from.
    fn estimate_over(
        &self,
        n: DVec3,
        (albedo, emission): (Vec3, Vec3),
        (spp, seed): (u32, u64),
        mut origin: impl FnMut(&mut fastrand::Rng) -> DVec3,
    ) -> Estimate {
        let spp = spp.max(2);
        let (rho, e) = (albedo.as_dvec3(), emission.as_dvec3());
        if n == DVec3::ZERO {
            return Estimate {
                mean: emission,
                std_error: Vec3::ZERO,
                irradiance: Vec3::ZERO,
                lights: Vec3::ZERO,
            };
        }
        let mut rng = fastrand::Rng::with_seed(splitmix64(seed));
        let (mut sum, mut sum_sq, mut h_sum) = (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
        let mut lights_sum = DVec3::ZERO;
        for _ in 0..spp {
            let at = origin(&mut rng);
            let (h, lights) = self.irradiance_sample(at, n, &mut rng);
            lights_sum += lights;
            let b = e + rho * h;
            sum += b;
            sum_sq += b * b;
            h_sum += h;
        }
        let count = f64::from(spp);
        let mean = sum / count;
        // Unbiased sample variance; clamp the rounding of sum_sq - n mean².
        let variance = ((sum_sq - mean * mean * count) / (count - 1.0)).max(DVec3::ZERO);
        Estimate {
            mean: mean.as_vec3(),
            std_error: (variance / count).map(f64::sqrt).as_vec3(),
            irradiance: (h_sum / count).as_vec3(),
            lights: (lights_sum / count).as_vec3(),
        }
    }

    /// The irradiance `H(x)` at `x` with normal `n` ([`Self::estimate_point`]
    /// with albedo 1 and no emission).
    pub fn estimate_irradiance(&self, x: DVec3, n: DVec3, spp: u32, seed: u64) -> Estimate {
        self.estimate_point(x, n, Vec3::ONE, Vec3::ZERO, spp, seed)
    }

    /// Estimates every point in parallel, point `i` seeded from `seed` and
    /// `i` ([`point_seed`]), so the result does not depend on threads.
    pub fn estimate_points(
        &self,
        points: &[SurfacePoint],
        spp: u32,
        seed: u64,
        progress: &dyn Progress,
    ) -> Vec<Estimate> {
        let total = points.len();
        let step = (total / 100).max(1);
        let done = AtomicUsize::new(0);
        points
            .par_iter()
            .enumerate()
            .map(|(i, p)| {
                let estimate = self.estimate_point(
                    p.position,
                    p.normal,
                    p.albedo,
                    p.emission,
                    spp,
                    point_seed(seed, i),
                );
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                if d.is_multiple_of(step) || d == total {
                    progress.points(d, total);
                }
                estimate
            })
            .collect()
    }

    /// Estimates every element of `atlas` over its texel: each of its
    /// `spp` paths leaves from a point drawn uniformly from the region the
    /// texel stands for on its patch (`Element::region`, on a triangle its
    /// part below the diagonal), placed at the tracer's poses, so the
    /// estimate is the texel's area average, which is what a lightmap texel
    /// holds where the light changes within it (a shadow edge across it).
    /// Seeded and indexed like [`Self::estimate_elements`]; a texel that
    /// stands for no surface gets its emission.
    pub fn estimate_texels(
        &self,
        atlas: &Atlas,
        spp: u32,
        progress: &dyn Progress,
    ) -> Vec<Estimate> {
        let total = atlas.elements.len();
        let step = (total / 100).max(1);
        let done = AtomicUsize::new(0);
        (0..total)
            .into_par_iter()
            .map(|i| {
                let estimate = self.estimate_texel(atlas, i, spp);
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                if d.is_multiple_of(step) || d == total {
                    progress.points(d, total);
                }
                estimate
            })
            .collect()
    }

    /// Element `i`'s [`Self::estimate_texels`] alone (the same numbers).
    pub fn estimate_texel(&self, atlas: &Atlas, i: usize, spp: u32) -> Estimate {
        let e = &atlas.elements[i];
        match self.rays.patches().get(e.patch as usize) {
            Some(wp) if e.covers_surface() => {
                let [s0, t0, s1, t1] = e.region.map(f64::from);
                let triangle = wp.is_triangle();
                let centre = wp.centre();
                let n = wp.normal;
                self.estimate_over(n, (e.albedo, e.emission), (spp, point_seed(0, i)), |rng| {
                    let (mut s, mut t) = (s0, t0);
                    for _ in 0..64 {
                        s = s0 + (s1 - s0) * rng.f64();
                        t = t0 + (t1 - t0) * rng.f64();
                        if !triangle || t <= s {
                            break;
                        }
                    }
                    let sample = wp.at(s, t);
                    let inward = (centre - sample).normalize_or_zero();
                    sample + inward * SURFACE_OFFSET + n * SURFACE_OFFSET
                })
            }
            _ => Estimate {
                mean: e.emission,
                std_error: Vec3::ZERO,
                irradiance: Vec3::ZERO,
                lights: Vec3::ZERO,
            },
        }
    }

    /// Estimates every element of `atlas` (built from the scene this tracer
    /// was made from) at its sample point: `element.st` on its patch placed
    /// at the tracer's poses (so dynamic objects' elements are where their
    /// object is), moved onto the patch ([`Self::surface_point`]), with the
    /// element's albedo and emission. Element `i` is seeded from `i` alone
    /// (batch seed 0). Indexed like `atlas.elements`; an element whose
    /// patch is not in the scene, or that stands for no surface (a texel of
    /// a triangle's chart above its diagonal, which dilation fills), gets
    /// its emission and zero error without a path: on meshes those are
    /// nearly half the elements.
    pub fn estimate_elements(
        &self,
        atlas: &Atlas,
        spp: u32,
        progress: &dyn Progress,
    ) -> Vec<Estimate> {
        let points: Vec<SurfacePoint> = atlas
            .elements
            .iter()
            .map(|e| {
                let [s, t] = e.st.map(f64::from);
                let traced = e
                    .covers_surface()
                    .then(|| self.surface_point(e.patch, s, t));
                match traced.flatten() {
                    Some(p) => SurfacePoint {
                        albedo: e.albedo,
                        emission: e.emission,
                        ..p
                    },
                    None => SurfacePoint {
                        position: DVec3::ZERO,
                        normal: DVec3::ZERO,
                        albedo: e.albedo,
                        emission: e.emission,
                    },
                }
            })
            .collect();
        self.estimate_points(&points, spp, 0, progress)
    }

    /// One sample of the irradiance at `origin` (already off its surface)
    /// with unit normal `n`: a path with next-event estimation at every
    /// vertex (see the module doc); and the part of it that came straight
    /// from the lights and the sky.
    fn irradiance_sample(
        &self,
        origin: DVec3,
        n: DVec3,
        rng: &mut fastrand::Rng,
    ) -> (DVec3, DVec3) {
        let (mut x, mut n) = (origin, n);
        let mut h = DVec3::ZERO;
        let mut lights = DVec3::ZERO;
        let mut throughput = DVec3::ONE;
        let mut bounces = 0;
        loop {
            let surfaces = self.surface_direct(x, n, rng);
            let punctual = self.punctual_direct(x, n, rng);
            h += throughput * (surfaces + punctual);
            if bounces == 0 {
                lights += punctual;
            }
            let dir = cosine_direction(n, rng);
            let Some(hit) = self.rays.closest_hit(x, dir, f64::INFINITY) else {
                // The path leaves the scene: the sky's radiance over the
                // direction's density cos θ / π, times the cosine, is π L.
                if let Some(sky) = &self.sky {
                    let seen = sky.radiance(dir.as_vec3()).as_dvec3() * std::f64::consts::PI;
                    h += throughput * seen;
                    if bounces == 0 {
                        lights += seen;
                    }
                }
                break;
            };
            if !hit.front {
                break;
            }
            let patch = hit.patch as usize;
            let wp = &self.rays.patches()[patch];
            if self.selection[patch] > 0.0 {
                // The emitter found by the bounce, weighted against the
                // chance that next-event estimation picks the same point.
                // Its radiance E/π over the density cos θ / π is E.
                let p_bounce = n.dot(dir) * std::f64::consts::FRAC_1_PI;
                let p_light = self.light_density(patch, hit.distance, -wp.normal.dot(dir));
                h += throughput * self.emission[patch] * power_heuristic(p_bounce, p_light);
            }
            throughput *= self.albedo_at(patch, hit.point);
            bounces += 1;
            if throughput.max_element() <= 0.0 || bounces >= MAX_BOUNCES {
                break;
            }
            if bounces >= ROULETTE_AFTER {
                let q = throughput.max_element().min(0.95);
                if rng.f64() >= q {
                    break;
                }
                throughput /= q;
            }
            n = wp.normal;
            x = hit.point + n * SURFACE_OFFSET;
        }
        (h, lights)
    }

    /// The albedo of patch `patch` at the point `x` on it: its material's,
    /// times its texture there (`scene/texture.rs`).
    fn albedo_at(&self, patch: usize, x: DVec3) -> DVec3 {
        match &self.textures[patch] {
            None => self.albedo[patch],
            Some(map) => {
                let (s, t) = self.rays.patches()[patch].param(x);
                self.albedo[patch] * map.sample(s as f32, t as f32).as_dvec3()
            }
        }
    }

    /// The solid-angle density with which [`Self::direct`] samples a point
    /// of emitter `patch` at `distance`, seen at `cos_y` to its normal.
    fn light_density(&self, patch: usize, distance: f64, cos_y: f64) -> f64 {
        self.selection[patch] / self.rays.patches()[patch].area * distance * distance / cos_y
    }

    /// `Σ I(ω) cos θ / d²` over the point and spot lights `x` sees in front
    /// of it, with the spot cone and range window of
    /// `lightwire_scene::Light`; and `E_n cos θ` for each directional
    /// light whose disc, at one direction drawn uniformly over it, is open.
    fn punctual_direct(&self, x: DVec3, n: DVec3, rng: &mut fastrand::Rng) -> DVec3 {
        let mut e = DVec3::ZERO;
        for light in &self.lights {
            if let lightwire_scene::LightKind::Directional {
                direction,
                angular_radius,
            } = light.kind
            {
                let centre = -direction.as_dvec3();
                let cos = n.dot(centre);
                if cos <= 0.0 {
                    continue;
                }
                let mut dir = centre;
                if angular_radius > 0.0 {
                    let t1 = centre.any_orthonormal_vector();
                    let t2 = centre.cross(t1);
                    let r = rng.f64().sqrt() * f64::from(angular_radius).tan();
                    let phi = std::f64::consts::TAU * rng.f64();
                    dir = (centre + (t1 * phi.cos() + t2 * phi.sin()) * r).normalize();
                }
                if n.dot(dir) > 0.0 && !self.rays.occluded(x, dir, f64::INFINITY) {
                    e += light.intensity.as_dvec3() * cos;
                }
                continue;
            }
            let d = light.position.as_dvec3() - x;
            let r2 = d.length_squared();
            if r2 <= 0.0 {
                continue;
            }
            let r = r2.sqrt();
            let dir = d / r;
            let cos = n.dot(dir);
            if cos <= 0.0 {
                continue;
            }
            // Outside a spot's cone or past the range: no shadow ray.
            let i = light.intensity_towards(-dir.as_vec3(), r as f32);
            if i == Vec3::ZERO || self.rays.occluded(x, dir, r * (1.0 - 1e-9)) {
                continue;
            }
            e += i.as_dvec3() * (cos / r2);
        }
        e
    }

    /// Next-event estimate of the emitting surfaces' direct irradiance at
    /// `x` (off its surface) with normal `n`: one point on one emitter,
    /// one shadow ray, weighted against the bounce that could have found
    /// the same point.
    fn surface_direct(&self, x: DVec3, n: DVec3, rng: &mut fastrand::Rng) -> DVec3 {
        let u = rng.f64();
        let k = self.emitters.partition_point(|e| e.cdf <= u);
        let Some(emitter) = self.emitters.get(k) else {
            return DVec3::ZERO;
        };
        let patch = emitter.patch as usize;
        let wp = &self.rays.patches()[patch];
        let y = uniform_point(wp, rng.f64(), rng.f64());
        let d = y - x;
        let r2 = d.length_squared();
        if r2 <= 0.0 {
            return DVec3::ZERO;
        }
        let r = r2.sqrt();
        let dir = d / r;
        let (cos_x, cos_y) = (n.dot(dir), -wp.normal.dot(dir));
        if cos_x <= 0.0 || cos_y <= 0.0 {
            return DVec3::ZERO;
        }
        // Stop just short of the emitter: its own plane is not a blocker.
        if self.rays.occluded(x, dir, r * (1.0 - 1e-9)) {
            return DVec3::ZERO;
        }
        // (E/π) cos_x over the solid-angle density of the sample.
        let p_light = self.light_density(patch, r, cos_y);
        let weight = power_heuristic(p_light, cos_x * std::f64::consts::FRAC_1_PI);
        self.emission[patch] * (std::f64::consts::FRAC_1_PI * cos_x / p_light * weight)
    }
}

/// The point of `wp` at uniform variates `(s, t)` on the unit square: the
/// point `(s, t)` of a parallelogram; on a triangle (the half `t <= s` of
/// its frame) a point with `t > s` is mirrored across the diagonal to
/// `(t, s)`. The mirror maps the square's upper half onto the lower one
/// preserving area, so the point is uniform over the triangle (density
/// `1 / area`, as [`PathTracer::light_density`] assumes).
fn uniform_point(wp: &WorldPatch, s: f64, t: f64) -> DVec3 {
    if wp.is_triangle() && t > s {
        wp.at(t, s)
    } else {
        wp.at(s, t)
    }
}

/// Veach and Guibas's power heuristic (β = 2) for one sample from each of
/// two strategies: the weight of the strategy with density `a` where the
/// other has density `b`.
fn power_heuristic(a: f64, b: f64) -> f64 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

/// The seed of point `i` of a batch seeded with `seed`.
pub fn point_seed(seed: u64, i: usize) -> u64 {
    splitmix64(seed ^ splitmix64(i as u64))
}

/// SplitMix64's output function: neighbouring seeds give unrelated
/// generator states.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A direction about the unit normal `n` with density `cos θ / π`
/// (Malley's method: a uniform point on the unit disk lifted to the
/// hemisphere), in the orthonormal basis of Duff et al., "Building an
/// orthonormal basis, revisited" (JCGT 2017).
fn cosine_direction(n: DVec3, rng: &mut fastrand::Rng) -> DVec3 {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bt = DVec3::new(b, sign + n.y * n.y * a, -n.y);
    let (r1, r2) = (rng.f64(), rng.f64());
    let phi = std::f64::consts::TAU * r1;
    let sin_theta = r2.sqrt();
    let cos_theta = (1.0 - r2).sqrt();
    (t * (phi.cos() * sin_theta) + bt * (phi.sin() * sin_theta) + n * cos_theta).normalize()
}

/// How noisy a set of element estimates is, over the non-emitting
/// elements (the elements [`crate::accuracy::accuracy`] judges), each
/// weighted by its area.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NoiseSummary {
    /// Non-emitting elements summarised.
    pub elements: usize,
    /// `sqrt(Σ A_i |σ_i|² / Σ A_i |B_i|²)`: the NRMSE that noise alone
    /// adds to a comparison with the exact answer (same form as the
    /// metric's NRMSE).
    pub noise_nrmse: f64,
    /// Area-weighted mean of `|σ_i| / |B_i|` over the elements above the
    /// [`RELATIVE_FLOOR`].
    pub mean_relative_std_error: f64,
    /// Largest `|σ_i| / |B_i|` over the same elements.
    pub max_relative_std_error: f64,
}

/// [`NoiseSummary`] of `estimates` (indexed like `atlas.elements`). All
/// zero when nothing non-emitting is lit.
pub fn noise_summary(atlas: &Atlas, estimates: &[Estimate]) -> NoiseSummary {
    let picked: Vec<(f64, &Estimate)> = atlas
        .elements
        .iter()
        .zip(estimates)
        .filter(|(e, _)| e.emission.max_element() <= 0.0)
        .map(|(e, est)| (f64::from(e.area), est))
        .collect();
    let (mut noise, mut norm, mut magnitude, mut area) = (0.0, 0.0, 0.0, 0.0);
    for (a, est) in &picked {
        noise += a * f64::from(est.std_error.length_squared());
        norm += a * f64::from(est.mean.length_squared());
        magnitude += a * f64::from(est.mean.length());
        area += a;
    }
    let floor = if area > 0.0 {
        RELATIVE_FLOOR * magnitude / area
    } else {
        0.0
    };
    let (mut rel_sum, mut rel_area, mut rel_max) = (0.0f64, 0.0f64, 0.0f64);
    for (a, est) in &picked {
        if f64::from(est.mean.length()) > floor && floor > 0.0 {
            let r = est.relative_std_error();
            rel_sum += a * r;
            rel_area += a;
            rel_max = rel_max.max(r);
        }
    }
    NoiseSummary {
        elements: picked.len(),
        noise_nrmse: if norm > 0.0 {
            (noise / norm).sqrt()
        } else {
            0.0
        },
        mean_relative_std_error: if rel_area > 0.0 {
            rel_sum / rel_area
        } else {
            0.0
        },
        max_relative_std_error: rel_max,
    }
}

/// `std_error.json`, written next to a path-traced bake's `stats.json`.
#[derive(Debug, Serialize)]
pub struct StdErrorFile {
    pub scene: String,
    /// Paths per element.
    pub spp: u32,
    #[serde(flatten)]
    pub summary: NoiseSummary,
    /// Per element (indexed like `atlas.elements`, the order of the
    /// atlas's charts, row-major within each): atlas texel and standard
    /// error per channel (W/m²).
    pub per_element: Vec<ElementStdError>,
}

/// One element's entry in [`StdErrorFile`].
#[derive(Debug, Serialize)]
pub struct ElementStdError {
    pub texel: [u32; 2],
    pub std_error: [f32; 3],
}

/// The contents of `std_error.json` for a bake of `scene` at `spp`.
pub fn std_error_file(
    scene: &Scene,
    atlas: &Atlas,
    spp: u32,
    estimates: &[Estimate],
) -> StdErrorFile {
    StdErrorFile {
        scene: scene.name.clone(),
        spp,
        summary: noise_summary(atlas, estimates),
        per_element: atlas
            .elements
            .iter()
            .zip(estimates)
            .map(|(e, est)| ElementStdError {
                texel: e.texel,
                std_error: est.std_error.to_array(),
            })
            .collect(),
    }
}

/// Where a path-traced bake's power goes, summed over channels (W).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Power {
    /// Emitted by the scene's emitters at the bake's poses, and delivered
    /// onto the surfaces by the lights and the sky (`Σ_i A_i D_i`, `D` the
    /// estimates' [`Estimate::lights`]).
    pub emitted: f64,
    /// The lights' and the sky's part of `emitted`.
    pub lights: f64,
    /// Absorbed by surfaces, `Σ_i A_i (1 − ρ_i) H_i` over the elements
    /// (areas at the poses' scales): an estimate, with the elements'
    /// quadrature error and the path tracer's noise. In a closed scene it
    /// should equal the emitted power.
    pub absorbed: f64,
}

/// [`Power`] of element estimates (indexed like `atlas.elements`).
pub fn energy_balance(
    scene: &Scene,
    atlas: &Atlas,
    poses: &[Pose],
    estimates: &[Estimate],
) -> Power {
    let (absorbed, lights) = atlas
        .elements
        .iter()
        .zip(estimates)
        .map(|(e, est)| {
            let scale = poses
                .get(e.object as usize)
                .map_or(1.0, |p| f64::from(p.scale));
            let a = f64::from(e.area) * scale * scale;
            (
                a * ((DVec3::ONE - e.albedo.as_dvec3()) * est.irradiance.as_dvec3()).element_sum(),
                a * f64::from(est.lights.element_sum()),
            )
        })
        .fold((0.0, 0.0), |(x, y), (p, q)| (x + p, y + q));
    Power {
        emitted: f64::from(scene.emitted_power(poses).element_sum()) + lights,
        lights,
        absorbed,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_directions_are_unit_above_the_surface_with_mean_cosine_two_thirds() {
        let mut rng = fastrand::Rng::with_seed(3);
        for n in [
            DVec3::Y,
            -DVec3::Z,
            DVec3::Z,
            DVec3::new(1.0, 2.0, -3.0).normalize(),
        ] {
            let k = 20_000;
            let mut mean_cos = 0.0;
            for _ in 0..k {
                let d = cosine_direction(n, &mut rng);
                assert!((d.length() - 1.0).abs() < 1e-12);
                let c = d.dot(n);
                assert!(c > 0.0, "{d} below {n}");
                mean_cos += c / f64::from(k);
            }
            // E[cos θ] under cos θ / π is 2/3; its sd is 0.236/√k.
            assert!((mean_cos - 2.0 / 3.0).abs() < 0.01, "{n}: {mean_cos}");
        }
    }

    #[test]
    fn seeds_of_neighbouring_points_differ() {
        let seeds: std::collections::HashSet<u64> = (0..1000).map(|i| point_seed(0, i)).collect();
        assert_eq!(seeds.len(), 1000);
    }
}
