//! The frame codec: one message per WebSocket binary frame, bincode 2 with
//! one fixed configuration.
//!
//! # Configuration
//!
//! [`CONFIG`] is `bincode::config::standard()` spelled out: little endian,
//! **variable-length integers** (bincode's varint: values below 251 take one
//! byte; 251, 252, 253 prefix a 2-, 4- or 8-byte little-endian value), and a
//! decode budget set with `.with_limit::<DECODE_BUDGET_BYTES>()`.
//!
//! Two limits guard a decoder:
//!
//! - the **frame limit** [`MAX_FRAME_BYTES`] on the encoded length, checked
//!   before any parsing ([`DecodeError::TooLarge`]);
//! - bincode's **claim budget** [`DECODE_BUDGET_BYTES`], which caps the
//!   memory that the length prefixes inside one frame may make the decoder
//!   allocate (bincode counts in-memory sizes, e.g. 32 bytes per `Tile`
//!   slot, not wire bytes). It is four times the frame limit so that every
//!   legitimate frame within [`MAX_FRAME_BYTES`] decodes, while a hostile
//!   16-byte frame claiming a billion-element vector is refused before
//!   allocating.

use bincode::Encode;
use bincode::config::{Configuration, Limit, LittleEndian, Varint};
use bincode::de::read::Reader;

use crate::{ClientMessage, ErrorCode, MAX_FRAME_BYTES, Role, SceneInfo, ServerMessage};

/// Bincode's allocation budget for decoding one frame; see the module docs.
pub const DECODE_BUDGET_BYTES: usize = 4 * MAX_FRAME_BYTES;

/// The type of [`CONFIG`].
pub type WireConfig = Configuration<LittleEndian, Varint, Limit<DECODE_BUDGET_BYTES>>;

/// The one bincode configuration of protocol version 1.
pub const CONFIG: WireConfig = bincode::config::standard()
    .with_little_endian()
    .with_variable_int_encoding()
    .with_limit::<DECODE_BUDGET_BYTES>();

/// Why a frame could not be decoded. Every message says what was being
/// decoded and where it went wrong.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// The frame is longer than [`MAX_FRAME_BYTES`].
    #[error("frame of {len} bytes exceeds the limit of {max} bytes")]
    TooLarge {
        /// Frame length.
        len: usize,
        /// The limit.
        max: usize,
    },
    /// The bytes are not a valid encoding of the message type (truncated,
    /// unknown discriminant, invalid UTF-8, bad bool, over budget, ...).
    /// The text names the message type, the byte offset at which decoding
    /// stopped, and the reason.
    #[error("malformed frame: {0}")]
    Malformed(String),
    /// A complete message was decoded but the frame holds more bytes.
    #[error(
        "{message} ends at byte {consumed} but the frame has {len} bytes ({} trailing)",
        len - consumed
    )]
    TrailingBytes {
        /// Message type that was decoded.
        message: &'static str,
        /// Bytes the message used.
        consumed: usize,
        /// Frame length.
        len: usize,
    },
}

impl DecodeError {
    /// The [`ErrorCode`] a server answers this with.
    pub const fn code(&self) -> ErrorCode {
        match self {
            DecodeError::TooLarge { .. } => ErrorCode::TooLarge,
            DecodeError::Malformed(_) | DecodeError::TrailingBytes { .. } => ErrorCode::BadFrame,
        }
    }
}

/// Encodes a client message into one frame.
pub fn encode_client(msg: &ClientMessage) -> Vec<u8> {
    encode(msg)
}

/// Encodes a server message into one frame. The result may exceed
/// [`MAX_FRAME_BYTES`] (a keyframe of a huge atlas); a server must check
/// the length before sending, since peers will refuse such a frame.
pub fn encode_server(msg: &ServerMessage) -> Vec<u8> {
    encode(msg)
}

/// Encodes a `Welcome` for a peer that announced protocol `version`: the
/// message as it is for [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION); for
/// version 3 with its `protocol_version` set to 3 and the `SceneInfo`
/// without `lights`; for version 2 also every `SurfaceInfo` without `uvs`,
/// which version 2 does not have, or `None` when a surface needs them (the
/// client could not draw it) or `msg` is no `Welcome`.
pub fn encode_welcome_for(version: u16, msg: &ServerMessage) -> Option<Vec<u8>> {
    let ServerMessage::Welcome {
        server,
        role,
        capabilities,
        scene,
        ..
    } = msg
    else {
        return None;
    };
    if version == crate::PROTOCOL_VERSION {
        return Some(encode(msg));
    }
    let fits = match version {
        3 => true,
        2 => scene.surfaces.iter().all(|s| s.uvs.is_empty()),
        _ => false,
    };
    fits.then(|| {
        encode(&OlderWelcome {
            version,
            server,
            role: *role,
            capabilities: *capabilities,
            scene,
        })
    })
}

