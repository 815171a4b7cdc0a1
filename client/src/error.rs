//! What can go wrong, said with where: every variant names the server URL
//! (or object) it concerns and carries the peer's or decoder's reason.

use lightwire_protocol::lightmap::ApplyError;
use lightwire_protocol::{DecodeError, ErrorCode};

use crate::endpoint::EndpointError;

/// Errors of [`crate::Client`]. Cloneable, so that one can travel in an
/// [`crate::Event`] and be returned too.
#[derive(Clone, Debug, thiserror::Error)]
pub enum ClientError {
    /// The address could not be used.
    #[error(transparent)]
    Endpoint(#[from] EndpointError),
    /// TCP or the WebSocket upgrade failed (refused, timed out, HTTP error).
    #[error("{url}: cannot connect: {reason}")]
    Connect {
        /// The WebSocket URL.
        url: String,
        /// Why (for an HTTP refusal, its status and body).
        reason: String,
        /// A refusal that retrying cannot fix (HTTP 4xx: no such scene,
        /// origin refused).
        permanent: bool,
    },
    /// The socket opened but the Hello/Welcome exchange did not complete.
    #[error("{url}: handshake failed: {reason}")]
    Handshake {
        /// The WebSocket URL.
        url: String,
        /// What arrived instead of `Welcome`.
        reason: String,
    },
    /// The server answered `Hello` with an `Error` (bad token, protocol
    /// version).
    #[error("{url}: the server refused the session: {code}: {message}")]
    Refused {
        /// The WebSocket URL.
        url: String,
        /// The protocol error code.
        code: ErrorCode,
        /// The server's reason.
        message: String,
    },
    /// A server frame did not decode; it was ignored.
    #[error("{url}: frame #{index} ({len} bytes) from the server does not decode: {source}")]
    Decode {
        /// The WebSocket URL.
        url: String,
        /// Position of the frame in this session (the Welcome is #1).
        index: u64,
        /// Its length in bytes.
        len: usize,
        /// The decoder's reason, with the byte offset.
        source: DecodeError,
    },
    /// A keyframe or delta decoded but could not be applied (bad tile,
    /// wrong layout); the client asked for a resync.
    #[error("{url}: {what} does not apply: {source}")]
    Apply {
        /// The WebSocket URL.
        url: String,
        /// Which frame, e.g. "delta 7 -> 8".
        what: String,
        /// The lightmap codec's reason.
        source: ApplyError,
    },
    /// The server broke the protocol (e.g. a second Welcome, text frames).
    #[error("{url}: protocol violation by the server: {reason}")]
    Protocol {
        /// The WebSocket URL.
        url: String,
        /// What happened.
        reason: String,
    },
    /// The session ended (closed, reset, silent for too long).
    #[error("{url}: connection lost: {reason}")]
    Lost {
        /// The WebSocket URL.
        url: String,
        /// Why, e.g. the close code and reason.
        reason: String,
    },
    /// Reconnecting was given up after the configured number of attempts.
    #[error("{url}: gave up reconnecting after {attempts} attempts; last error: {last}")]
    GaveUp {
        /// The WebSocket URL.
        url: String,
        /// Attempts made.
        attempts: u32,
        /// The last attempt's error.
        last: String,
    },
    /// `send_pose` for an object the scene does not let anyone move.
    #[error("object {object}: {reason}")]
    UnknownObject {
        /// The object index or name asked for.
        object: String,
        /// Why it cannot be moved.
        reason: String,
    },
    /// `send_pose` with a pose the server would refuse (PROTOCOL.md §4).
    #[error("pose for object {object} is invalid: {reason}")]
    InvalidPose {
        /// The object index.
        object: u32,
        /// [`lightwire_protocol::Pose::validate`]'s reason.
        reason: &'static str,
    },
    /// `send_pose` or `send_light` on a connection whose role may not
    /// drive.
    #[error(
        "this connection's role ({role:?}) may not move objects or set lights; use a driver or admin token"
    )]
    Forbidden {
        /// The role the server granted.
        role: lightwire_protocol::Role,
    },
    /// `send_light` for a light the scene does not have.
    #[error("light {light}: {reason}")]
    UnknownLight {
        /// The light index or name asked for.
        light: String,
        /// Why, with the scene's light names.
        reason: String,
    },
    /// `send_light` with a state the server would refuse (PROTOCOL.md §4).
    #[error("the state for light {light} is invalid: {reason}")]
    InvalidLight {
        /// The light's name.
        light: String,
        /// [`lightwire_protocol::LightState::validate`]'s reason.
        reason: &'static str,
    },
    /// `send_light` to a server that does not follow lights: its `Welcome`
    /// lacks `CAP_LIGHTS` (a server older than protocol 4, or a relay whose
    /// upstream does not announce it; a relay forwards `SetLight` while its
    /// upstream announces `CAP_LIGHTS`).
    #[error(
        "{url}: the server does not follow lights (its Welcome does not offer CAP_LIGHTS: a server older than protocol 4, or a relay whose upstream does not offer it; a relay forwards SetLight while its upstream does); connect to a `lightwire serve` that offers CAP_LIGHTS, or to a relay of one"
    )]
    NoLights {
        /// The WebSocket URL.
        url: String,
    },
    /// The client was closed or its task ended.
    #[error("the client is closed")]
    Closed,
    /// Waiting for something took too long.
    #[error("{what}: timed out after {seconds:.1} s")]
    Timeout {
        /// What was awaited.
        what: String,
        /// How long.
        seconds: f64,
    },
}

impl ClientError {
    /// Whether reconnecting cannot help: a refused token or protocol
    /// version, a scene that does not exist, a malformed address.
    pub fn is_permanent(&self) -> bool {
        match self {
            ClientError::Endpoint(_) | ClientError::GaveUp { .. } | ClientError::Closed => true,
            ClientError::Connect { permanent, .. } => *permanent,
            ClientError::Refused { code, .. } => matches!(
                code,
                ErrorCode::Unauthorized | ErrorCode::UnsupportedVersion | ErrorCode::Forbidden
            ),
            _ => false,
        }
    }
}
