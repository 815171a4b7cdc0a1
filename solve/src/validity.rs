//! Texels nobody can see: samples inside or under geometry, and how they
//! are kept out of the light.
//!
//! A texel's sample point can lie where no viewer ever looks: the floor
//! under a block resting on it, a wall behind a box pushed against it, the
//! ceiling above a light that hangs a centimetre below it. What a solver
//! computes there is meaningless (black under a block, leaked light above a
//! lamp), and bilinear filtering blends it into the visible texels around
//! it: floor points a few millimetres from a block's base read 25–60% too
//! dark. Such texels are **invalid**:
//!
//! - **Detection** ([`Validity::compute`]): from the sample point, [`RAYS`]
//!   stratified, cosine-distributed rays over the hemisphere; a texel is
//!   invalid when more than [`BACK_FACE_LIMIT`] of them (cosine-weighted)
//!   first hit the *back* of a surface. Surfaces are one-sided and face
//!   where light is, so a point that sees mostly backs is enclosed: inside a
//!   block, under it, or sandwiched between a lamp and the ceiling. A texel
//!   is also invalid when it is *outside* the level: more than
//!   [`OUTSIDE_LIMIT`] of its rays see backs or nothing, at least
//!   [`OUTSIDE_BACK_SHARE`] of them backs. Real levels model floor and
//!   ceiling slabs that run on past the walls (the garage's floor 0.4 to
//!   1.5 m, its ceiling 0.2 m): such texels are not lit, were not filled,
//!   and were read dark into the corners beside them (a ceiling 1.5 cm from
//!   a wall at a third of its light), and a shooter tile reaching past a
//!   wall put its hemicube eye outside and shot its power away.
//! - **Exclusion**: the GPU solver neither lets invalid elements receive
//!   nor shoot (their area and power leave the solve), and the accuracy
//!   metric leaves them out ([`Validity::keep`]).
//! - **Sending** ([`Validity::donors`]): in the reference and the gather
//!   solver (and so in the progressive solver's gathered corrections) an
//!   invalid element sends its nearest valid neighbour's light, since the
//!   part of its region beside the geometry is lit surface and the rest
//!   is hidden. Progressive shooting does not: a shooter's one hemicube
//!   eye cannot hide the part under the block, so it would send that
//!   part's light into the room.
//! - **Filling** ([`Validity::dilate`]): after every solve or publication,
//!   each invalid texel takes the mean of its valid 8-neighbours in its own
//!   chart, ring by ring inwards, so that bilinear filtering next to a
//!   contact reads the visible side's light.
//!
//! Dynamic objects move contacts: [`Validity::update_near`] re-tests the
//! elements near the moved objects (their old and new bounds) at the new
//! poses, so a box put down on the floor invalidates the texels under it
//! and a box moved away gives them back.

use std::sync::LazyLock;

use glam::{DVec3, Vec2, Vec3};

use crate::raycast::{CosineGrid, Raycaster};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

/// Rays per element (a stratified 8 x 8 grid over the cosine-weighted
/// hemisphere).
pub const RAYS: usize = 64;
/// Fraction of rays that may see back faces before a texel is invalid.
pub const BACK_FACE_LIMIT: f64 = 0.5;
/// A texel whose rays see backs *or nothing* is outside the level when at
/// least this share of them see backs: the floor of a room
/// modelled to run on past its walls, the ceiling slab over them, a wall's
/// end behind the wall it meets. Seen from there the walls show their
/// backs and the rest is void; a texel of a courtyard open to the sky sees
/// void too, but the fronts of the walls around it, so it stays valid.
pub const OUTSIDE_BACK_SHARE: f64 = 0.1;
/// ... and when more than this share of its rays see backs or nothing.
pub const OUTSIDE_LIMIT: f64 = 0.75;
/// Ray origins leave the surface by this fraction of the scene's extent
/// (and move as far towards the patch centre), as the solvers' samples do.
const OFFSET: f64 = 1e-5;

/// The invalid elements of an atlas at some poses.
#[derive(Debug, Clone, PartialEq)]
pub struct Validity {
    invalid: Vec<bool>,
}

impl Validity {
    /// Every element that stands for surface valid (nothing ray-tested);
    /// the texels of triangle charts above the diagonal are invalid.
    pub fn all_valid(atlas: &Atlas) -> Self {
        Self {
            invalid: atlas.elements.iter().map(|e| !e.covers_surface()).collect(),
        }
    }

    /// Tests every element of `atlas` with the scene at `poses`.
    pub fn compute(scene: &Scene, atlas: &Atlas, poses: &[Pose]) -> Self {
        let caster = Raycaster::new(scene, poses);
        let extent = caster.extent();
        use rayon::prelude::*;
        let invalid = (0..atlas.elements.len())
            .into_par_iter()
            .map(|i| encloses(&caster, scene, atlas, poses, i, extent))
            .collect();
        Self { invalid }
    }

