//! The reference solver: slow, simple, independent, and trusted.
//!
//! It shares no radiosity code with the GPU solvers (it reads only the
//! validated scene and the atlas's element list) so that tests comparing the
//! two mean something. The method is the classical one:
//!
//! 1. **Form factors** (thesis §2.2.1). Element `j` emits from the region
//!    of its patch it stands for (a cell, half cell or quarter cell; see
//!    [`crate::atlas`]); the regions tile every patch. From a point `x`, the
//!    form factor to region `j` is the exact point-to-polygon value
//!    ([`form_factor::point_to_polygon`]) times the fraction of shadow rays
//!    from `x` to a stratified grid on region `j` that arrive
//!    ([`bvh::Bvh`]). `F_ij` averages that over a grid of points on region
//!    `i` (a Galerkin form factor with constant basis functions: it obeys
//!    reciprocity `A_i F_ij = A_j F_ji` up to quadrature error, so the
//!    discrete system conserves energy). Both grids are 1, 2×2 or 4×4
//!    depending on how close the regions are compared with their size,
//!    which is where the integrand varies and partial occlusion matters.
//!    For an unoccluded closed scene `Σ_j F_ij = 1` exactly.
//! 2. **Solve** `B_i = E_i + ρ_i Σ_j F_ij B_j` (thesis eq. 2.2.2) by Jacobi
//!    iteration on the dense matrix, starting from `B = E`. Each sweep
//!    propagates one more bounce; iteration stops when the power added by a
//!    sweep, `Σ_i A_i |ΔB_i|`, falls below a fraction (default 1e-4) of the
//!    emitted power `Σ_i A_i E_i`.
//! 3. **Point values.** A lightmap stores radiosity at texel sample points
//!    (on patch edges, thesis §4.1), not region averages. A final gather
//!    evaluates `B(x_i) = E_i + ρ_i Σ_j F(x_i → j) B_j` at every sample, with
//!    the point form factors kept in a second matrix. Samples at the same
//!    world position on two coplanar patches therefore get the same value.
//!
//! The dense matrix costs `4 N²` bytes; [`MAX_ELEMENTS`] keeps that bounded.
//! Rows are computed and iterated in parallel with rayon.

pub mod bvh;
pub mod form_factor;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::atlas::Atlas;
use crate::scene::{Pose, Scene};
use bvh::{Bvh, Parallelogram};

/// Largest element count the dense reference solver accepts (two matrices
/// of 1.6 GB each).
pub const MAX_ELEMENTS: usize = 20_000;

/// Distance of shadow-ray end points from their surfaces (m), and of the
/// sample point from a patch edge, so that rays leaving a corner do not
/// start inside the adjacent wall.
const SURFACE_OFFSET: f64 = 1e-5;

/// Why the reference solver refused a problem.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    #[error(
        "the reference solver keeps a dense {n} x {n} form factor matrix and accepts at most {MAX_ELEMENTS} elements; lower the scene's texel_density (e.g. --density-scale)"
    )]
    TooManyElements { n: usize },
}

/// Settings for [`ReferenceSolver::solve`].
#[derive(Debug, Clone, Copy)]
pub struct SolveOptions {
    /// Stop when the power added by one sweep is below this fraction of the
    /// emitted power.
    pub tolerance: f64,
    /// Give up after this many sweeps.
    pub max_iterations: usize,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-4,
            max_iterations: 100_000,
        }
    }
}

/// Receives progress while the solver works (e.g. prints to stderr).
pub trait Progress: Sync {
    /// `done` of `total` form-factor rows computed.
    fn form_factors(&self, done: usize, total: usize);
    /// One more Jacobi sweep finished; `residual` is its power fraction.
    fn iteration(&self, iteration: usize, residual: f64);
}

/// Progress that goes nowhere.
pub struct Silent;

impl Progress for Silent {
    fn form_factors(&self, _: usize, _: usize) {}
    fn iteration(&self, _: usize, _: f64) {}
}

/// One element placed in the world, as the reference solver sees it.
#[derive(Debug, Clone, Copy)]
struct WorldElement {
    /// The texel's sample point, nudged off edges and off the surface.
    x: DVec3,
    normal: DVec3,
    area: f64,
    patch: u32,
    /// Corners of the region the element emits from.
    region: [DVec3; 4],
    albedo: DVec3,
    emission: DVec3,
}

