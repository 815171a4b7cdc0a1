//! `lightwire-solve`: radiosity from a validated scene and its atlas.
//!
//! This crate owns every way Lightwire computes light: the CPU
//! [`reference`] solver (analytic form factors, ray-cast visibility, Jacobi
//! iteration), the [`pathtrace`] oracle, the ray casting both use
//! ([`raycast`]), [`direct`] light, which texels are valid ([`validity`]),
//! the GPU solvers on wgpu ([`gpu`]: progressive refinement, gather, the
//! redistribution of light when objects move) with their WGSL shaders
//! beside the Rust that binds them, the CPU ray solver for levels
//! ([`rays`]: gathering over rays cast once and kept), one batch interface over all of them
//! ([`solver`]) and the metric every claim of accuracy uses ([`accuracy`]).
//! [`load`] loads a scene for solving: its samples inside geometry moved
//! out ([`validity::relocate`]).
//!
//! Its input is `lightwire-scene`'s [`Scene`](lightwire_scene::Scene) and
//! [`Atlas`](lightwire_scene::atlas::Atlas); its output is radiosity per
//! element. It may not use tokio, axum or anything of the network service
//! (`lightwire-server`), nor turn radiosity into a published image (that is
//! the server's publication path); it does not depend on them, so the
//! compiler refuses it.

pub mod accuracy;
pub mod direct;
pub mod eye;
pub mod gpu;
pub mod lights;
pub mod load;
pub mod pathtrace;
pub mod raycast;
pub mod rays;
pub mod reference;
pub mod solver;
pub mod validity;
