//! The tuning of a progressive solver.

use lightwire_scene::SolverHints;

#[cfg(doc)]
use super::ProgressiveSolver;

/// Tuning of [`ProgressiveSolver`].
#[derive(Debug, Clone, Copy)]
pub struct ProgressiveOptions {
    /// Top-face resolution of the hemicube item buffers in pixels (thesis
    /// §4.3.1: with the disk approximation the form factor does not depend
    /// on it, only visibility does, so it can be low).
    pub hemicube_resolution: u32,
    /// Most shooters one patch is split into (thesis §4.3.3); the count
    /// for a patch grows with the square root of its share of the emitted
    /// power. At most 128 (the shaders hold a batch's shooters in a
    /// uniform buffer of that many; more is taken as 128).
    pub max_shooters: u32,
    /// Form-factor subdivision: a shooter of area `A` at distance `r` is
    /// split into `ceil(subdivision * sqrt(A) / r)²` sub-disks (thesis
    /// §4.3.3, adaptive form factor subdivision).
    ///
    /// The disk approximation (thesis eq. 2.2.7) is biased low: each
    /// sub-disk of area `a` at distance `r` loses about `a / (π r²)` of its
    /// form factor to the `+ a` in the denominator, so a closed room
    /// receives less than is shot. Measured on a closed albedo-0.9 box
    /// (`furnace.json` repainted), power received per power shot:
    /// 0.9974 at 4, 0.9992 at 8, 0.9998 at 16, 1.0000 with the exact form
    /// factor; a room that needs ten bounces multiplies that loss tenfold.
    pub subdivision: f32,
    /// Upper bound on sub-disks per axis; closer shooters use the exact
    /// (infinitely subdivided) form factor: Lambert's contour integral,
    /// four arctangents for an unclipped quad.
    pub max_subdivision: u32,
    /// Publish indirect light only (gems §39.4): [`ProgressiveSolver::radiosity`]
    /// returns `B - E - D`, where `D` is the first bounce of the emitted
    /// light, for clients that draw direct light and shadows themselves.
    /// Every emitting patch shoots its emission once before anything else;
    /// `D` is what that delivered. (Emitters that light each other mix a
    /// little of their received light into `D`.)
    pub indirect_only: bool,
    /// Side length of the cross projection's sampling grid on each moving
    /// shooter (thesis Alg. 4.5 gridSize).
    pub cross_grid: u32,
    /// A receiver whose form factor to a moving tile is below this samples
    /// the tile's cross projection through a grid of half the side
    /// (`cross_grid / 2`, at least 1): where the tile is small in the
    /// receiver's view, its share of the light is small and the rays
    /// through it see nearly the same pixels of the back hemicube. 0:
    /// every receiver takes the full grid. At 0.005 the four thesis scenes
    /// read the same NRMSE as with the full grid everywhere, and
    /// cornell-small 2.31% instead of 1.87% at 0.01 (BENCHMARKS.md,
    /// "a coarse cross projection for receivers that see a tile small").
    pub cross_coarse_below: f32,
    /// Cross redistribution shoots from tiles of at most this many texels
    /// per side on each moving patch, not from every texel: a tile gathers
    /// the static scene's light once (its texels share it), shoots once
    /// and casts its shadow once. The thesis does the same by giving the
    /// rotating box far fewer elements under cross redistribution (§5.1:
    /// 918 → 90 on the large Cornell box, 270 → 24 on the low-quality
    /// one). 5 gives 45 tiles on cornell-large's box (912 texels) and 20
    /// on cornell-low's (294). 4 gave 57 on cornell-large: a cross frame
    /// there cost 18% more at the same NRMSE, and cornell-small read
    /// 1.46% against 1.13% with 5 (BENCHMARKS.md, "cross tiles of 5
    /// texels"). 1 shoots per texel.
    pub cross_tile: u32,
    /// Top-face resolution of the back hemicubes of shot radiosity used by
    /// the cross projection (thesis §4.5.2 renders them as low as 16, with
    /// multisampling as a blur; here one sample per pixel, which at 32²
    /// was more accurate than 16² with four and cost the same on lavapipe,
    /// BENCHMARKS.md "back hemicubes at 32²", and lets a back hemicube
    /// hold element ids that serve two moves, `redistribute/resources.rs`
    /// `Kept`).
    pub back_resolution: u32,
    /// Split shooter tiles that straddle a contact (valid and invalid
    /// elements), up to 1.5 times the tiles of the power-based grid
    /// (`Tiling::split_contacts` in `shooters.rs`), for every method.
    /// Incremental sessions once ran without it: with it, incremental on
    /// indirect-light read 20.3% NRMSE after five frames instead of 3.9%.
    /// The split was not the cause: ordinary refinement dropped negative
    /// light at its receivers (`reconstruct` in progressive.wgsl), so the
    /// refinement after each incremental move created energy, and the
    /// split's batches, which shoot that negative light from more and
    /// better placed tiles, created more (BENCHMARKS.md, "Incremental
    /// redistribution with split shooter tiles").
    pub split_contacts: bool,
    /// Most workgroups one dispatch of the per-patch power reduction uses
    /// (clamped to the adapter's per-dimension limit, 65,535 on most); a
    /// mesh has a patch per triangle and may have more, which the
    /// workgroups then take in turns. Tests lower it to exercise that.
    pub max_power_workgroups: u32,
    /// Draw each hemicube pass as one instanced draw where the device has
    /// clip distances (`hemicube::Draws::One`), else a draw per face of
    /// every shooter. Both give the same hemicubes; tests turn it off to
    /// compare.
    pub one_draw_hemicubes: bool,
    /// A batch whose patch leaves shooter slots free fills them with the
    /// next patches by unshot power, down to `shared_batch_ratio` of the
    /// first's (0 or above 1: one patch per batch, as the thesis shoots).
    /// Every shooter of a batch is shot at once and every element gathers
    /// from all of them, so it is still progressive refinement; what it
    /// saves is a batch's fixed cost (the reconstruction over every
    /// element, the selection, a submission and a readback), which a mesh
    /// of many small triangles, a patch and a shooter each, otherwise pays
    /// per triangle (BENCHMARKS.md, "shared batches").
    pub shared_batch_ratio: f32,
    /// Shoot a mesh's small triangles in clusters: triangles of one
    /// object and material joined through shared corners, their normals
    /// within 20° (`clusters.rs`), cut per batch into as many shooters as
    /// their power asks for, as a quad is. Without it a mesh needs about a
    /// shot per triangle (BENCHMARKS.md, "shooting clusters"); tests turn
    /// it off to compare.
    pub cluster_triangles: bool,
    /// Cross redistribution: keep the item buffers and back hemicubes a
    /// move draws at its tiles' new pose and copy them back as the next
    /// move's old-pose ones when its tiles, their shooters and every pose
    /// match (`redistribute/resources.rs` `Kept`), instead of drawing them
    /// again;
    /// tests turn it off to compare.
    pub keep_old_pose_hemicubes: bool,
}

impl Default for ProgressiveOptions {
    fn default() -> Self {
        Self {
            hemicube_resolution: 64,
            max_shooters: 128,
            subdivision: 8.0,
            max_subdivision: 2,
            indirect_only: false,
            cross_grid: 4,
            cross_coarse_below: 0.005,
            cross_tile: 5,
            back_resolution: 32,
            split_contacts: true,
            max_power_workgroups: u32::MAX,
            one_draw_hemicubes: true,
            shared_batch_ratio: 0.5,
            cluster_triangles: true,
            keep_old_pose_hemicubes: true,
        }
    }
}

impl ProgressiveOptions {
    /// These options with the settings `hints` states (a scene's measured
    /// ones, `Scene::solver`, or the command line's) in place of theirs.
    pub fn with_hints(self, hints: &SolverHints) -> Self {
        Self {
            cross_grid: hints.cross_grid.unwrap_or(self.cross_grid),
            back_resolution: hints.back_resolution.unwrap_or(self.back_resolution),
            cross_coarse_below: hints.cross_coarse_below.unwrap_or(self.cross_coarse_below),
            ..self
        }
    }
}
