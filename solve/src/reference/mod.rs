//! The reference solver: slow, simple, independent, and trusted.
//!
//! It shares no radiosity code with the GPU solvers (it reads only the
//! validated scene and the atlas's element list) so that tests comparing the
//! two mean something. The method is the classical one:
//!
//! 1. **Form factors** (thesis §2.2.1). Element `j` emits from the region
//!    of its patch it stands for (a cell, half cell or quarter cell; see
//!    [`lightwire_scene::atlas`]); the regions tile every patch. On a triangle patch
//!    (wallner §2's meshes; the half `t <= s` of its frame) a region is the
//!    element's box clipped by the diagonal: a triangle for a texel on the
//!    diagonal, nothing for one above it (such an element neither sends nor
//!    receives; its point value is computed and dilation replaces it), and
//!    its quadrature points lie on the clipped polygon
//!    (`Region::for_each_point`). From a point `x`, the
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
//!    emitted power `Σ_i A_i E_i`. An invalid element (its sample under or
//!    inside geometry, [`crate::validity`]) sends its nearest valid
//!    neighbour's radiosity instead of its own ([`Validity::donors`]): the
//!    part of its region beside the geometry is lit surface, and the rest
//!    is hidden from every visible receiver by the geometry itself.
//! 3. **Point values.** A lightmap stores radiosity at texel sample points
//!    (on patch edges, thesis §4.1), not region averages. A final gather
//!    evaluates `B(x_i) = E_i + ρ_i Σ_j F(x_i → j) B_j` at every sample, with
//!    the point form factors kept in a second matrix. Samples at the same
//!    world position on two coplanar patches therefore get the same value.
//!
//! The dense matrix costs `4 N²` bytes; [`MAX_ELEMENTS`] keeps that bounded.
//! Rows are computed and iterated in parallel with rayon.

pub use lightwire_scene::bvh;
pub mod form_factor;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::validity::Validity;
use bvh::{Bvh, Primitive};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

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
    /// The region the element emits from and receives on.
    region: Region,
    albedo: DVec3,
    /// What the element sends before any bounce: its emission, plus the
    /// direct light of the scene's point and spot lights it reflects
    /// (`ρ D`, `crate::lights`).
    emission: DVec3,
    /// `D`: the direct irradiance of the lights and the sky.
    lit: DVec3,
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
    /// Whose light each element sends: its own, or for an invalid one
    /// (under or inside geometry) its nearest valid neighbour's
    /// ([`Validity::donors`]).
    donors: Vec<u32>,
    /// Seconds spent computing form factors.
    pub form_factor_seconds: f64,
}

#[derive(Debug, Clone, Copy)]
struct WorldPatch {
    shape: Primitive,
    normal: DVec3,
    /// The centroid, towards which edge samples are nudged.
    centre: DVec3,
    first: usize,
    end: usize,
}

/// The polygon an element stands for, in world space: its parameter box,
/// on a triangle patch clipped by the diagonal `t <= s` (a triangle for a
/// texel on the diagonal, nothing for one above it).
#[derive(Debug, Clone, Copy)]
struct Region {
    /// Corners counter-clockwise seen from the front; `count` are used.
    corners: [DVec3; MAX_REGION_CORNERS],
    /// 4 for a box, 3 to 5 for a clipped one, 0 when the element stands
    /// for no surface.
    count: usize,
    /// Whether the corners are a whole parameter box (a parallelogram),
    /// integrated on its own `k × k` grid.
    parallelogram: bool,
    /// Its middle: the centroid of a box or triangle, the corners' mean of
    /// a pentagon (the sample point for an empty region).
    centre: DVec3,
    /// The longest side (0 for an empty region).
    size: f64,
}

/// A box clipped by one line has at most five corners, a texel's square
/// clipped by a triangle (`atlas/uv.rs`) at most seven.
const MAX_REGION_CORNERS: usize = 7;

impl Region {
    /// The region `[s0, s1] × [t0, t1]` of a patch with frame `(o, u, v)`,
    /// clipped to `t <= s` on a triangle; `sample` stands in for the centre
    /// of an empty one.
    fn new(
        [s0, t0, s1, t1]: [f64; 4],
        (o, u, v): (DVec3, DVec3, DVec3),
        triangle: bool,
        sample: DVec3,
    ) -> Region {
        let at = |(s, t): (f64, f64)| o + u * s + v * t;
        let square = [(s0, t0), (s1, t0), (s1, t1), (s0, t1)];
        let mut corners = [DVec3::ZERO; MAX_REGION_CORNERS];
        // A quad's box, or a triangle's that lies wholly below the
        // diagonal: a parallelogram, integrated on its own grid.
        if !triangle || square.iter().all(|&(s, t)| t <= s) {
            for (c, p) in corners.iter_mut().zip(square) {
                *c = at(p);
            }
            let [p0, p1, p2, p3, ..] = corners;
            return Region {
                corners,
                count: 4,
                parallelogram: true,
                centre: (p0 + p2) * 0.5,
                size: (p1 - p0).length().max((p3 - p0).length()),
            };
        }
        let clipped: Vec<DVec3> = lightwire_scene::atlas::clip_below_diagonal(&square)
            .into_iter()
            .map(at)
            .collect();
        Region::polygon_in_world(&clipped, sample)
    }

