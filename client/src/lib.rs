//! Lightwire thin client library.
//!
//! It will connect to a `lightwire serve` endpoint, keep a double-buffered
//! local lightmap and expose scene info and events (see the thin-client
//! issue). Today it only re-exports the protocol version it speaks.

pub use lightwire_protocol::PROTOCOL_VERSION;