/// A scene placed at fixed poses with its form factors computed.
pub struct ReferenceSolver {
    elements: Vec<WorldElement>,
    patches: Vec<WorldPatch>,
    /// Galerkin form factors, row-major `N × N`; row `i` is what element
    /// `i` receives from.
    matrix: Vec<f32>,
    /// Point form factors from each element's sample point, `N × N`.
    point_matrix: Vec<f32>,
    /// Seconds spent computing form factors.
    pub form_factor_seconds: f64,
}

#[derive(Debug, Clone, Copy)]
struct WorldPatch {
    shape: Parallelogram,
    normal: DVec3,
    first: usize,
    end: usize,
}

/// What a solve produced.
#[derive(Debug, Clone)]
pub struct Solution {
    /// Radiosity at each element's sample point (W/m² per channel): what
    /// the lightmap stores.
    pub radiosity: Vec<Vec3>,
    /// Mean radiosity over each element's region: the unknowns of the
    /// solved system.
    pub region_radiosity: Vec<Vec3>,
    /// Irradiance per element region: `H_i = Σ_j F_ij B_j`.
    pub irradiance: Vec<Vec3>,
    /// Jacobi sweeps performed.
    pub iterations: usize,
    /// Power added by the last sweep as a fraction of emitted power.
    pub residual_fraction: f64,
    /// Seconds spent iterating (form factors not included).
    pub seconds: f64,
}

/// Power bookkeeping of a solution, per channel (W).
#[derive(Debug, Clone, Copy)]
pub struct EnergyBalance {
    pub emitted: DVec3,
    pub absorbed: DVec3,
    pub escaped: DVec3,
}