    /// The region with corners `polygon` (world space, counter-clockwise),
    /// at most [`MAX_REGION_CORNERS`] of them; `sample` stands in for the
    /// centre of an empty one (fewer than three corners).
    fn polygon_in_world(polygon: &[DVec3], sample: DVec3) -> Region {
        let mut corners = [DVec3::ZERO; MAX_REGION_CORNERS];
        let count = polygon.len().min(MAX_REGION_CORNERS);
        if count < 3 {
            return Region {
                corners,
                count: 0,
                parallelogram: false,
                centre: sample,
                size: 0.0,
            };
        }
        corners[..count].copy_from_slice(&polygon[..count]);
        let polygon = &corners[..count];
        Region {
            corners,
            count,
            parallelogram: false,
            centre: polygon.iter().copied().sum::<DVec3>() / count as f64,
            size: (0..count)
                .map(|k| (polygon[(k + 1) % count] - polygon[k]).length())
                .fold(0.0, f64::max),
        }
    }

    /// The polygon `corners` (patch parameters, counter-clockwise) of a
    /// patch with frame `(o, u, v)`: an element of a triangle lit on its
    /// mesh's own lightmap, the part of its texel the triangle covers;
    /// `sample` stands in for the centre of an empty one.
    fn from_polygon(
        polygon: &[glam::Vec2],
        (o, u, v): (DVec3, DVec3, DVec3),
        sample: DVec3,
    ) -> Region {
        let world: Vec<DVec3> = polygon
            .iter()
            .map(|p| o + u * f64::from(p.x) + v * f64::from(p.y))
            .collect();
        Region::polygon_in_world(&world, sample)
    }

    fn polygon(&self) -> &[DVec3] {
        &self.corners[..self.count]
    }

    fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Calls `visit(point, weight)` for the quadrature points of a `k × k`
    /// grid on the region, with weights that sum to 1. A parallelogram's
    /// are its cell centres (weight `1 / k²`). Any other polygon is cut into
    /// a fan of triangles from its first corner, each weighted by its share
    /// of the area and sampled by the `k × k` grid folded onto it (cells
    /// above the triangle's diagonal mirrored onto those below, which keeps
    /// the points uniform: a cell below the diagonal weighs `2 / k²` at its
    /// centre, one on it `1 / k²` at its lower half's centroid), so every
    /// point lies on the region. An empty region has none.
    fn for_each_point(&self, k: usize, mut visit: impl FnMut(DVec3, f64)) {
        let kf = k as f64;
        let cell = 1.0 / (kf * kf);
        if self.parallelogram {
            let [o, p, _, q, ..] = self.corners;
            for b in 0..k {
                for a in 0..k {
                    let (s, t) = ((a as f64 + 0.5) / kf, (b as f64 + 0.5) / kf);
                    visit(o + (p - o) * s + (q - o) * t, cell);
                }
            }
            return;
        }
        let polygon = self.polygon();
        let fan_area = |i: usize| {
            let (a, b, c) = (polygon[0], polygon[i], polygon[i + 1]);
            0.5 * (b - a).cross(c - a).length()
        };
        let fans = 1..polygon.len().saturating_sub(1);
        let total: f64 = fans.clone().map(fan_area).sum();
        if total <= 0.0 {
            return;
        }
        for i in fans {
            // The triangle a0 + α (b0 − a0) + β (c0 − b0), 0 <= β <= α <= 1.
            let (a0, b0, c0) = (polygon[0], polygon[i], polygon[i + 1]);
            let (u, v) = (b0 - a0, c0 - b0);
            let share = fan_area(i) / total;
            for a in 0..k {
                let af = a as f64;
                for b in 0..a {
                    let (alpha, beta) = ((af + 0.5) / kf, (b as f64 + 0.5) / kf);
                    visit(a0 + u * alpha + v * beta, 2.0 * cell * share);
                }
                let (alpha, beta) = ((af + 2.0 / 3.0) / kf, (af + 1.0 / 3.0) / kf);
                visit(a0 + u * alpha + v * beta, cell * share);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a triangle patch, an element's region is its box clipped by the
    /// diagonal: whole below it, a triangle on it, nothing above it; its
    /// quadrature points lie on the clipped polygon, their weights sum to
    /// 1 and their weighted mean is the polygon's centroid (a midpoint rule,
    /// exact for linear functions).
    #[test]
    fn regions_on_a_triangle_are_clipped_and_sampled_inside() {
        let frame = (
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.5, 0.0, 1.5),
        );
        let (o, u, v) = frame;
        let param = |y: DVec3| {
            // Invert y = o + s u + t v in the plane y = 0.
            let d = y - o;
            let det = u.x * v.z - u.z * v.x;
            ((d.x * v.z - d.z * v.x) / det, (u.x * d.z - u.z * d.x) / det)
        };
        // (box, expected corner count, expected area share of the box)
        let cases = [
            ([0.5, 0.1, 0.7, 0.3], 4, 1.0),
            ([0.2, 0.2, 0.4, 0.4], 3, 0.5),
            ([0.0, 0.0, 0.1, 0.1], 3, 0.5),
            ([0.2, 0.5, 0.4, 0.7], 0, 0.0),
            ([0.3, 0.2, 0.6, 0.4], 5, 1.0 - 0.5 * 0.1 * 0.1 / (0.3 * 0.2)),
        ];
        for (bx, count, share) in cases {
            let region = Region::new(bx, frame, true, o);
            assert_eq!(region.count, count, "{bx:?}");
            let mut total = 0.0;
            let mut mean = DVec3::ZERO;
            let mut points = 0;
            region.for_each_point(4, |y, w| {
                let (s, t) = param(y);
                assert!(
                    t <= s + 1e-12
                        && s >= bx[0] - 1e-12
                        && s <= bx[2] + 1e-12
                        && t >= bx[1] - 1e-12
                        && t <= bx[3] + 1e-12,
                    "{bx:?}: ({s}, {t}) off the region"
                );
                total += w;
                mean += y * w;
                points += 1;
            });
            if count == 0 {
                assert_eq!(points, 0);
                continue;
            }
            assert!((total - 1.0).abs() < 1e-12, "{bx:?}: {total}");
            // The polygon's area and centroid by the shoelace formula.
            let polygon = region.polygon();
            let (mut area, mut centroid) = (0.0, DVec3::ZERO);
            for k in 1..polygon.len() - 1 {
                let a = 0.5
                    * (polygon[k] - polygon[0])
                        .cross(polygon[k + 1] - polygon[0])
                        .length();
                area += a;
                centroid += (polygon[0] + polygon[k] + polygon[k + 1]) / 3.0 * a;
            }
            centroid /= area;
            assert!(
                (mean - centroid).length() < 1e-12,
                "{bx:?}: {mean} vs {centroid}"
            );
            let box_area = (bx[2] - bx[0]) * (bx[3] - bx[1]) * u.cross(v).length();
            assert!(
                (area / box_area - share).abs() < 1e-9,
                "{bx:?}: {}",
                area / box_area
            );
        }
    }
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
    /// The share of `emitted` the lights and the sky deliver.
    pub lights: DVec3,
    pub absorbed: DVec3,
    pub escaped: DVec3,
    /// What invalid elements send beyond what their own samples receive
    /// (`Σ A_i (B_i - E_i - ρ_i H_i)` over elements that send a donor's
    /// light, [`Validity::donors`]): the light the visible part of a
    /// contact texel's region reflects, and the same light sent from its
    /// hidden part onto the hidden face of the block, which absorbs it.
    /// A source like the emission: emitted + donated = absorbed + escaped.
    pub donated: DVec3,
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
                let placed = patch.shape.transformed(pose);
                let (origin, u, v) = placed.frame();
                let (origin, u, v) = (dvec(origin), dvec(u), dvec(v));
                let range = atlas.elements_of(p as u32);
                WorldPatch {
                    shape: if placed.is_triangle() {
                        Primitive::triangle(origin, u, v)
                    } else {
                        Primitive::parallelogram(origin, u, v)
                    },
                    normal: u.cross(v).normalize(),
                    centre: dvec(placed.centre()),
                    first: range.start,
                    end: range.end,
                }
            })
            .collect();
        // The lights' direct light, reflected: a source like the emission
        // (`crate::lights`).
        let caster =
            crate::lights::any(scene).then(|| crate::raycast::Raycaster::new(scene, poses));
        let sky_directions = crate::raycast::CosineGrid::new(crate::lights::SKY_SIDE);
        let elements: Vec<WorldElement> = atlas
            .elements
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let wp = &patches[e.patch as usize];
                let (o, u, v) = (wp.shape.origin, wp.shape.u, wp.shape.v);
                let at = |s: f64, t: f64| o + u * s + v * t;
                let [s, t] = [f64::from(e.st[0]), f64::from(e.st[1])];
                // Nudge toward the patch's centroid so a sample on an edge
                // is unambiguously on its own patch, then off the surface.
                let sample = at(s, t);
                let inward = (wp.centre - sample).normalize_or_zero();
                let x = sample + inward * SURFACE_OFFSET + wp.normal * SURFACE_OFFSET;
                let region = if let Some(polygon) = atlas.lightmap_region(i) {
                    Region::from_polygon(&polygon, (o, u, v), sample)
                } else if e.covers_surface() {
                    Region::new(
                        e.region.map(f64::from),
                        (o, u, v),
                        wp.shape.triangle,
                        sample,
                    )
                } else {
                    // A triangle chart's texel above the diagonal: no
                    // surface to emit from or receive on (its value is
                    // the point value at its sample, and dilation
                    // replaces it).
                    Region::new([0.0; 4], (o, u, v), true, sample)
                };
                let scale = f64::from(poses[e.object as usize].scale);
                let lit = caster.as_ref().map_or(DVec3::ZERO, |c| {
                    let at = (x, wp.normal);
                    dvec(
                        crate::lights::texel_irradiance(scene, c, (atlas, poses), i, at)
                            + crate::lights::sky_irradiance_at(scene, c, at, &sky_directions),
                    )
                });
                WorldElement {
                    x,
                    normal: wp.normal,
                    area: f64::from(e.area) * scale * scale,
                    patch: e.patch,
                    region,
                    albedo: dvec(e.albedo),
                    emission: dvec(e.emission) + dvec(e.albedo) * lit,
                    lit,
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
        let donors = Validity::compute(scene, atlas, poses).donors(atlas);
        Ok(Self {
            elements,
            patches,
            matrix,
            point_matrix,
            donors,
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
    /// [`crate::accuracy::accuracy`]; `atlas` is the one this solver was
    /// built on) of the lightmap `goal`: Jacobi sweeps from `B = E` as in
    /// [`Self::solve`], the point values evaluated after each. Returns the
    /// sweeps and the seconds they took, not counting the point evaluations
    /// (which `solve` does once, at the end), or `None` when
    /// `max_iterations` sweeps do not get there. This is how a benchmark
    /// compares another solver with this one "at equal NRMSE".
    ///
    /// `keep` narrows the compared elements as in
    /// [`crate::accuracy::accuracy_where`].
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
                crate::accuracy::accuracy_where(atlas, &self.point_radiosity(&b), goal, keep)?
                    .nrmse;
            if error <= target {
                return Some((iterations, seconds));
            }
        }
        None
    }

    /// Emitted radiosity of every element: where Jacobi iteration starts.
    fn emission(&self) -> Vec<DVec3> {
        let mut b: Vec<DVec3> = self.elements.iter().map(|e| e.emission).collect();
        self.send_donated(&mut b);
        b
    }

    /// Every invalid element of `b` takes its donor's value
    /// ([`Validity::donors`]): what the part of its region beside the
    /// geometry it lies under sends (the rest is hidden from every
    /// receiver).
    fn send_donated(&self, b: &mut [DVec3]) {
        for (i, &d) in self.donors.iter().enumerate() {
            if d as usize != i {
                b[i] = b[d as usize];
            }
        }
    }

    /// One Jacobi sweep from `b`: the next radiosity, the irradiance it was
    /// computed from, and the power it added as a fraction of the emitted
    /// power (`Σ_i A_i |ΔB_i| / Σ_i A_i E_i`, 0 in a dark scene).
    fn sweep(&self, b: &[DVec3]) -> (Vec<DVec3>, Vec<DVec3>, f64) {
        let h = self.gather(b);
        let mut next: Vec<DVec3> = self
            .elements
            .iter()
            .zip(&h)
            .map(|(e, hi)| e.emission + e.albedo * *hi)
            .collect();
        self.send_donated(&mut next);
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
    /// (`Σ A_i (1-ρ_i) (H_i + D_i)`, `D` the lights' direct irradiance) or
    /// escaped to infinity (`Σ A_i B_i (1 - Σ_j F_ij)`). In a converged,
    /// energy-conserving discretisation the two add up to the emitted
    /// power (the emitting surfaces' and the power the lights deliver onto
    /// the surfaces, `Σ A_i D_i`: a sun's or a sky's is the part that
    /// falls on the scene) and what the invalid elements donate
    /// ([`EnergyBalance::donated`]).
    pub fn energy_balance(&self, solution: &Solution) -> EnergyBalance {
        let n = self.len();
        let mut balance = EnergyBalance {
            emitted: DVec3::ZERO,
            lights: DVec3::ZERO,
            absorbed: DVec3::ZERO,
            escaped: DVec3::ZERO,
            donated: DVec3::ZERO,
        };
        for (i, e) in self.elements.iter().enumerate() {
            let row_sum: f64 = self.matrix[i * n..(i + 1) * n]
                .iter()
                .map(|f| f64::from(*f))
                .sum();
            balance.emitted += e.area * (e.emission - e.albedo * e.lit + e.lit);
            balance.lights += e.area * e.lit;
            balance.absorbed +=
                e.area * (DVec3::ONE - e.albedo) * (dvec(solution.irradiance[i]) + e.lit);
            balance.escaped +=
                e.area * dvec(solution.region_radiosity[i]) * (1.0 - row_sum).max(0.0);
            if self.donors[i] as usize != i {
                let own = e.emission + e.albedo * dvec(solution.irradiance[i]);
                balance.donated += e.area * (dvec(solution.region_radiosity[i]) - own);
            }
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
        if !ei.region.polygon().iter().any(front) && !front(&ei.x) {
            continue;
        }
        // ... and some of the patch (its own three or four corners) above
        // the receiver's horizon.
        let (corners, count) = patch.shape.corners();
        let horizon = ei
            .region
            .polygon()
            .first()
            .copied()
            .unwrap_or(ei.x - ei.normal * (2.0 * SURFACE_OFFSET))
            - ei.normal * SURFACE_OFFSET;
        if corners[..count]
            .iter()
            .all(|c| ei.normal.dot(*c - horizon) <= 0.0)
        {
            continue;
        }
        for j in patch.first..patch.end {
            let ej = &elements[j];
            if ej.region.is_empty() {
                continue; // Stands for no surface: sends nothing.
            }
            point_row[j] = point_to_region(ei.x, ei, ej, bvh) as f32;
            if !ei.region.is_empty() {
                row[j] = region_to_region(ei, ej, bvh) as f32;
            }
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

/// Finest integration grid per axis.
const FINEST_GRID: usize = 4;

/// Grid size for a pair of elements. It depends only on the unordered
/// pair, so `i → j` and `j → i` integrate over the same point pairs and
/// cast the same shadow rays.
fn pair_grid(ei: &WorldElement, ej: &WorldElement) -> usize {
    let distance = (ei.region.centre - ej.region.centre).length();
    grid(distance, ei.region.size.max(ej.region.size))
}

/// Unoccluded `F(x → region j)`: zero when `x` is behind region `j`
/// (surfaces emit from their front face only).
fn unoccluded(x: DVec3, ei: &WorldElement, ej: &WorldElement) -> f64 {
    let Some(corner) = ej.region.polygon().first() else {
        return 0.0;
    };
    if ej.normal.dot(x - *corner) <= 0.0 {
        return 0.0;
    }
    form_factor::point_to_polygon(x, ei.normal, ej.region.polygon())
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
    ei.region.for_each_point(k, |x, w| {
        let x = x + lift;
        let f = unoccluded(x, ei, ej);
        if f > 0.0 {
            let v = visibility(x, ei, ej, k, bvh);
            partial |= v > 0.0 && v < 1.0;
            sum += w * f * v;
        }
    });
    (sum, partial)
}

/// Fraction (by quadrature weight) of the points of a `k × k` grid on
/// region `j` (`Region::for_each_point`) that `x` sees. Only points above `x`'s
/// horizon count: the form factor has already clipped the region to that
/// hemisphere, and visibility must describe the same part of it.
fn visibility(x: DVec3, ei: &WorldElement, ej: &WorldElement, k: usize, bvh: &Bvh) -> f64 {
    let skip = [ei.patch, ej.patch];
    let lift = ej.normal * SURFACE_OFFSET;
    let (mut seen, mut counted) = (0.0, 0.0);
    ej.region.for_each_point(k, |y, w| {
        let y = y + lift;
        if ei.normal.dot(y - x) > 0.0 {
            counted += w;
            if !bvh.occluded(x, y, skip) {
                seen += w;
            }
        }
    });
    if counted <= 0.0 {
        // The grid missed the sliver above the horizon; judge by its centre.
        let y = ej.region.centre + lift;
        return if bvh.occluded(x, y, skip) { 0.0 } else { 1.0 };
    }
    seen / counted
}