/// An older version's `Welcome`, for [`encode_welcome_for`]: version 4's
/// with `protocol_version` set to `version`, the `SceneInfo` without
/// `lights` (versions 2 and 3), and every `SurfaceInfo` without `uvs`
/// (version 2), encoded from version 4's values as bincode encodes a
/// derived type (an enum variant as its index then its fields, a struct as
/// its fields in order, a `Vec` as its length then its items). `Welcome` is
/// variant 0 in every version; the committed vectors of the older versions
/// (`tests/vectors/v2/`, `tests/vectors/v3/`) check the bytes.
struct OlderWelcome<'a> {
    version: u16,
    server: &'a str,
    role: Role,
    capabilities: u32,
    scene: &'a SceneInfo,
}

impl Encode for OlderWelcome<'_> {
    fn encode<E: bincode::enc::Encoder>(
        &self,
        encoder: &mut E,
    ) -> Result<(), bincode::error::EncodeError> {
        let scene = self.scene;
        (
            0u32,
            self.version,
            self.server,
            self.role,
            self.capabilities,
        )
            .encode(encoder)?;
        (
            &scene.id,
            scene.atlas_width,
            scene.atlas_height,
            scene.tile_size,
            scene.format,
            &scene.objects,
            &scene.materials,
        )
            .encode(encoder)?;
        (scene.surfaces.len() as u64).encode(encoder)?;
        for s in &scene.surfaces {
            (&s.name, s.object, s.material, s.corners, s.rect).encode(encoder)?;
            if self.version >= 3 {
                s.uvs.encode(encoder)?;
            }
        }
        Ok(())
    }
}

/// Decodes one client frame. Never panics, whatever the bytes.
pub fn decode_client(bytes: &[u8]) -> Result<ClientMessage, DecodeError> {
    decode(bytes, "ClientMessage")
}

/// Decodes one server frame. Never panics, whatever the bytes.
pub fn decode_server(bytes: &[u8]) -> Result<ServerMessage, DecodeError> {
    decode(bytes, "ServerMessage")
}

fn encode<T: bincode::Encode>(msg: &T) -> Vec<u8> {
    // Encoding into a Vec only fails if an Encode impl fails; ours do not.
    bincode::encode_to_vec(msg, CONFIG).expect("encoding a Lightwire message cannot fail")
}

fn decode<T: bincode::Decode<()>>(bytes: &[u8], message: &'static str) -> Result<T, DecodeError> {
    if bytes.len() > MAX_FRAME_BYTES {
        return Err(DecodeError::TooLarge {
            len: bytes.len(),
            max: MAX_FRAME_BYTES,
        });
    }
    let mut reader = TrackingReader { bytes, pos: 0 };
    match bincode::decode_from_reader::<T, _, _>(&mut reader, CONFIG) {
        Ok(value) if reader.pos == bytes.len() => Ok(value),
        Ok(_) => Err(DecodeError::TrailingBytes {
            message,
            consumed: reader.pos,
            len: bytes.len(),
        }),
        Err(e) => Err(DecodeError::Malformed(format!(
            "{message} at byte {} of {}: {}",
            reader.pos,
            bytes.len(),
            describe(&e)
        ))),
    }
}

/// bincode's own Display is its Debug; say it in words where it matters.
fn describe(e: &bincode::error::DecodeError) -> String {
    use bincode::error::DecodeError as E;
    match e {
        E::UnexpectedEnd { additional } => {
            format!("frame ends early ({additional} more bytes needed)")
        }
        E::UnexpectedVariant {
            type_name, found, ..
        } => format!("unknown discriminant {found} for {type_name}"),
        E::LimitExceeded => {
            format!("a length prefix claims more than the {DECODE_BUDGET_BYTES}-byte decode budget")
        }
        E::Utf8 { inner } => format!("string is not UTF-8 ({inner})"),
        E::InvalidBooleanValue(v) => format!("bool byte is {v}, not 0 or 1"),
        E::OutsideUsizeRange(v) => format!("length {v} does not fit in usize"),
        E::InvalidIntegerType { expected, found } => {
            format!("varint tag for {found:?} where {expected:?} was expected")
        }
        other => other.to_string(),
    }
}

/// A slice reader that remembers how far it got, so errors can say where.
struct TrackingReader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Reader for TrackingReader<'_> {
    #[inline]
    fn read(&mut self, out: &mut [u8]) -> Result<(), bincode::error::DecodeError> {
        let rest = &self.bytes[self.pos..];
        if out.len() > rest.len() {
            return Err(bincode::error::DecodeError::UnexpectedEnd {
                additional: out.len() - rest.len(),
            });
        }
        out.copy_from_slice(&rest[..out.len()]);
        self.pos += out.len();
        Ok(())
    }

    #[inline]
    fn peek_read(&mut self, n: usize) -> Option<&[u8]> {
        self.bytes[self.pos..].get(..n)
    }

    #[inline]
    fn consume(&mut self, n: usize) {
        self.pos = (self.pos + n).min(self.bytes.len());
    }
}