fn dvec(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

impl ReferenceSolver {
    /// Places every element at `poses` (one per object) and computes the
    /// form factor matrix.
    pub fn new(
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        progress: &dyn Progress,
    ) -> Result<Self, ReferenceError> {
        let n = atlas.elements.len();
        if n > MAX_ELEMENTS {
            return Err(ReferenceError::TooManyElements { n });
        }
        let started = Instant::now();
        let patches: Vec<WorldPatch> = scene
            .patches
            .iter()
            .enumerate()
            .map(|(p, patch)| {
                let pose = &poses[patch.object as usize];
                let (origin, u, v) = patch.shape.transformed(pose).frame();
                let range = atlas.elements_of(p as u32);
                WorldPatch {
                    shape: Parallelogram::new(dvec(origin), dvec(u), dvec(v)),
                    normal: dvec(u).cross(dvec(v)).normalize(),
                    first: range.start,
                    end: range.end,
                }
            })
            .collect();
        let elements: Vec<WorldElement> = atlas
            .elements
            .iter()
            .map(|e| {
                let wp = &patches[e.patch as usize];
                let (o, u, v) = (wp.shape.origin, wp.shape.u, wp.shape.v);
                let at = |s: f64, t: f64| o + u * s + v * t;
                let [s, t] = [f64::from(e.st[0]), f64::from(e.st[1])];
                // Nudge toward the patch centre so a sample on an edge is
                // unambiguously on its own patch, then off the surface.
                let sample = at(s, t);
                let inward = (at(0.5, 0.5) - sample).normalize_or_zero();
                let x = sample + inward * SURFACE_OFFSET + wp.normal * SURFACE_OFFSET;
                let [s0, t0, s1, t1] = e.region.map(f64::from);
                let scale = f64::from(poses[e.object as usize].scale);
                WorldElement {
                    x,
                    normal: wp.normal,
                    area: f64::from(e.area) * scale * scale,
                    patch: e.patch,
                    region: [at(s0, t0), at(s1, t0), at(s1, t1), at(s0, t1)],
                    albedo: dvec(e.albedo),
                    emission: dvec(e.emission),
                }
            })
            .collect();
        let bvh = Bvh::new(patches.iter().map(|p| p.shape).collect());

        let mut matrix = vec![0.0f32; n * n];
        let mut point_matrix = vec![0.0f32; n * n];
        let done = AtomicUsize::new(0);
        if n > 0 {
            matrix
                .par_chunks_mut(n)
                .zip(point_matrix.par_chunks_mut(n))
                .enumerate()
                .for_each(|(i, (row, point_row))| {
                    fill_row(&elements, &patches, &bvh, i, row, point_row);
                    let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                    if d.is_multiple_of(256) || d == n {
                        progress.form_factors(d, n);
                    }
                });
        }
        Ok(Self {
            elements,
            patches,
            matrix,
            point_matrix,
            form_factor_seconds: started.elapsed().as_secs_f64(),
        })
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.elements.len()
    }

    /// Whether the scene has no elements.
    pub fn is_empty(&self) -> bool {
        self.elements.is_empty()
    }

    /// The stored form factor `F_ij`: the fraction of the light leaving
    /// element `i` that reaches element `j`, as seen from `i`'s sample.
    pub fn form_factor(&self, i: usize, j: usize) -> f64 {
        f64::from(self.matrix[i * self.len() + j])
    }

    /// Area of element `i` at the solver's poses.
    pub fn area(&self, i: usize) -> f64 {
        self.elements[i].area
    }

    /// Number of patches in the scene.
    pub fn patch_count(&self) -> usize {
        self.patches.len()
    }

    /// Elements of patch `p`.
    pub fn patch_elements(&self, p: usize) -> std::ops::Range<usize> {
        self.patches[p].first..self.patches[p].end
    }

    /// Solves for radiosity by Jacobi iteration.
    pub fn solve(&self, options: SolveOptions, progress: &dyn Progress) -> Solution {
        let started = Instant::now();
        let mut b = self.emission();
        let mut h = vec![DVec3::ZERO; self.len()];
        let mut iterations = 0;
        let mut residual = f64::INFINITY;
        while iterations < options.max_iterations {
            let (next, gathered, fraction) = self.sweep(&b);
            (b, h, residual) = (next, gathered, fraction);
            iterations += 1;
            progress.iteration(iterations, residual);
            if residual < options.tolerance {
                break;
            }
        }
        // Irradiance consistent with the final radiosity.
        if iterations > 0 {
            h = self.gather(&b);
        }
        Solution {
            radiosity: self.point_radiosity(&b),
            region_radiosity: b.iter().map(|v| v.as_vec3()).collect(),
            irradiance: h.iter().map(|v| v.as_vec3()).collect(),
            iterations,
            residual_fraction: residual,
            seconds: started.elapsed().as_secs_f64(),
        }
    }

    /// How long this solver takes to come within `target` NRMSE (see
    /// [`crate::metrics::accuracy`]; `atlas` is the one this solver was
    /// built on) of the lightmap `goal`: Jacobi sweeps from `B = E` as in
    /// [`Self::solve`], the point values evaluated after each. Returns the
    /// sweeps and the seconds they took, not counting the point evaluations
    /// (which `solve` does once, at the end), or `None` when
    /// `max_iterations` sweeps do not get there. This is how a benchmark
    /// compares another solver with this one "at equal NRMSE".
    ///
    /// `keep` narrows the compared elements as in
    /// [`crate::metrics::accuracy_where`].
    pub fn sweeps_to_nrmse(
        &self,
        atlas: &Atlas,
        goal: &[Vec3],
        target: f64,
        max_iterations: usize,
        keep: &dyn Fn(usize) -> bool,
    ) -> Option<(usize, f64)> {
        let mut b = self.emission();
        let mut seconds = 0.0;
        for iterations in 1..=max_iterations {
            let started = Instant::now();
            b = self.sweep(&b).0;
            seconds += started.elapsed().as_secs_f64();
            let error =
                crate::metrics::accuracy_where(atlas, &self.point_radiosity(&b), goal, keep)?.nrmse;
            if error <= target {
                return Some((iterations, seconds));
            }
        }
        None
    }

    /// Emitted radiosity of every element: where Jacobi iteration starts.
    fn emission(&self) -> Vec<DVec3> {
        self.elements.iter().map(|e| e.emission).collect()
    }

    /// One Jacobi sweep from `b`: the next radiosity, the irradiance it was
    /// computed from, and the power it added as a fraction of the emitted
    /// power (`Σ_i A_i |ΔB_i| / Σ_i A_i E_i`, 0 in a dark scene).
    fn sweep(&self, b: &[DVec3]) -> (Vec<DVec3>, Vec<DVec3>, f64) {
        let h = self.gather(b);
        let next: Vec<DVec3> = self
            .elements
            .iter()
            .zip(&h)
            .map(|(e, hi)| e.emission + e.albedo * *hi)
            .collect();
        let (mut added, mut emitted) = (0.0, 0.0);
        for ((e, bn), bo) in self.elements.iter().zip(&next).zip(b) {
            added += e.area * (*bn - *bo).abs().element_sum();
            emitted += e.area * e.emission.element_sum();
        }
        let fraction = if emitted > 0.0 { added / emitted } else { 0.0 };
        (next, h, fraction)
    }

    /// Radiosity at each element's sample point given region radiosity `b`
    /// (step 3 of the module docs).
    fn point_radiosity(&self, b: &[DVec3]) -> Vec<Vec3> {
        gather_rows(&self.point_matrix, self.len(), b)
            .iter()
            .zip(&self.elements)
            .map(|(hp, e)| (e.emission + e.albedo * *hp).as_vec3())
            .collect()
    }

    /// `H_i = Σ_j F_ij B_j` for every element, in parallel.
    fn gather(&self, b: &[DVec3]) -> Vec<DVec3> {
        gather_rows(&self.matrix, self.len(), b)
    }

    /// Where the power of a solution goes: absorbed by surfaces
    /// (`Σ A_i (1-ρ_i) H_i`) or escaped to infinity
    /// (`Σ A_i B_i (1 - Σ_j F_ij)`). In a converged, energy-conserving
    /// discretisation the two add up to the emitted power.
    pub fn energy_balance(&self, solution: &Solution) -> EnergyBalance {
        let n = self.len();
        let mut balance = EnergyBalance {
            emitted: DVec3::ZERO,
            absorbed: DVec3::ZERO,
            escaped: DVec3::ZERO,
        };
        for (i, e) in self.elements.iter().enumerate() {
            let row_sum: f64 = self.matrix[i * n..(i + 1) * n]
                .iter()
                .map(|f| f64::from(*f))
                .sum();
            balance.emitted += e.area * e.emission;
            balance.absorbed += e.area * (DVec3::ONE - e.albedo) * dvec(solution.irradiance[i]);
            balance.escaped +=
                e.area * dvec(solution.region_radiosity[i]) * (1.0 - row_sum).max(0.0);
        }
        balance
    }
}

/// `H_i = Σ_j M_ij B_j` for every row of an `n × n` matrix, in parallel.
fn gather_rows(matrix: &[f32], n: usize, b: &[DVec3]) -> Vec<DVec3> {
    if n == 0 {
        return Vec::new();
    }
    matrix
        .par_chunks(n)
        .map(|row| {
            let mut acc = DVec3::ZERO;
            for (f, bj) in row.iter().zip(b) {
                if *f != 0.0 {
                    acc += *bj * f64::from(*f);
                }
            }
            acc
        })
        .collect()
}

/// Computes row `i` of the Galerkin and of the point form factor matrix.
fn fill_row(
    elements: &[WorldElement],
    patches: &[WorldPatch],
    bvh: &Bvh,
    i: usize,
    row: &mut [f32],
    point_row: &mut [f32],
) {
    let ei = &elements[i];
    for (p, patch) in patches.iter().enumerate() {
        if p as u32 == ei.patch {
            continue; // A planar patch does not see itself.
        }
        // Some of the receiver must be in front of the source patch ...
        let front = |y: &DVec3| patch.normal.dot(*y - patch.shape.origin) > 0.0;
        if !ei.region.iter().any(front) && !front(&ei.x) {
            continue;
        }
        // ... and some of the patch above the receiver's horizon.
        let s = &patch.shape;
        let corners = [
            s.origin,
            s.origin + s.u,
            s.origin + s.u + s.v,
            s.origin + s.v,
        ];
        let horizon = ei.region[0] - ei.normal * SURFACE_OFFSET;
        if corners.iter().all(|c| ei.normal.dot(*c - horizon) <= 0.0) {
            continue;
        }
        for j in patch.first..patch.end {
            let ej = &elements[j];
            point_row[j] = point_to_region(ei.x, ei, ej, bvh) as f32;
            row[j] = region_to_region(ei, ej, bvh) as f32;
        }
    }
}

/// Sub-samples per axis for integrating over a region of size `size` seen
/// from `distance` away.
fn grid(distance: f64, size: f64) -> usize {
    if distance > 6.0 * size {
        1
    } else if distance > 2.0 * size {
        2
    } else {
        FINEST_GRID
    }
}

/// Centre of cell `(a, b)` of a `k × k` grid on a region.
fn grid_point(region: &[DVec3; 4], k: usize, a: usize, b: usize) -> DVec3 {
    let [o, p, _, q] = *region;
    o + (p - o) * ((a as f64 + 0.5) / k as f64) + (q - o) * ((b as f64 + 0.5) / k as f64)
}

fn region_size(region: &[DVec3; 4]) -> f64 {
    (region[1] - region[0])
        .length()
        .max((region[3] - region[0]).length())
}

fn region_centre(region: &[DVec3; 4]) -> DVec3 {
    (region[0] + region[2]) * 0.5
}

/// Finest integration grid per axis.
const FINEST_GRID: usize = 4;

/// Grid size for a pair of elements. It depends only on the unordered
/// pair, so `i → j` and `j → i` integrate over the same point pairs and
/// cast the same shadow rays.
fn pair_grid(ei: &WorldElement, ej: &WorldElement) -> usize {
    let distance = (region_centre(&ei.region) - region_centre(&ej.region)).length();
    grid(
        distance,
        region_size(&ei.region).max(region_size(&ej.region)),
    )
}

/// Unoccluded `F(x → region j)`: zero when `x` is behind region `j`
/// (surfaces emit from their front face only).
fn unoccluded(x: DVec3, ei: &WorldElement, ej: &WorldElement) -> f64 {
    if ej.normal.dot(x - ej.region[0]) <= 0.0 {
        return 0.0;
    }
    form_factor::point_to_polygon(x, ei.normal, &ej.region)
}

/// `F(x → region j)` with visibility, for a point `x` on element `i`.
fn point_to_region(x: DVec3, ei: &WorldElement, ej: &WorldElement, bvh: &Bvh) -> f64 {
    let f = unoccluded(x, ei, ej);
    if f <= 0.0 {
        return 0.0;
    }
    f * visibility(x, ei, ej, pair_grid(ei, ej), bvh)
}

/// `F_ij`: the mean of the point form factor (with visibility) over a grid
/// on region `i`. Where the pair is partly occluded (a penumbra), the
/// integral is redone on the finest grid: visibility is the least smooth
/// part of the integrand.
fn region_to_region(ei: &WorldElement, ej: &WorldElement, bvh: &Bvh) -> f64 {
    let k = pair_grid(ei, ej);
    let (f, partial) = region_to_region_on(ei, ej, k, bvh);
    if partial && k < FINEST_GRID {
        region_to_region_on(ei, ej, FINEST_GRID, bvh).0
    } else {
        f
    }
}

/// [`region_to_region`] on a `k × k` grid; also tells whether any point saw
/// region `j` only in part.
fn region_to_region_on(ei: &WorldElement, ej: &WorldElement, k: usize, bvh: &Bvh) -> (f64, bool) {
    let lift = ei.normal * SURFACE_OFFSET;
    let mut sum = 0.0;
    let mut partial = false;
    for b in 0..k {
        for a in 0..k {
            let x = grid_point(&ei.region, k, a, b) + lift;
            let f = unoccluded(x, ei, ej);
            if f > 0.0 {
                let v = visibility(x, ei, ej, k, bvh);
                partial |= v > 0.0 && v < 1.0;
                sum += f * v;
            }
        }
    }
    (sum / (k * k) as f64, partial)
}

/// Fraction of a `k × k` grid of points on region `j` that `x` sees.
/// Only points above `x`'s horizon count: the form factor has already
/// clipped the region to that hemisphere, and visibility must describe the
/// same part of it.
fn visibility(x: DVec3, ei: &WorldElement, ej: &WorldElement, k: usize, bvh: &Bvh) -> f64 {
    let skip = [ei.patch, ej.patch];
    let lift = ej.normal * SURFACE_OFFSET;
    let (mut seen, mut counted) = (0, 0);
    for b in 0..k {
        for a in 0..k {
            let y = grid_point(&ej.region, k, a, b) + lift;
            if ei.normal.dot(y - x) <= 0.0 {
                continue;
            }
            counted += 1;
            if !bvh.occluded(x, y, skip) {
                seen += 1;
            }
        }
    }
    if counted == 0 {
        // The grid missed the sliver above the horizon; judge by its centre.
        let y = region_centre(&ej.region) + lift;
        return if bvh.occluded(x, y, skip) { 0.0 } else { 1.0 };
    }
    f64::from(seen) / f64::from(counted)
}