    /// Re-tests, at `poses`, the elements whose world sample lies within
    /// `margin` of the world bounds of `objects` at `poses` or at `old`
    /// (the poses the current mask was computed at), and every element of
    /// those objects. Returns the elements it re-tested, in order.
    pub fn update_near(
        &mut self,
        scene: &Scene,
        atlas: &Atlas,
        (old, poses): (&[Pose], &[Pose]),
        objects: &[u32],
        margin: f32,
    ) -> Vec<usize> {
        let boxes: Vec<(Vec3, Vec3)> = objects
            .iter()
            .flat_map(|&o| {
                [
                    bounds(scene, o, &old[o as usize]),
                    bounds(scene, o, &poses[o as usize]),
                ]
            })
            .flatten()
            .map(|(lo, hi)| (lo - Vec3::splat(margin), hi + Vec3::splat(margin)))
            .collect();
        let near: Vec<usize> = (0..atlas.elements.len())
            .filter(|&i| {
                let e = &atlas.elements[i];
                if objects.contains(&e.object) {
                    return true;
                }
                let p = poses[e.object as usize].transform_point(e.position);
                boxes
                    .iter()
                    .any(|(lo, hi)| p.cmpge(*lo).all() && p.cmple(*hi).all())
            })
            .collect();
        if near.is_empty() {
            return near;
        }
        let caster = Raycaster::new(scene, poses);
        let extent = caster.extent();
        use rayon::prelude::*;
        let tested: Vec<bool> = near
            .par_iter()
            .map(|&i| encloses(&caster, scene, atlas, poses, i, extent))
            .collect();
        for (&i, invalid) in near.iter().zip(tested) {
            self.invalid[i] = invalid;
        }
        near
    }

    /// Whether element `i` is invalid.
    pub fn is_invalid(&self, i: usize) -> bool {
        self.invalid.get(i).copied().unwrap_or(false)
    }

    /// The per-element mask (true = invalid).
    pub fn mask(&self) -> &[bool] {
        &self.invalid
    }

    /// How many elements are invalid.
    pub fn count(&self) -> usize {
        self.invalid.iter().filter(|&&b| b).count()
    }

