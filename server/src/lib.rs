//! Lightwire server library: scenes, the lightmap atlas, radiosity solvers
//! and the bake pipeline behind the `lightwire` command.
//!
//! Data flows one way: a scene file is parsed and validated into a
//! [`scene::Scene`]; [`atlas::Atlas::build`] charts every patch into one
//! lightmap texture whose texels are the radiosity elements (both at once:
//! [`load::load_scene`]); a solver (the GPU solvers of [`gpu`], the CPU
//! [`reference`] solver, or the [`pathtrace`] oracle, all four behind one
//! [`solver::BatchSolver`] interface for batch work) computes radiosity
//! per element; [`bake`] scatters it into the atlas and writes images and
//! metadata. [`service`]
//! runs the same pipeline continuously behind HTTP and WebSocket
//! (`lightwire serve`); [`relay`] fans a solver's streams out to many
//! viewers (`lightwire relay`).

pub mod atlas;
pub mod bake;
pub mod bench;
pub mod direct;
pub mod gpu;
pub mod load;
pub mod metrics;
pub mod pathtrace;
pub mod raycast;
pub mod reference;
pub mod relay;
pub mod scene;
pub mod service;
pub mod solver;
pub mod uvmap;
pub mod validity;
