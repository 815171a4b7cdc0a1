//! Error codes of [`ServerMessage::Error`](crate::ServerMessage::Error).
//!
//! On the wire a code is its `u16` value (a bincode varint), not an enum
//! discriminant, so that a newer server can add codes without breaking older
//! clients: a value this version does not know decodes to
//! [`ErrorCode::Other`] instead of failing the whole frame.

use bincode::de::{Decode, Decoder};
use bincode::enc::{Encode, Encoder};
use bincode::error::{DecodeError, EncodeError};
use serde::{Deserialize, Serialize};

/// Why the server refused something. The numeric values are part of the
/// protocol (PROTOCOL.md, "Error codes").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ErrorCode {
    /// 1: the frame could not be decoded (truncated, garbage, trailing bytes, text frame).
    BadFrame,
    /// 2: the frame exceeds [`MAX_FRAME_BYTES`](crate::MAX_FRAME_BYTES).
    TooLarge,
    /// 3: Hello announced a protocol version the server does not speak.
    UnsupportedVersion,
    /// 4: missing or unknown token.
    Unauthorized,
    /// 5: the role does not allow this (e.g. a viewer sends Transform).
    Forbidden,
    /// 6: Transform names an object that does not exist or is not dynamic.
    UnknownObject,
    /// 7: Transform's pose fails [`Pose::validate`](crate::Pose::validate).
    InvalidPose,
    /// 8: too many messages; slow down.
    RateLimited,
    /// 9: Transform's (or SetLight's) seq is not newer than the latest accepted for that object (light).
    StaleSeq,
    /// 10: a well-formed message at the wrong time (e.g. Transform before Hello, a second Hello).
    ProtocolViolation,
    /// 11: SetLight names a light that does not exist (since version 4).
    UnknownLight,
    /// 12: SetLight's state fails [`LightState::validate`](crate::LightState::validate) (since version 4).
    InvalidLight,
    /// Any value this version does not define. Never constructed with a
    /// value listed above: use [`ErrorCode::from_u16`].
    Other(u16),
}

impl ErrorCode {
    /// The wire value.
    pub const fn as_u16(self) -> u16 {
        match self {
            ErrorCode::BadFrame => 1,
            ErrorCode::TooLarge => 2,
            ErrorCode::UnsupportedVersion => 3,
            ErrorCode::Unauthorized => 4,
            ErrorCode::Forbidden => 5,
            ErrorCode::UnknownObject => 6,
            ErrorCode::InvalidPose => 7,
            ErrorCode::RateLimited => 8,
            ErrorCode::StaleSeq => 9,
            ErrorCode::ProtocolViolation => 10,
            ErrorCode::UnknownLight => 11,
            ErrorCode::InvalidLight => 12,
            ErrorCode::Other(v) => v,
        }
    }

    /// The code for a wire value; unknown values become [`ErrorCode::Other`].
    pub const fn from_u16(v: u16) -> Self {
        match v {
            1 => ErrorCode::BadFrame,
            2 => ErrorCode::TooLarge,
            3 => ErrorCode::UnsupportedVersion,
            4 => ErrorCode::Unauthorized,
            5 => ErrorCode::Forbidden,
            6 => ErrorCode::UnknownObject,
            7 => ErrorCode::InvalidPose,
            8 => ErrorCode::RateLimited,
            9 => ErrorCode::StaleSeq,
            10 => ErrorCode::ProtocolViolation,
            11 => ErrorCode::UnknownLight,
            12 => ErrorCode::InvalidLight,
            other => ErrorCode::Other(other),
        }
    }

    /// Stable snake_case name, for metrics labels and logs.
    pub const fn name(self) -> &'static str {
        match self {
            ErrorCode::BadFrame => "bad_frame",
            ErrorCode::TooLarge => "too_large",
            ErrorCode::UnsupportedVersion => "unsupported_version",
            ErrorCode::Unauthorized => "unauthorized",
            ErrorCode::Forbidden => "forbidden",
            ErrorCode::UnknownObject => "unknown_object",
            ErrorCode::InvalidPose => "invalid_pose",
            ErrorCode::RateLimited => "rate_limited",
            ErrorCode::StaleSeq => "stale_seq",
            ErrorCode::ProtocolViolation => "protocol_violation",
            ErrorCode::UnknownLight => "unknown_light",
            ErrorCode::InvalidLight => "invalid_light",
            ErrorCode::Other(_) => "other",
        }
    }
}

impl std::fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({})", self.name(), self.as_u16())
    }
}

impl Encode for ErrorCode {
    fn encode<E: Encoder>(&self, encoder: &mut E) -> Result<(), EncodeError> {
        self.as_u16().encode(encoder)
    }
}

impl<Context> Decode<Context> for ErrorCode {
    fn decode<D: Decoder<Context = Context>>(decoder: &mut D) -> Result<Self, DecodeError> {
        Ok(ErrorCode::from_u16(u16::decode(decoder)?))
    }
}

bincode::impl_borrow_decode!(ErrorCode);
