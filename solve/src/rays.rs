//! The ray solver: gathering radiosity with form factors estimated by rays
//! that are cast once and kept, on the CPU.
//!
//! Gathering (thesis §4.2) sets every element's radiosity from what its
//! hemisphere sees, `B_i = E_i + ρ_i H_i`, and repeats (a Jacobi iteration
//! of the radiosity equation, thesis §2.3). A hemicube per element and
//! bounce costs elements x patches per bounce, which a level of 60,000
//! elements and 9,000 patches cannot pay; a ray-cast gather sweep
//! (`gpu::Correction::by_rays`) costs elements x rays x log(patches), but
//! casting the rays again every bounce still costs seconds per bounce, and
//! a closed room with near-white walls needs dozens of bounces.
//!
//! The rays do not change between bounces; only the radiosity they read
//! does. So each valid element casts its `side`² stratified
//! cosine-distributed rays once against the bounding volume hierarchy and
//! keeps where they landed as a sparse row: the elements each hit reads
//! (bilinear between the texels around the hit, as a client samples the
//! lightmap, `direct::Lookup::Bilinear`) and their weights, merged per
//! element. Such a row is a Monte Carlo estimate of the element's form
//! factors to every other element (the point-to-area form factor is the
//! share of cosine-distributed directions that reach an area, thesis
//! §2.2.1). The emitters' own light is integrated once per element by
//! next-event estimation (`direct::Emitters::irradiance_within`, `grid`²
//! shadow rays shared among the emitters by what each gives): a
//! hemisphere's rays would find a small lamp with a handful of hits. Every bounce after that is a sparse matrix-vector
//! product over the kept rows, milliseconds where a sweep of rays takes
//! seconds:
//!
//! `B_i = E_i + ρ_i (D_i + Σ_j w_ij (B_j - E_j))`,
//!
//! `D_i` the direct irradiance and `B - E` the reflected light (the
//! emission is all in `D`; an emitter's reflected light is read by the
//! rays like any other surface's). The radiosity the rows read is filled
//! at invalid texels from their valid neighbours first
//! (`Validity::dilate`), as a client would see it.
//!
//! The fixed point is the one a ray-cast correction sweep converges to
//! (`gpu::Correction`), without progressive refinement in between: on
//! the garage level it gives the lightmap in a fraction of the time
//! (BENCHMARKS.md, section 9). The rays are the same for every bounce, so
//! the estimate's noise is a fixed pattern, not flicker.

use std::time::{Duration, Instant};

use glam::Vec3;
use rayon::prelude::*;

use crate::direct::{Emitters, Lookup, lookup_weights};
use crate::raycast::sample_point;
use crate::raycast::{CosineGrid, Raycaster};
use crate::validity::Validity;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

/// Cosine-distributed rays per element by default, `SIDE`² (as a ray-cast
/// correction sweep, `gpu::RAY_SIDE`).
pub const SIDE: usize = 16;

/// Elements whose rays are cast between two progress reports.
const CHUNK: usize = 2048;

/// Largest ratio of two successive sweeps' changes the convergence
/// estimate believes: a slower decay is taken as this one.
const MAX_DECAY: f64 = 0.995;

/// One element's kept rays: the elements they read, in order, and the
/// weight of each (its bilinear weights summed over the rays, over the ray
/// count).
type Row = (Vec<u32>, Vec<f32>);

/// Gathering over kept rays (see the module doc).
pub struct RaySolver {
    /// The valid elements of present objects, which gather; the others
    /// are filled from them.
    receivers: Vec<u32>,
    /// Row `r` of receiver `r`: `columns[starts[r]..starts[r + 1]]` with
    /// the same range of `weights` (each hit's bilinear weight over the
    /// ray count).
    starts: Vec<usize>,
    columns: Vec<u32>,
    weights: Vec<f32>,
    /// Direct irradiance from the emission, per receiver cast so far.
    direct: Vec<Vec3>,
    /// Irradiance per receiver at the last sweep.
    irradiance: Vec<Vec3>,
    /// `B` per element.
    radiosity: Vec<Vec3>,
    /// `E` and `ρ` per element.
    emission: Vec<Vec3>,
    albedo: Vec<Vec3>,
    /// World area per element.
    areas: Vec<f32>,
    validity: Validity,
    emitted: f64,
    /// With point or spot lights: the power of the direct light (theirs
    /// and the emitting surfaces') the receivers reflect, which the sweeps'
    /// changes are measured against beside the emitted power (a scene lit
    /// only by lights emits nothing from its surfaces).
    lit: f64,
    /// The power the lights and the sky deliver onto the receivers
    /// (`Σ A D` of their direct light).
    delivered: f64,
    sweeps: usize,
    /// Power the last sweep changed, and the one before, as fractions of
    /// the emitted power.
    changes: (f64, f64),
    /// What casting needs, until every receiver is cast.
    casting: Option<Casting>,
}

