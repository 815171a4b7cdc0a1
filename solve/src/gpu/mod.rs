//! GPU radiosity solvers on wgpu.
//!
//! Data flow. [`Device::new`] picks an adapter (a discrete GPU if there is
//! one, else anything down to the lavapipe software rasterizer) and creates a
//! device with the adapter's limits. [`ProgressiveSolver::new`] places every
//! atlas element in the world at the given poses and uploads, once: the
//! element records (position, area, normal, patch id, albedo), the radiosity
//! `B` and unshot radiosity `B^u` (both start at the emission `E`), an
//! irradiance accumulator `H` for energy bookkeeping, the patch element
//! ranges, and two triangles per patch for the hemicube rasterizer.
//!
//! Each batch then runs entirely on the GPU except for one 16-byte readback
//! (thesis Alg. 4.2, gems §39.2):
//!
//! 1. The CPU knows, from the previous batch's readback, the patch with the
//!    most unshot power. It splits that patch's chart into a grid of
//!    shooters whose count grows with the power (thesis §4.3.3) and writes
//!    their geometry (a few hundred bytes).
//! 2. `shooter_energy` sums each shooter's unshot power into the
//!    intermediate buffer `T` and clears the patch's `B^u`.
//! 3. The hemicube pass rasterizes patch ids into one large `R32Uint`
//!    target: a row of five face viewports per shooter (thesis §4.3.2).
//! 4. `reconstruct`: every element gathers from every shooter of the batch:
//!    an id lookup in the item buffer decides visibility, the disk
//!    approximation (thesis eq. 2.2.7–2.2.8) gives the form factor, and
//!    `ΔB = ρ B_s^u A_s F` is added to `B` and `B^u`.
//! 5. `patch_power_main` reduces `B^u` to unshot power per patch and
//!    `select_shooter` finds the maximum and the total (gems §39.2.3); the
//!    16-byte answer is copied to a mappable buffer and read back: it is
//!    both the next batch's shooter and the convergence measure.
//!
//! Shader sources live beside the Rust that binds them (`*.wgsl` here, in
//! `progressive/`, `progressive/redistribute/` and `gather/`) and are
//! compiled into the binary with `include_str!`; each file names on its
//! first line the files it requires, `shaders.rs` assembles them into
//! modules, and its tests validate every file and every module with naga,
//! tie each struct shared with WGSL to its Rust mirror's size, and check
//! every pipeline's bindings against the WGSL.
//!
//! The building blocks, one concept per file:
//!
//! - `device.rs`: the adapter, the device and its health;
//! - `binding.rs`: bind group layouts declared once per WGSL binding
//!   (named slots, and the passes that list them);
//! - `buffers.rs`: helpers the solvers share (textures, dispatch,
//!   readback, energy sums);
//! - `placement.rs`: elements and patches placed at the objects' poses;
//! - `hemicube.rs`: the hemicube rasterizer (item buffers and shot
//!   radiosity);
//! - `shaders.rs`: the WGSL modules;
//! - `progressive/`: progressive refinement and redistribution;
//! - `gather/`: gather radiosity;
//! - `correct.rs`: gather sweeps that correct a progressive solution;
//! - `dynamic.rs`: the solver session that follows moves;
//! - `vpl.rs`: bounces by virtual point lights and imperfect
//!   shadow maps, the fast first answer for a light that moves;
//! - `profile.rs`: where that session's time goes, per stage (profiling
//!   only).

pub mod basis;
mod binding;
mod buffers;
mod correct;
mod device;
mod dynamic;
mod gather;
mod hemicube;
mod placement;
pub mod profile;
mod progressive;
mod shaders;
mod vpl;

pub use correct::{
    Correction, CorrectionReport, MAX_DEFAULT_SWEEP, RAY_GRID, RAY_SIDE, corrections_affordable,
};
pub use device::{Device, GpuError};
pub use dynamic::{CORRECTED_RESIDUAL, DynamicOptions, DynamicSolver, DynamicStep, Seed};
pub use gather::{GatherBalance, GatherOptions, GatherReport, GatherSolver};
pub use progressive::{
    EnergyBalance, Move, ProgressiveOptions, ProgressiveSolver, Redistribution, StepReport,
};
pub use vpl::{BounceOptions, BounceReport, FirstBounce, ISM_SIDE};
