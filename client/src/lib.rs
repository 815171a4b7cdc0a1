//! Lightwire thin client library: what a game links to offload global
//! illumination, and what the `lightwire-client` command (watch, drive,
//! view, load) is made of.
//!
//! # API in one screen
//!
//! ```no_run
//! # async fn demo() -> Result<(), lightwire_client::ClientError> {
//! use lightwire_client::{Client, Event, Pose};
//! // Server base URL + scene id (or a full ws://HOST:PORT/ws/scenes/ID).
//! let mut client = Client::connect("http://127.0.0.1:8080", Some("token"), Some("cornell-low")).await?;
//! let scene = client.scene();                  // Arc<SceneInfo>: atlas, objects, materials, quads
//! let frame = client.wait_for_version(1, std::time::Duration::from_secs(10)).await?;
//! let texels = &frame.lightmap.texels;         // RGB9E5, row-major: upload as Rgb9e5Ufloat
//! let box_index = client.object_index("box").expect("the scene has a box");
//! let seq = client.send_pose(box_index, Pose::IDENTITY)?;   // drivers/admins only
//! while let Some(event) = client.next_event().await {
//!     if let Event::Version(v) = event {
//!         for d in &v.delivered { println!("seq {} reached the light after {:?}", d.seq, d.latency); }
//!     }
//! }
//! # let _ = (scene, texels, seq); Ok(()) }
//! ```
//!
//! - [`Client::connect`]`(url, token, scene)` returns after the `Welcome`;
//!   the socket then lives in a background tokio task that reconnects with
//!   jittered exponential backoff ([`BackoffPolicy`]) and stops for good
//!   only on a permanent refusal (bad token, no such scene) or
//!   [`Client::close`]. [`Client::connect_with`] takes [`Options`].
//! - [`Client::frame`] is the **front buffer**: an `Arc<`[`Frame`]`>` with
//!   the scene, the lightmap and the seqs it reflects. It only ever holds
//!   complete versions; deltas are applied to a back buffer that only the
//!   task touches ([`buffer`]). [`Client::subscribe`] wakes on new ones.
//! - [`Client::send_pose`] queues a pose (newest per object wins) and
//!   returns its seq; [`Event::Version`] reports, per newly reflected seq,
//!   the transform-to-light latency ([`latency`]).
//! - Lights: connect with [`Options::lights`] and every [`Frame`] carries
//!   the lights' states its version was lit with ([`Frame::lights`]);
//!   [`Client::send_light`] queues a light's whole new state (newest per
//!   light wins) under a seq newer than any the client saw for that
//!   light, and [`Client::wait_for_light`] waits for a version lit with
//!   it.
//! - [`Client::next_event`]: a bounded stream of [`Event`]s (versions,
//!   stats, resyncs, server errors, disconnects, reconnects); events the
//!   application does not read in time are dropped and counted.
//! - Renderers: the `render` and `view` modules (the `view` subcommand)
//!   build on `Client` and [`Frame`]. `main.rs` calls
//!   `view::run(args: view::ViewArgs) -> anyhow::Result<()>` synchronously,
//!   outside any tokio runtime (`ViewArgs` is a `clap::Args`).
//!
//! # Data flow
//!
//! ```text
//! socket ─► connection task ─► DoubleBuffer (back) ─swap─► watch<Arc<Frame>> (front) ─► renderer
//!              │   ▲                                          
//!              │   └── outbox (newest pose per object, ◄── send_pose, send_light
//!              │               newest state per light)
//!              └──► bounded events ─► next_event          LatencyBook ◄─ send times
//! ```
//!
//! Transform scripts for drivers and load tests are in [`script`].

pub use lightwire_protocol::backoff;
pub mod buffer;
mod client;
mod connection;
pub mod endpoint;
pub mod error;
mod events;
pub mod latency;
mod options;
pub mod render;
mod shared;
/// Transform scripts live in the protocol crate, so that the server's
/// benchmarks replay the same streams as `drive` and `load`.
pub use lightwire_protocol::script;
pub mod view;

pub use backoff::BackoffPolicy;
pub use buffer::Frame;
pub use client::Client;
pub use endpoint::Endpoint;
pub use error::ClientError;
pub use events::{Delivered, Event, LightDelivered, VersionEvent};
pub use lightwire_protocol::{
    ErrorCode, LightInfo, LightState, LightStatus, LightType, PROTOCOL_VERSION, Pose, Role,
    SceneInfo, Stats,
};
pub use options::Options;
pub use shared::Counters;