/// The scene as the rays see it while they are cast.
struct Casting {
    caster: Raycaster,
    emitters: Emitters,
    directions: CosineGrid,
    grid: usize,
}

impl RaySolver {
    /// Finds the valid elements of `atlas` at `poses`, casts each one's
    /// `side`² cosine rays and `grid`² shadow rays, and keeps the rows;
    /// `progress(done, total)` hears of the elements cast. The shadow rays
    /// are shared among the emitters (`Emitters::irradiance_within`).
    /// Radiosity starts at `E + ρ D` (emission and direct light).
    pub fn new(
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        rays: (usize, usize),
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Self {
        let validity = Validity::compute(scene, atlas, poses);
        let mut solver = Self::prepare(scene, atlas, (poses, &[]), validity, rays);
        while !solver.cast_next(scene, atlas, poses, CHUNK) {
            progress(solver.cast(), solver.receivers.len());
        }
        progress(solver.cast(), solver.receivers.len());
        solver
    }

    /// A solver for `scene` at `poses` without the objects flagged in
    /// `absent` (a cross session's static set, thesis §4.5.2), whose valid
    /// elements `validity` gives, with nothing cast yet: cast with
    /// [`RaySolver::cast_next`] (a live session does it a slice at a time).
    pub fn prepare(
        scene: &Scene,
        atlas: &Atlas,
        (poses, absent): (&[Pose], &[bool]),
        validity: Validity,
        (side, grid): (usize, usize),
    ) -> Self {
        let is_absent = |o: u32| -> bool { absent.get(o as usize).copied().unwrap_or(false) };
        let receivers: Vec<u32> = (0..atlas.elements.len() as u32)
            .filter(|&i| {
                !validity.is_invalid(i as usize) && !is_absent(atlas.elements[i as usize].object)
            })
            .collect();
        let emission: Vec<Vec3> = atlas
            .elements
            .iter()
            .map(|e| {
                if is_absent(e.object) {
                    Vec3::ZERO
                } else {
                    e.emission
                }
            })
            .collect();
        let albedo: Vec<Vec3> = atlas.elements.iter().map(|e| e.albedo).collect();
        let areas: Vec<f32> = atlas
            .elements
            .iter()
            .map(|e| {
                let s = poses.get(e.object as usize).map_or(1.0, |p| p.scale);
                e.area * s * s
            })
            .collect();
        let emitted = emission
            .iter()
            .zip(&areas)
            .map(|(e, a)| f64::from(*a) * f64::from(e.element_sum()))
            .sum();
        Self {
            starts: vec![0],
            columns: Vec::new(),
            weights: Vec::new(),
            direct: Vec::with_capacity(receivers.len()),
            irradiance: Vec::new(),
            radiosity: emission.clone(),
            receivers,
            emission,
            albedo,
            areas,
            validity,
            emitted,
            lit: 0.0,
            delivered: 0.0,
            sweeps: 0,
            changes: (1.0, 1.0),
            casting: Some(Casting {
                caster: Raycaster::with_absent(scene, poses, absent),
                emitters: Emitters::of(scene),
                directions: CosineGrid::new(side),
                grid,
            }),
        }
    }

    /// Casts the rays of up to `count` more receivers (in parallel) and
    /// keeps their rows; returns whether every receiver is cast. `scene`,
    /// `atlas` and `poses` must be those the solver was prepared with.
    pub fn cast_next(
        &mut self,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        count: usize,
    ) -> bool {
        let Some(casting) = &self.casting else {
            return true;
        };
        let done = self.direct.len();
        let end = done.saturating_add(count).min(self.receivers.len());
        let emission = &self.emission;
        let cast: Vec<(Vec3, Vec3, Row)> = self.receivers[done..end]
            .par_iter()
            .map(|&i| casting.cast(scene, atlas, poses, i, emission))
            .collect();
        for ((d, lights, (c, w)), &i) in cast.into_iter().zip(&self.receivers[done..end]) {
            self.radiosity[i as usize] = self.emission[i as usize] + self.albedo[i as usize] * d;
            self.delivered += f64::from(self.areas[i as usize]) * f64::from(lights.element_sum());
            if crate::lights::any(scene) {
                // The lights' power enters as the first reflection of
                // their direct light (the emitters' as their emission).
                let reflected = self.albedo[i as usize] * d;
                self.lit += f64::from(self.areas[i as usize]) * f64::from(reflected.element_sum());
            }
            self.direct.push(d);
            self.columns.extend(c);
            self.weights.extend(w);
            self.starts.push(self.columns.len());
        }
        if end < self.receivers.len() {
            return false;
        }
        self.casting = None;
        self.irradiance = self.direct.clone();
        true
    }

    /// Receivers cast so far.
    pub fn cast(&self) -> usize {
        self.direct.len()
    }

    /// Whether every receiver's rays are cast (sweeps may run).
    pub fn is_cast(&self) -> bool {
        self.casting.is_none()
    }

    /// One bounce: every receiver gathers the reflected light its kept
    /// rays read. `atlas` must be the one the solver was built on; nothing
    /// happens before every receiver is cast.
    pub fn sweep(&mut self, atlas: &Atlas) {
        if !self.is_cast() {
            return;
        }
        let mut seen = self.radiosity.clone();
        self.validity.dilate(atlas, &mut seen);
        for (s, e) in seen.iter_mut().zip(&self.emission) {
            *s = (*s - *e).max(Vec3::ZERO);
        }
        let irradiance: Vec<Vec3> = (0..self.receivers.len())
            .into_par_iter()
            .map(|r| {
                let range = self.starts[r]..self.starts[r + 1];
                let reflected: Vec3 = self.columns[range.clone()]
                    .iter()
                    .zip(&self.weights[range])
                    .map(|(&j, &w)| seen[j as usize] * w)
                    .sum();
                self.direct[r] + reflected
            })
            .collect();
        let mut change = 0.0f64;
        for (r, &i) in self.receivers.iter().enumerate() {
            let i = i as usize;
            let b = self.emission[i] + self.albedo[i] * irradiance[r];
            change +=
                f64::from(self.areas[i]) * f64::from((b - self.radiosity[i]).abs().element_sum());
            self.radiosity[i] = b;
        }
        self.irradiance = irradiance;
        let source = self.emitted + self.lit;
        let change = if source > 0.0 { change / source } else { 0.0 };
        self.changes = (change, self.changes.0);
        self.sweeps += 1;
    }

    /// Sweeps until [`RaySolver::residual_fraction`] is at most
    /// `tolerance`, or `budget` is spent (at least one sweep);
    /// `progress(sweep, residual)` hears of each. Returns whether the
    /// tolerance was met (false at once before every receiver is cast).
    pub fn solve(
        &mut self,
        atlas: &Atlas,
        tolerance: f64,
        budget: Option<Duration>,
        progress: &dyn Fn(usize, f64),
    ) -> bool {
        if !self.is_cast() {
            return false;
        }
        let started = Instant::now();
        loop {
            self.sweep(atlas);
            progress(self.sweeps, self.residual_fraction());
            if self.residual_fraction() <= tolerance {
                return true;
            }
            if budget.is_some_and(|b| started.elapsed() >= b) {
                return false;
            }
        }
    }

    /// The power the sweeps still have to add, as a fraction of the
    /// emitted power, extrapolated from the last two sweeps' changes as a
    /// geometric series (each bounce carries a roughly fixed share of the
    /// last one's light on): `c r / (1 - r)` with `c` the last change and
    /// `r` its ratio to the one before. 1 before the second sweep.
    pub fn residual_fraction(&self) -> f64 {
        if self.sweeps < 2 {
            return 1.0;
        }
        let (last, before) = self.changes;
        if last <= 0.0 {
            return 0.0;
        }
        let ratio = if before > 0.0 {
            (last / before).min(MAX_DECAY)
        } else {
            MAX_DECAY
        };
        last * ratio / (1.0 - ratio)
    }

    /// Bounces gathered so far.
    pub fn sweeps(&self) -> usize {
        self.sweeps
    }

    /// Kept row entries (element, weight), 8 bytes each.
    pub fn kept_entries(&self) -> usize {
        self.columns.len()
    }

    /// Radiosity per element; invalid elements hold their emission (the
    /// publication path fills them, `Validity::dilate`).
    pub fn radiosity(&self) -> &[Vec3] {
        &self.radiosity
    }

    /// Which elements are invalid.
    pub fn validity(&self) -> &Validity {
        &self.validity
    }

    /// Emitted and absorbed power (W, channels summed), and the part of
    /// the emitted power the lights and the sky deliver onto the
    /// receivers (`Σ A D`, their direct light): each valid element
    /// absorbs `A (1 - ρ) H` of the irradiance of the last sweep, direct
    /// light included.
    pub fn power(&self) -> (f64, f64, f64) {
        let absorbed = self
            .receivers
            .iter()
            .zip(&self.irradiance)
            .map(|(&i, h)| {
                let i = i as usize;
                f64::from(self.areas[i])
                    * f64::from(((Vec3::ONE - self.albedo[i]) * *h).element_sum())
            })
            .sum();
        (self.emitted + self.delivered, absorbed, self.delivered)
    }
}

impl Casting {
    /// Element `i`'s direct irradiance from `emission` and the lights,
    /// the lights' (and the sky's) part of it, and its row.
    fn cast(
        &self,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        i: u32,
        emission: &[Vec3],
    ) -> (Vec3, Vec3, Row) {
        let caster = &self.caster;
        let (x, n) = sample_point(scene, caster, atlas, poses, i as usize);
        let lights =
            crate::lights::texel_irradiance(scene, caster, (atlas, poses), i as usize, (x, n));
        let direct = self.emitters.irradiance_within(
            caster,
            atlas,
            (x, n),
            (self.grid, self.grid * self.grid),
            |j| emission[j],
        ) + lights;
        let per_ray = 1.0 / self.directions.len().max(1) as f32;
        let mut hits: Vec<(u32, f32)> = Vec::with_capacity(self.directions.len() * 4);
        let mut sky = Vec3::ZERO;
        // Each receiver its own shift of the stratified grid: a small
        // bright patch (the sun through a window) then reads as noise
        // across a wall, not as streaks (`CosineGrid::around_shifted`).
        let mut rng = fastrand::Rng::with_seed(u64::from(i).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let shift = (rng.f64(), rng.f64());
        for d in self.directions.around_shifted(n, shift) {
            let Some(hit) = caster.closest_hit(x, d, f64::INFINITY) else {
                // A ray that leaves the scene sees the sky: with
                // cosine-distributed rays, π times the mean radiance they
                // find is its irradiance.
                if let Some(s) = &scene.sky {
                    sky += s.radiance(d.as_vec3()) * (std::f32::consts::PI * per_ray);
                }
                continue;
            };
            // A back face gives nothing (the inside of a closed prop).
            if !hit.front {
                continue;
            }
            if let Some(w) = lookup_weights(caster, atlas, hit.patch, hit.point, Lookup::Bilinear) {
                hits.extend(
                    w.iter()
                        .filter(|(_, w)| *w > 0.0)
                        .map(|&(j, w)| (j as u32, w * per_ray)),
                );
            }
        }
        let (direct, lights) = (direct + sky, lights + sky);
        hits.sort_unstable_by_key(|h| h.0);
        let mut row: Row = (Vec::new(), Vec::new());
        for (j, w) in hits {
            if row.0.last() == Some(&j) {
                if let Some(last) = row.1.last_mut() {
                    *last += w;
                }
            } else {
                row.0.push(j);
                row.1.push(w);
            }
        }
        (direct, lights, row)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use lightwire_scene::LoadOptions;
    use lightwire_scene::load::load_scene;

    fn furnace() -> (Scene, Atlas) {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/furnace.json");
        load_scene(&path, LoadOptions::default()).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Inside a closed box every ray lands on a face, so every kept row's
    /// weights sum to 1: no light is lost or made by the kept rows.
    #[test]
    fn in_a_closed_box_every_kept_row_sums_to_one() {
        let (scene, atlas) = furnace();
        let poses = scene.initial_poses();
        let solver = RaySolver::new(&scene, &atlas, &poses, (8, 4), &|_, _| {});
        assert!(!solver.receivers.is_empty());
        for r in 0..solver.receivers.len() {
            let sum: f32 = solver.weights[solver.starts[r]..solver.starts[r + 1]]
                .iter()
                .sum();
            assert!((sum - 1.0).abs() < 1e-4, "row {r} sums to {sum}");
        }
    }

    /// The furnace (a closed box, albedo 0.5, emission 1 everywhere)
    /// converges to `E / (1 - ρ) = 2` at every valid element, within 0.5%:
    /// the emission's direct light is exact (the point-to-polygon form
    /// factors of the five other faces sum to 1) and the bounces lose
    /// nothing. A solver that dropped the emitters' reflected light, or
    /// counted their emission twice (by next-event estimation and by
    /// rays), would read 1.5 or 2.5.
    #[test]
    fn the_furnace_converges_to_e_over_one_minus_rho() {
        let (scene, atlas) = furnace();
        let poses = scene.initial_poses();
        let mut solver = RaySolver::new(&scene, &atlas, &poses, (8, 4), &|_, _| {});
        assert!(solver.solve(&atlas, 1e-6, None, &|_, _| {}));
        for &i in &solver.receivers {
            let b = solver.radiosity()[i as usize];
            for c in 0..3 {
                assert!((b[c] - 2.0).abs() <= 0.01, "element {i}: {b}");
            }
        }
        let (emitted, absorbed, _) = solver.power();
        assert!(
            (absorbed / emitted - 1.0).abs() < 0.01,
            "absorbed {absorbed} of {emitted}"
        );
    }
}