    /// A `keep` predicate for [`crate::accuracy::accuracy_where`]: the
    /// valid elements.
    pub fn keep(&self) -> impl Fn(usize) -> bool + '_ {
        move |i| !self.is_invalid(i)
    }

    /// For every element, the element whose light it shows in a solve:
    /// itself when valid, the nearest valid element of its chart (in texel
    /// steps; the lower index on a tie) when invalid, itself again when its
    /// chart has none.
    ///
    /// A texel whose sample lies under a block still stands for a region
    /// that reaches past the block's edge, by up to a texel, and that part
    /// is floor in the light: as a sender it must show what the floor
    /// beside the block shows, not its own (dark) value, while the rest of
    /// its region is hidden by the block from every receiver anyway. Sent
    /// dark, it paints a strip beside every contact black, which the side
    /// of the block sees over half its hemisphere at the contact: on
    /// cornell-large with its floor cut into triangles, whose texels fall
    /// differently against the box, the box's bottom row read 60% darker
    /// than with the quad floor (reference solver and GPU solvers alike).
    pub fn donors(&self, atlas: &Atlas) -> Vec<u32> {
        let n = self.invalid.len().min(atlas.elements.len());
        (0..n)
            .map(|i| {
                if !self.invalid[i] {
                    return i as u32;
                }
                let e = &atlas.elements[i];
                let chart = atlas.charts[e.patch as usize];
                let first = atlas.patch_elements[e.patch as usize] as usize;
                let (a, b) = ((e.texel[0] - chart.x) as i64, (e.texel[1] - chart.y) as i64);
                let (w, h) = (i64::from(chart.w), i64::from(chart.h));
                // Ring r holds the texels at Chebyshev distance r; the
                // nearest valid one by Euclidean distance lies within the
                // first ring that has one, or the next (r √2 > r + 1 from
                // r = 3 on, so two more rings always suffice).
                let mut best: Option<(i64, usize)> = None;
                for r in 1..w.max(h) {
                    if let Some((d, _)) = best
                        && d < r * r
                    {
                        break;
                    }
                    for y in (b - r).max(0)..=(b + r).min(h - 1) {
                        for x in (a - r).max(0)..=(a + r).min(w - 1) {
                            if (x - a).abs().max((y - b).abs()) != r {
                                continue;
                            }
                            let j = first + (y * w + x) as usize;
                            if self.invalid[j] {
                                continue;
                            }
                            let d = (x - a).pow(2) + (y - b).pow(2);
                            if best.is_none_or(|(bd, bj)| (d, j) < (bd, bj)) {
                                best = Some((d, j));
                            }
                        }
                    }
                }
                best.map_or(i as u32, |(_, j)| j as u32)
            })
            .collect()
    }

    /// What every publication does to a solver's radiosity before a client
    /// sees it: the seams stitched over the valid texels
    /// ([`Atlas::stitch`]), then the invalid texels filled
    /// ([`Validity::dilate`]).
    ///
    /// A seam texel that is invalid (a corner inside the column an arch
    /// stands on) is filled by dilation from its own chart, and its
    /// partners on other charts from theirs; last, it takes the mean of
    /// its group's valid texels (of all of them when none is valid), so
    /// that both sides blend the same value towards it.
    pub fn fill(&self, atlas: &Atlas, values: &mut [Vec3]) {
        atlas.stitch(values, self.keep());
        self.fill_rings(atlas, values);
        for group in &atlas.seams {
            if !group.iter().any(|&i| self.is_invalid(i as usize)) {
                continue;
            }
            let mean = |pick: &dyn Fn(usize) -> bool| {
                let (sum, n) = group
                    .iter()
                    .map(|&i| i as usize)
                    .filter(|&i| pick(i) && i < values.len())
                    .fold((Vec3::ZERO, 0u32), |(s, n), i| (s + values[i], n + 1));
                (n > 0).then(|| sum / n as f32)
            };
            let Some(target) = mean(&|i| !self.is_invalid(i)).or_else(|| mean(&|_| true)) else {
                continue;
            };
            for &i in group {
                if self.is_invalid(i as usize) && (i as usize) < values.len() {
                    values[i as usize] = target;
                }
            }
        }
        self.straighten_diagonals(atlas, values);
    }

    /// Fills every invalid element of `values` (indexed like
    /// `atlas.elements`) with the mean of its valid or already filled
    /// 8-neighbours on its own chart, one ring at a time, until nothing
    /// more can be filled (a chart with no valid texel keeps its values).
    ///
    /// Then the row just above a triangle chart's diagonal is set again: a
    /// client reads the lightmap bilinearly, and halfway between two
    /// diagonal texels `(a, a)` and `(a + 1, a + 1)` it blends them with
    /// `(a + 1, a)` below and `(a, a + 1)` above the diagonal. Setting the
    /// latter to `v(a, a) + v(a + 1, a + 1) - v(a + 1, a)` (no lower than
    /// zero; when `(a + 1, a)` is invalid too, both take the mean of the
    /// two diagonal texels) makes the blend along the diagonal exactly the
    /// linear one between the diagonal's own texels, so that the triangle's edge there
    /// shows what its edge texels hold, as its other two edges do, and a
    /// seam along it agrees with the neighbour's edge.
    pub fn dilate(&self, atlas: &Atlas, values: &mut [Vec3]) {
        self.fill_rings(atlas, values);
        self.straighten_diagonals(atlas, values);
    }

    /// The row above every triangle chart's diagonal, as [`Validity::dilate`]
    /// says, from the values as they are (every texel filled).
    fn straighten_diagonals(&self, atlas: &Atlas, values: &mut [Vec3]) {
        if values.len() != self.invalid.len() {
            return;
        }
        for (patch, chart) in atlas.charts.iter().enumerate() {
            if atlas.on_lightmap_uvs(patch as u32) {
                // No diagonal: its texels are its mesh's (`atlas/uv.rs`).
                continue;
            }
            let first = atlas.patch_elements[patch] as usize;
            let w = chart.w as usize;
            let at = |a: usize, b: usize| first + b * w + a;
            // A triangle's chart: its texel (0, 1) stands for no surface.
            if chart.h < 2 || atlas.elements[at(0, 1)].covers_surface() {
                continue;
            }
            for a in 0..(chart.w.min(chart.h) as usize - 1) {
                let (above, d0, d1, below) =
                    (at(a, a + 1), at(a, a), at(a + 1, a + 1), at(a + 1, a));
                if !self.invalid[above] {
                    continue;
                }
                if self.invalid[below] {
                    // The texel below is invalid too (inside geometry):
                    // both take the diagonal's mean, which keeps the sum.
                    let mean = (values[d0] + values[d1]) * 0.5;
                    values[above] = mean;
                    values[below] = mean;
                } else {
                    values[above] = (values[d0] + values[d1] - values[below]).max(Vec3::ZERO);
                }
            }
        }
    }

    /// Invalid texels from their valid or already filled 8-neighbours,
    /// ring by ring (the first step of [`Validity::dilate`]).
    fn fill_rings(&self, atlas: &Atlas, values: &mut [Vec3]) {
        if values.len() != self.invalid.len() || !self.invalid.iter().any(|&b| b) {
            return;
        }
        let mut known: Vec<bool> = self.invalid.iter().map(|&b| !b).collect();
        let mut pending: Vec<usize> = (0..known.len()).filter(|&i| !known[i]).collect();
        while !pending.is_empty() {
            let mut filled = Vec::new();
            for &i in &pending {
                let e = &atlas.elements[i];
                let chart = atlas.charts[e.patch as usize];
                let first = atlas.patch_elements[e.patch as usize] as usize;
                let (a, b) = ((e.texel[0] - chart.x) as i64, (e.texel[1] - chart.y) as i64);
                let (mut sum, mut n) = (Vec3::ZERO, 0u32);
                for db in -1..=1i64 {
                    for da in -1..=1i64 {
                        let (x, y) = (a + da, b + db);
                        if (da, db) == (0, 0)
                            || x < 0
                            || y < 0
                            || x >= i64::from(chart.w)
                            || y >= i64::from(chart.h)
                        {
                            continue;
                        }
                        let j = first + (y as usize) * chart.w as usize + x as usize;
                        if known[j] {
                            sum += values[j];
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    filled.push((i, sum / n as f32));
                }
            }
            if filled.is_empty() {
                break;
            }
            for &(i, v) in &filled {
                values[i] = v;
                known[i] = true;
            }
            pending.retain(|&i| !known[i]);
        }
    }
}

/// World bounds of object `object`'s patches at `pose` (`None` if it has
/// none).
pub(crate) fn bounds(scene: &Scene, object: u32, pose: &Pose) -> Option<(Vec3, Vec3)> {
    let mut out: Option<(Vec3, Vec3)> = None;
    for p in scene.patches.iter().filter(|p| p.object == object) {
        for c in p.shape.transformed(pose).corners() {
            out = Some(match out {
                None => (c, c),
                Some((lo, hi)) => (lo.min(c), hi.max(c)),
            });
        }
    }
    out
}

/// Candidate sample points per side of an element's region that
/// [`relocate`] tries.
pub const RELOCATE_GRID: usize = 4;
/// A static element whose sample sees the backs of surfaces over more than
/// this share of its hemisphere is partly enclosed, and [`relocate`] looks
/// for a more open point of its texel.
pub const RELOCATE_BACK_SHARE: f64 = 0.2;
/// Rays [`relocate`] measures a point's share of backs with (a stratified
/// 4 x 4 grid over the cosine-weighted hemisphere): a texel in the open
/// sees no back and costs these alone.
pub const RELOCATE_RAYS: usize = 16;

/// Moves the sample of every static element that the static world
/// encloses, wholly or in part, to the point of its own texel that sees
/// the fewest backs of surfaces, and returns how many moved.
///
/// An element's sample is one point of the region its texel covers: the
/// point of its patch nearest to the texel's centre. Where geometry passes
/// through that region (a frame's bar through the strip it stands on, a
/// panel set into a frame, a prop sunk into a wall), the point can fall
/// inside or behind it while the rest of the texel is in view. Enclosed,
/// the texel is invalid and takes its chart's light by dilation, and a
/// chart every sample of which is enclosed has none to take; half
/// enclosed (the garage's lamp: a bar's face 3 cm wide, its texels' samples
/// on the 1.7 cm behind the emitting panel, the 1.5 cm in front of it in
/// full light), it is valid and dark. Either way a player sees black where
/// the light is brightest. Bakers move such samples out of geometry; here,
/// for each element whose sample sees backs over more than
/// [`RELOCATE_BACK_SHARE`] of its hemisphere (measured with
/// [`RELOCATE_RAYS`] rays; or sees some and is enclosed by [`Validity`]'s
/// rule), the [`RELOCATE_GRID`]² points of its region that lie on its
/// patch and in its own texel are measured the same way, and the one that
/// sees the fewest backs (the nearest of equals) and is not enclosed becomes its
/// sample, position and patch parameters, if it sees fewer than the sample
/// did. Dynamic objects are left out on both sides (they move;
/// [`Validity::update_near`] follows them), so a texel under the crate keeps
/// its sample and is invalid only while the crate is there. Texels wholly
/// inside or under geometry keep theirs.
pub fn relocate(scene: &Scene, atlas: &mut Atlas) -> usize {
    use rayon::prelude::*;
    let poses = scene.initial_poses();
    let absent: Vec<bool> = scene.objects.iter().map(|o| o.dynamic).collect();
    let caster = Raycaster::with_absent(scene, &poses, &absent);
    let extent = caster.extent();
    let grid = RELOCATE_GRID as f32;
    let atlas_ref: &Atlas = atlas;
    let moves: Vec<(usize, Vec2, Vec3)> = (0..atlas_ref.elements.len())
        .into_par_iter()
        .filter_map(|i| {
            let e = &atlas_ref.elements[i];
            let static_world = scene
                .objects
                .get(e.object as usize)
                .is_some_and(|o| !o.dynamic);
            if !static_world || !e.covers_surface() {
                return None;
            }
            // The static world's pose is the identity: its object space is
            // the world.
            let shape = &scene.patches[e.patch as usize].shape;
            let centre = shape.centre().as_dvec3();
            let n = e.normal.as_dvec3();
            let share = |x: Vec3| back_share(&caster, (x.as_dvec3(), n), centre, extent);
            let here = share(e.position);
            if here == 0.0
                || (here <= RELOCATE_BACK_SHARE
                    && !encloses(&caster, scene, atlas_ref, &poses, i, extent))
            {
                return None;
            }
            let (o, u, v) = shape.frame();
            let [s0, t0, s1, t1] = e.region;
            let at = Vec2::from(e.st);
            let metres = |st: Vec2| (u * (st.x - at.x) + v * (st.y - at.y)).length_squared();
            (0..RELOCATE_GRID * RELOCATE_GRID)
                .map(|k| {
                    let (a, b) = ((k % RELOCATE_GRID) as f32, (k / RELOCATE_GRID) as f32);
                    Vec2::new(
                        s0 + (a + 0.5) / grid * (s1 - s0),
                        t0 + (b + 0.5) / grid * (t1 - t0),
                    )
                })
                .filter(|st| {
                    shape.contains(st.x, st.y)
                        && atlas_ref.element_of(e.patch, shape.is_triangle(), *st) == Some(i)
                })
                .map(|st| {
                    let position = o + u * st.x + v * st.y;
                    (share(position), metres(st), st, position)
                })
                .filter(|c| {
                    c.0 < here && !encloses_at(&caster, (c.3.as_dvec3(), n), centre, extent)
                })
                .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)))
                .map(|(_, _, st, position)| (i, st, position))
        })
        .collect();
    for &(i, st, position) in &moves {
        let e = &mut atlas.elements[i];
        e.st = st.to_array();
        e.position = position;
    }
    moves.len()
}

