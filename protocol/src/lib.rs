//! Lightwire wire protocol.
//!
//! This crate will hold the message types, the bincode codec and the golden
//! vectors (see PROTOCOL.md). It must never depend on tokio or wgpu, so that
//! any client — a game, a load tester, a browser via its JavaScript twin —
//! can share it.

/// The protocol version a peer announces in its handshake. Bumped on any
/// incompatible change to PROTOCOL.md.
pub const PROTOCOL_VERSION: u16 = 1;
