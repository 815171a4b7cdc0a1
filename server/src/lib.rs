//! `lightwire-server`: the service, the relay, bakes and benchmarks behind
//! the `lightwire` command.
//!
//! Data flows one way: `lightwire-scene` parses and validates a scene and
//! charts it into an atlas; a solver of `lightwire-solve` computes radiosity
//! per element; this crate turns that radiosity into the image a client
//! receives ([`publish`], the one way it takes) and [`bake`] writes it to
//! files. [`service`] runs the same
//! pipeline continuously behind HTTP and WebSocket (`lightwire serve`);
//! [`relay`] fans a solver's streams out to many viewers (`lightwire
//! relay`); [`bench`] measures it all. This is the top layer: nothing
//! below it may use it.

pub mod bake;
pub mod bench;
pub mod publish;
pub mod relay;
pub mod service;