/// The share of [`RELOCATE_RAYS`] cosine-distributed rays from the world
/// point `x` with normal `n` (nudged as [`encloses`] nudges it) that first
/// meet the back of a surface.
fn back_share(caster: &Raycaster, (x, n): (DVec3, DVec3), centre: DVec3, extent: f64) -> f64 {
    static FEW: LazyLock<CosineGrid> =
        LazyLock::new(|| CosineGrid::new((RELOCATE_RAYS as f64).sqrt() as usize));
    let origin = ray_origin((x, n), centre, extent);
    let backs = FEW
        .around(n)
        .filter(|&d| {
            caster
                .closest_hit(origin, d, f64::INFINITY)
                .is_some_and(|hit| !hit.front)
        })
        .count();
    backs as f64 / FEW.len().max(1) as f64
}

/// Where the rays of the surface point `x` with normal `n` leave from: a
/// hair ([`OFFSET`] of the scene's `extent`) above it and as far towards its
/// patch's `centre`.
fn ray_origin((x, n): (DVec3, DVec3), centre: DVec3, extent: f64) -> DVec3 {
    let inward = (centre - x).normalize_or_zero();
    x + (n + inward) * (OFFSET * extent)
}

/// [`RAYS`] directions, stratified over the cosine-weighted hemisphere.
static DIRECTIONS: LazyLock<CosineGrid> =
    LazyLock::new(|| CosineGrid::new((RAYS as f64).sqrt() as usize));

