//! One published lightmap version, encoded once for every client.

use std::sync::OnceLock;

use bytes::Bytes;
use lightwire_protocol::{Delta, Keyframe, ServerMessage, encode_server};

/// A complete lightmap version as sent to clients. Frames are encoded on
/// first use and shared by every session (`Bytes`), so fan-out costs a
/// reference count per client, not an encode.
pub struct Publication {
    /// This version.
    pub version: u64,
    /// The version the delta applies to.
    pub base_version: u64,
    /// Every tile of this version.
    pub keyframe: Keyframe,
    /// Only the tiles that changed since `base_version`.
    pub delta: Delta,
    delta_frame: OnceLock<Bytes>,
    keyframe_frame: OnceLock<Bytes>,
}

impl Publication {
    pub fn new(keyframe: Keyframe, delta: Delta) -> Self {
        Self {
            version: delta.version,
            base_version: delta.base_version,
            keyframe,
            delta,
            delta_frame: OnceLock::new(),
            keyframe_frame: OnceLock::new(),
        }
    }

    /// The encoded `Delta` frame.
    pub fn delta_frame(&self) -> Bytes {
        self.delta_frame
            .get_or_init(|| Bytes::from(encode_server(&ServerMessage::Delta(self.delta.clone()))))
            .clone()
    }

    /// The encoded `Keyframe` frame.
    pub fn keyframe_frame(&self) -> Bytes {
        self.keyframe_frame
            .get_or_init(|| {
                Bytes::from(encode_server(&ServerMessage::Keyframe(
                    self.keyframe.clone(),
                )))
            })
            .clone()
    }
}