/// Whether element `i`'s sample sees back faces over more than
/// [`BACK_FACE_LIMIT`] of its cosine-weighted hemisphere.
fn encloses(
    caster: &Raycaster,
    scene: &Scene,
    atlas: &Atlas,
    poses: &[Pose],
    i: usize,
    extent: f64,
) -> bool {
    let e = &atlas.elements[i];
    if !e.covers_surface() {
        // A triangle chart's texel above its diagonal: no surface there.
        return true;
    }
    let pose = &poses[e.object as usize];
    let patch = &scene.patches[e.patch as usize];
    let n = pose.transform_normal(e.normal).as_dvec3();
    let x = pose.transform_point(e.position).as_dvec3();
    let centre = patch.shape.transformed(pose).centre().as_dvec3();
    encloses_at(caster, (x, n), centre, extent)
}

/// Whether the world point `x` with normal `n` on a patch whose centre is
/// `centre` is enclosed, by [`encloses`]'s rule.
fn encloses_at(caster: &Raycaster, (x, n): (DVec3, DVec3), centre: DVec3, extent: f64) -> bool {
    let origin = ray_origin((x, n), centre, extent);
    let total = DIRECTIONS.len();
    // Invalid when more than `limit` rays see backs, or more than
    // `outside` see backs or nothing at all with at least `outside_backs`
    // of them on backs ([`OUTSIDE_BACK_SHARE`]); decided as soon as the rays left
    // cannot change the answer (about half of them for a texel in the
    // open).
    let limit = (BACK_FACE_LIMIT * total as f64).floor() as usize;
    let outside = (OUTSIDE_LIMIT * total as f64).floor() as usize;
    let outside_backs = (OUTSIDE_BACK_SHARE * total as f64).ceil() as usize;
    let (mut back, mut lost, mut cast) = (0, 0, 0);
    for d in DIRECTIONS.around(n) {
        let left = total - cast;
        if back > limit || (back >= outside_backs && back + lost > outside) {
            return true;
        }
        if back + left <= limit && (back + left < outside_backs || back + lost + left <= outside) {
            return false;
        }
        cast += 1;
        match caster.closest_hit(origin, d, f64::INFINITY) {
            Some(hit) if !hit.front => back += 1,
            Some(_) => {}
            None => lost += 1,
        }
    }
    back > limit || (back >= outside_backs && back + lost > outside)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2 x 2 floor with a closed-topped 0.5 m block resting on it (four
    /// sides and a top, no bottom) and a light above.
    const BLOCK: &str = r#"{
      "name": "contact", "lightmap": { "texel_density": 10 },
      "materials": [
        { "name": "white", "albedo": [0.5, 0.5, 0.5] },
        { "name": "light", "albedo": [0, 0, 0], "emission": [10, 10, 10] }
      ],
      "objects": [{ "name": "crate", "pose": { "translation": [1.03, 0.25, 1.03] } }],
      "surfaces": [
        { "name": "floor", "material": "white",
          "quad": { "origin": [0, 0, 0], "u": [0, 0, 2], "v": [2, 0, 0] } },
        { "name": "light", "material": "light",
          "quad": { "origin": [0.5, 2, 0.5], "u": [1, 0, 0], "v": [0, 0, 1] } },
        { "name": "crate", "material": "white", "object": "crate",
          "box": { "center": [0, 0, 0], "size": [0.5, 0.5, 0.5] } }
      ]
    }"#;

    /// The block scene, its atlas and validity at the initial poses.
    fn block_at_rest() -> (Scene, Atlas, Validity) {
        let scene = Scene::parse(BLOCK, "contact").expect("scene");
        let atlas = Atlas::build(&scene).expect("atlas");
        let v = Validity::compute(&scene, &atlas, &scene.initial_poses());
        (scene, atlas, v)
    }

    fn floor_texel_at(atlas: &Atlas, poses: &[Pose], x: f32, z: f32) -> usize {
        (0..atlas.elements.len())
            .filter(|&i| atlas.elements[i].patch == 0)
            .min_by(|&a, &b| {
                let d = |i: usize| {
                    let p = poses[0].transform_point(atlas.elements[i].position);
                    (p.x - x).powi(2) + (p.z - z).powi(2)
                };
                d(a).total_cmp(&d(b))
            })
            .expect("floor texels")
    }

    /// A 4 x 4 floor with a 2 x 2 room of 1.5 m walls in its middle, the
    /// floor running on 1 m past them as a level's floor slab does; closed
    /// by a ceiling, or open to the sky (a courtyard). A lamp hangs inside.
    fn floor_past_the_walls(ceiling: bool) -> (Scene, Atlas, Validity) {
        let top = if ceiling {
            r#"{ "name": "ceiling", "material": "white",
                 "quad": { "origin": [1, 1.5, 1], "u": [2, 0, 0], "v": [0, 0, 2] } },"#
        } else {
            ""
        };
        let json = format!(
            r#"{{
          "name": "slab", "lightmap": {{ "texel_density": 10 }},
          "materials": [
            {{ "name": "white", "albedo": [0.5, 0.5, 0.5] }},
            {{ "name": "light", "albedo": [0, 0, 0], "emission": [10, 10, 10] }}
          ],
          "surfaces": [
            {{ "name": "floor", "material": "white",
               "quad": {{ "origin": [0, 0, 0], "u": [0, 0, 4], "v": [4, 0, 0] }} }},
            {{ "name": "west", "material": "white",
               "quad": {{ "origin": [1, 0, 1], "u": [0, 1.5, 0], "v": [0, 0, 2] }} }},
            {{ "name": "east", "material": "white",
               "quad": {{ "origin": [3, 0, 1], "u": [0, 0, 2], "v": [0, 1.5, 0] }} }},
            {{ "name": "north", "material": "white",
               "quad": {{ "origin": [1, 0, 1], "u": [2, 0, 0], "v": [0, 1.5, 0] }} }},
            {{ "name": "south", "material": "white",
               "quad": {{ "origin": [1, 0, 3], "u": [0, 1.5, 0], "v": [2, 0, 0] }} }},
            {top}
            {{ "name": "lamp", "material": "light",
               "quad": {{ "origin": [1.5, 1.4, 1.5], "u": [1, 0, 0], "v": [0, 0, 1] }} }}
          ]
        }}"#
        );
        let scene = Scene::parse(&json, "slab").expect("scene");
        let atlas = Atlas::build(&scene).expect("atlas");
        let v = Validity::compute(&scene, &atlas, &scene.initial_poses());
        (scene, atlas, v)
    }

    #[test]
    fn relocation_moves_samples_out_of_static_geometry_into_their_texels_open_part() {
        // The block made part of the static world.
        let json = BLOCK
            .replace(r#""objects": [{ "name": "crate", "pose": { "translation": [1.03, 0.25, 1.03] } }],"#, "")
            .replace(r#""object": "crate",
          "box": { "center": [0, 0, 0]"#, r#""box": { "center": [1.03, 0.25, 1.03]"#);
        let scene = Scene::parse(&json, "static block").expect("scene");
        assert!(scene.objects.iter().all(|o| !o.dynamic), "{json}");
        let poses = scene.initial_poses();
        let mut atlas = Atlas::build(&scene).expect("atlas");
        let before = Validity::compute(&scene, &atlas, &poses);
        let original = atlas.elements.clone();
        let moved = relocate(&scene, &mut atlas);
        let after = Validity::compute(&scene, &atlas, &poses);
        let under = |p: Vec3| (0.78..=1.28).contains(&p.x) && (0.78..=1.28).contains(&p.z);
        assert!(moved > 0, "texels straddle the block's edges");
        let mut changed = 0;
        for (i, (old, new)) in original.iter().zip(&atlas.elements).enumerate() {
            if old.position == new.position {
                // Unmoved: valid before, or wholly under the block.
                assert_eq!(before.is_invalid(i), after.is_invalid(i), "element {i}");
                continue;
            }
            changed += 1;
            assert!(
                before.is_invalid(i) && !after.is_invalid(i),
                "element {i} moved"
            );
            assert_eq!(old.patch, 0, "only the floor meets the block");
            assert!(
                under(old.position) && !under(new.position),
                "{old:?} -> {new:?}"
            );
            // Within its own region and texel.
            let [s0, t0, s1, t1] = new.region;
            assert!((s0..=s1).contains(&new.st[0]) && (t0..=t1).contains(&new.st[1]));
            let shape = &scene.patches[0].shape;
            assert_eq!(
                atlas.element_of(0, shape.is_triangle(), Vec2::from(new.st)),
                Some(i)
            );
            let (o, u, v) = shape.frame();
            assert!((o + u * new.st[0] + v * new.st[1] - new.position).length() < 1e-5);
        }
        assert_eq!(changed, moved);
        // The floor under the block's middle keeps its sample and stays
        // invalid.
        let middle = floor_texel_at(&atlas, &poses, 1.03, 1.03);
        assert!(after.is_invalid(middle));
        assert_eq!(after.count(), before.count() - moved);

        // A dynamic crate: neither its texels nor the floor's under it move
        // (the crate is left out, and will move).
        let scene = Scene::parse(BLOCK, "contact").expect("scene");
        let mut atlas = Atlas::build(&scene).expect("atlas");
        assert_eq!(relocate(&scene, &mut atlas), 0);
    }

    #[test]
    fn a_floor_running_on_past_the_walls_is_invalid_outside_them_and_valid_inside() {
        for ceiling in [true, false] {
            let (scene, atlas, v) = floor_past_the_walls(ceiling);
            let poses = scene.initial_poses();
            let at = |x, z| floor_texel_at(&atlas, &poses, x, z);
            // Outside: the walls' backs and the void. Right by a wall, a
            // metre from it, and by the room's corner.
            for (x, z) in [(0.95, 2.0), (0.05, 2.0), (3.5, 2.0), (2.0, 0.3), (3.2, 3.2)] {
                assert!(
                    v.is_invalid(at(x, z)),
                    "ceiling {ceiling}: the floor at ({x}, {z}) is outside the room"
                );
            }
            // Inside, under the ceiling or the open sky: the walls' fronts.
            for (x, z) in [(2.0, 2.0), (1.05, 2.0), (2.95, 2.95), (1.5, 1.05)] {
                assert!(
                    !v.is_invalid(at(x, z)),
                    "ceiling {ceiling}: the floor at ({x}, {z}) is in the room"
                );
            }
            // A wall's texels are in the room, even by the ceiling or the
            // open top.
            let west = scene
                .patches
                .iter()
                .position(|p| p.name == "west")
                .expect("west wall") as u32;
            let walls: Vec<usize> = (0..atlas.elements.len())
                .filter(|&i| atlas.elements[i].patch == west)
                .collect();
            assert!(!walls.is_empty());
            assert!(
                walls.iter().all(|&i| !v.is_invalid(i)),
                "ceiling {ceiling}: every texel of the west wall is valid"
            );
        }
    }

    #[test]
    fn texels_under_a_box_are_invalid_and_come_back_when_it_moves_away() {
        let scene = Scene::parse(BLOCK, "contact").expect("scene");
        let atlas = Atlas::build(&scene).expect("atlas");
        let mut poses = scene.initial_poses();
        let mut v = Validity::compute(&scene, &atlas, &poses);
        let under = floor_texel_at(&atlas, &poses, 1.0, 1.0);
        let open = floor_texel_at(&atlas, &poses, 0.2, 1.8);
        assert!(v.is_invalid(under), "the floor under the box");
        assert!(!v.is_invalid(open), "the open floor");
        // Lift the box off the floor: the texels under it become valid.
        let old = poses.clone();
        poses[1].translation.y = 1.0;
        let before = v.clone();
        let tested = v.update_near(&scene, &atlas, (&old, &poses), &[1], 0.1);
        assert!(
            tested.contains(&under),
            "the texel under the box is re-tested"
        );
        assert_ne!(v, before, "lifting the box changes validity");
        assert!(!v.is_invalid(under), "the floor once the box is lifted");
        assert_eq!(
            v,
            Validity::compute(&scene, &atlas, &poses),
            "update = recompute"
        );
        // And put it back down.
        let lifted = poses.clone();
        v.update_near(&scene, &atlas, (&lifted, &old), &[1], 0.1);
        assert_eq!(v, Validity::compute(&scene, &atlas, &old));
        assert!(v.is_invalid(under));
    }

    #[test]
    fn dilation_fills_invalid_texels_from_their_valid_neighbours_only() {
        let (_, atlas, v) = block_at_rest();
        assert!(v.count() > 0);
        // Valid texels 1, invalid ones a poison value.
        let mut values: Vec<Vec3> = (0..atlas.elements.len())
            .map(|i| {
                if v.is_invalid(i) {
                    Vec3::splat(-7.0)
                } else {
                    Vec3::ONE
                }
            })
            .collect();
        v.dilate(&atlas, &mut values);
        for (i, value) in values.iter().enumerate() {
            if atlas.elements[i].patch == 0 {
                assert_eq!(*value, Vec3::ONE, "floor element {i} after dilation");
            }
        }
        // Valid elements are never touched.
        let mut graded: Vec<Vec3> = (0..atlas.elements.len())
            .map(|i| Vec3::splat(i as f32))
            .collect();
        let before = graded.clone();
        v.dilate(&atlas, &mut graded);
        for i in 0..graded.len() {
            if !v.is_invalid(i) {
                assert_eq!(graded[i], before[i]);
            }
        }
    }

    /// The block scene with every quad cut in two along its diagonal.
    fn triangulated_block() -> (Atlas, Validity) {
        let scene = Scene::parse(BLOCK, "contact")
            .expect("scene")
            .triangulated();
        let atlas = Atlas::build(&scene).expect("atlas");
        let v = Validity::compute(&scene, &atlas, &scene.initial_poses());
        (atlas, v)
    }

    #[test]
    fn seams_join_texels_of_coplanar_charts_at_one_point_and_never_across_a_crease() {
        let (atlas, _) = triangulated_block();
        assert!(!atlas.seams.is_empty());
        for group in &atlas.seams {
            let e0 = &atlas.elements[group[0] as usize];
            assert!(
                group
                    .iter()
                    .any(|&i| atlas.elements[i as usize].patch != e0.patch)
            );
            for &i in group {
                let e = &atlas.elements[i as usize];
                // One object, one facing: the box's faces meet at creases.
                assert_eq!(e.object, e0.object);
                assert!(e.normal.dot(e0.normal) > 0.999, "{group:?}");
                // Grid points agree (corner samples are moved inwards by
                // a twentieth of a texel, so allow that much).
                assert!((e.position - e0.position).length() < 0.02, "{group:?}");
            }
        }
        // Each floor triangle's diagonal texels pair with the other's.
        let floor = atlas
            .elements
            .iter()
            .filter(|e| {
                e.patch == 0 && e.texel[0] - atlas.charts[0].x == e.texel[1] - atlas.charts[0].y
            })
            .count();
        let paired = atlas
            .seams
            .iter()
            .filter(|g| {
                g.iter().any(|&i| atlas.elements[i as usize].patch == 0)
                    && g.iter().any(|&i| atlas.elements[i as usize].patch == 1)
            })
            .count();
        assert_eq!(
            paired, floor,
            "every diagonal texel of the floor's first triangle has its partner"
        );
    }

    #[test]
    fn stitching_makes_a_seams_valid_texels_equal_and_keeps_the_rest() {
        let (atlas, v) = triangulated_block();
        let mut values: Vec<Vec3> = (0..atlas.elements.len())
            .map(|i| Vec3::splat(i as f32))
            .collect();
        let before = values.clone();
        atlas.stitch(&mut values, v.keep());
        let mut stitched = vec![false; values.len()];
        for group in &atlas.seams {
            let valid: Vec<usize> = group
                .iter()
                .map(|&i| i as usize)
                .filter(|&i| !v.is_invalid(i))
                .collect();
            if valid.len() < 2 {
                continue;
            }
            let mean = valid.iter().map(|&i| before[i]).sum::<Vec3>() / valid.len() as f32;
            for &i in &valid {
                assert!((values[i] - mean).length() < 1e-3, "{group:?}");
                stitched[i] = true;
            }
        }
        for i in 0..values.len() {
            if !stitched[i] {
                assert_eq!(values[i], before[i], "element {i} is on no seam");
            }
        }
    }

    #[test]
    fn a_triangle_reads_linearly_along_its_diagonal_after_dilation() {
        let (atlas, v) = triangulated_block();
        // A smooth but curved field over each chart: v = 1 + a² + 2 b.
        let mut values: Vec<Vec3> = atlas
            .elements
            .iter()
            .map(|e| {
                let c = atlas.charts[e.patch as usize];
                let (a, b) = ((e.texel[0] - c.x) as f32, (e.texel[1] - c.y) as f32);
                Vec3::splat(1.0 + a * a + 2.0 * b)
            })
            .collect();
        v.dilate(&atlas, &mut values);
        // Patch 0, the floor's first triangle: halfway between diagonal
        // texels the bilinear read is the mean of the two (where none of
        // the four is inside the block).
        let c = atlas.charts[0];
        let n = c.w.min(c.h);
        let first = atlas.patch_elements[0] as usize;
        let at = |a: u32, b: u32| first + (b * c.w + a) as usize;
        let mut checked = 0;
        for a in 0..n - 1 {
            if [at(a, a), at(a + 1, a + 1), at(a + 1, a)]
                .iter()
                .any(|&i| v.is_invalid(i))
            {
                continue;
            }
            let s = (a as f32 + 0.5) / (n - 1) as f32;
            let read = atlas.sample(&values, 0, [s, s]);
            let line = (values[at(a, a)] + values[at(a + 1, a + 1)]) * 0.5;
            assert!(
                (read - line).length() < 1e-4,
                "diagonal cell {a}: {read} vs {line}"
            );
            checked += 1;
        }
        assert!(checked > 5, "{checked} diagonal cells");
    }

    #[test]
    fn an_invalid_texel_sends_its_nearest_valid_neighbours_light() {
        let (_, atlas, v) = block_at_rest();
        let donors = v.donors(&atlas);
        assert_eq!(donors.len(), atlas.elements.len());
        let texel = |i: usize| {
            let e = &atlas.elements[i];
            (i64::from(e.texel[0]), i64::from(e.texel[1]))
        };
        let mut donated = 0;
        for (i, &d) in donors.iter().enumerate() {
            let d = d as usize;
            if !v.is_invalid(i) {
                assert_eq!(d, i, "a valid element sends its own light");
                continue;
            }
            if d == i {
                // Only where the chart holds no valid texel (the crate's
                // faces are all valid here; the floor has valid texels).
                assert!(
                    (0..atlas.elements.len())
                        .filter(|&j| atlas.elements[j].patch == atlas.elements[i].patch)
                        .all(|j| v.is_invalid(j)),
                    "invalid element {i} has no donor although its chart has valid texels"
                );
                continue;
            }
            donated += 1;
            assert!(!v.is_invalid(d), "donor {d} of {i} is invalid");
            assert_eq!(atlas.elements[d].patch, atlas.elements[i].patch);
            // No valid texel of the chart is nearer.
            let ((a, b), (x, y)) = (texel(i), texel(d));
            let dist = (x - a).pow(2) + (y - b).pow(2);
            for j in 0..atlas.elements.len() {
                if atlas.elements[j].patch == atlas.elements[i].patch && !v.is_invalid(j) {
                    let (x, y) = texel(j);
                    assert!(
                        (x - a).pow(2) + (y - b).pow(2) >= dist,
                        "{j} is nearer to {i} than {d}"
                    );
                }
            }
        }
        assert!(donated > 0, "the floor under the crate has invalid texels");
    }
}
