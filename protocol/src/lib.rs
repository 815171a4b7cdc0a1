//! Lightwire wire protocol: message types, the bincode codec, and the
//! lightmap tile codec.
//!
//! # Data flow
//!
//! A client opens a WebSocket and sends [`ClientMessage::Hello`]. The server
//! answers with [`ServerMessage::Welcome`] (its role decision and the
//! [`SceneInfo`] a thin client needs to draw), then a
//! [`ServerMessage::Keyframe`] that carries every tile of the current
//! lightmap, then a [`ServerMessage::Delta`] for every version it publishes.
//! Each WebSocket binary frame holds exactly one message, encoded by
//! [`encode_client`] / [`encode_server`] and decoded by [`decode_client`] /
//! [`decode_server`] (bincode 2, one fixed configuration: see [`codec`]).
//!
//! On the server, a [`lightmap::Encoder`] quantizes each solver output
//! (RGB9E5 by default), compares it with what it last published, and emits
//! a [`Delta`] whose tiles are residuals for the texels that left its error
//! budget (the rule is on [`lightmap::Encoder`]).
//! On the client, a [`lightmap::Lightmap`] applies keyframes and deltas. The
//! encoder keeps exactly the state a client reconstructs, so both sides hold
//! bit-identical texels at every version.
//!
//! PROTOCOL.md at the repository root documents every byte; the golden
//! vectors in `protocol/tests/vectors/` pin them.
//!
//! [`backoff`] is the reconnect policy every peer that dials another (the
//! client library, the relay's upstream) follows, so that a fleet does not
//! reconnect to a restarted server in lockstep.
//!
//! [`script`] reads transform scripts (keyframed poses and light states
//! over time), the streams `lightwire-client drive`/`load` send and the
//! server's benchmarks replay.
//!
//! [`tone`] is the one tone curve (white point, exposure, curve, sRGB) that
//! every picture of a lightmap uses: `bake`'s PNGs, the client's renderer
//! and, in JavaScript, the dashboard.
//!
//! This crate must never depend on tokio or wgpu, so that every client — a
//! game, a load tester, the dashboard's JavaScript twin — can share it.

pub mod backoff;
pub mod codec;
pub mod error_code;
pub mod lightmap;
pub mod messages;
pub mod script;
pub mod tone;

pub use codec::{
    DecodeError, decode_client, decode_server, encode_client, encode_server, encode_welcome_for,
};
pub use error_code::ErrorCode;
pub use messages::{
    ClientMessage, Delta, Keyframe, LightInfo, LightState, LightStatus, LightType, MaterialInfo,
    ObjectInfo, ObjectPose, ObjectSeq, PixelFormat, Pose, Role, SceneInfo, ServerMessage, Stats,
    SurfaceInfo, Tile, unix_micros,
};

/// The protocol version a peer announces in its handshake. Bumped on any
/// incompatible change to PROTOCOL.md.
///
/// Version 2 (from 1): `Delta` tiles are residuals onto the tile a receiver
/// holds instead of the tile's new texels (PROTOCOL.md §5); no message
/// layout changed.
///
/// Version 3 (from 2): `SurfaceInfo` ends with `uvs`, its corners'
/// lightmap coordinates where they do not follow from its rectangle (a
/// triangle lit on its mesh's own lightmap UVs). A server still answers a
/// version 2 client ([`MIN_PROTOCOL_VERSION`], [`encode_welcome_for`]) on
/// every scene that has no such surface.
///
/// Version 4 (from 3): lights. `SceneInfo` ends with `lights`; a client
/// sets a light's state with `SetLight` (client discriminant 4) and, when
/// its `Hello` sets [`HELLO_LIGHTS`], receives the states each version was
/// lit with in `Lights` (server discriminant 7); error codes 11
/// (`UnknownLight`) and 12 (`InvalidLight`). Sequence numbers of
/// transforms and lights compare in serial-number order
/// ([`seq_is_newer`]), so no value freezes an object or a light. A server
/// still answers version 3 (and 2) clients with their `Welcome`, without
/// the lights, and refuses their `SetLight`.
pub const PROTOCOL_VERSION: u16 = 4;

/// The oldest version a server answers: version 2 and 3 clients get their
/// version's `Welcome` (without `SceneInfo::lights`; version 2 also without
/// `SurfaceInfo::uvs`, on scenes that need none).
pub const MIN_PROTOCOL_VERSION: u16 = 2;

/// Whether sequence number `seq` is newer than `latest`, in serial-number
/// order (RFC 1982 with 64 bits): `seq` is newer when it is one of the
/// 2^63 − 1 values after `latest`, counting on from `u64::MAX` to 0. So
/// after `u64::MAX` comes 0, and whatever seq a driver sends, the next
/// value is newer still: no seq freezes an object or a light. A receiver
/// starts each object and light at `latest = 0`, so the first seq must be
/// in 1..=2^63 − 1; seqs from the protocol's counters (1, 2, 3, ...) never
/// meet the wrap.
pub fn seq_is_newer(seq: u64, latest: u64) -> bool {
    let ahead = seq.wrapping_sub(latest);
    ahead != 0 && ahead < 1 << 63
}

/// `Welcome.capabilities` bit: the server serves the scene's geometry as
/// glTF binary at `/api/scenes/{id}/scene.glb` on the host and port of the
/// WebSocket (`http` for `ws`, `https` for `wss`; `id` is
/// `SceneInfo::id`), lightmap UVs as `TEXCOORD_1`, readable with the
/// same token as the connection (PROTOCOL.md §3, "Capabilities").
/// Receivers ignore bits they do not know, so older clients are
/// unaffected.
pub const CAP_SCENE_GLB: u32 = 1;

/// `Welcome.capabilities` bit: the server sends [`ServerMessage::Poses`]
/// to a client whose `Hello` set [`HELLO_POSES`] (PROTOCOL.md §3,
/// "Capabilities").
pub const CAP_POSES: u32 = 2;

/// `Welcome.capabilities` bit: the server sends [`ServerMessage::Lights`]
/// to a version 4 client whose `Hello` set [`HELLO_LIGHTS`], and follows
/// drivers' [`ClientMessage::SetLight`] (PROTOCOL.md §3,
/// "Capabilities"). `lightwire serve` sets it, and a relay while its
/// upstream does (it forwards `SetLight` upstream and passes the
/// upstream's `Lights` on).
pub const CAP_LIGHTS: u32 = 4;

/// `Hello.capabilities` bit: send me [`ServerMessage::Poses`], the poses of
/// the dynamic objects each lightmap version was lit for, so that a
/// viewer that does not drive draws them where their light is. A server
/// without [`CAP_POSES`] ignores it; one with it never sends `Poses` to a
/// client that did not ask, so older clients never see the variant.
pub const HELLO_POSES: u32 = 1;

/// `Hello.capabilities` bit: send me [`ServerMessage::Lights`], the
/// lights' states each lightmap version was lit with (version 4 and
/// later; a server ignores it from an older client, which could not
/// decode the variant).
pub const HELLO_LIGHTS: u32 = 2;

/// The path of the scene's glTF binary ([`CAP_SCENE_GLB`]), relative to
/// the server's origin: `/api/scenes/{id}/scene.glb` with `id`
/// percent-encoded as a path segment.
pub fn scene_glb_path(id: &str) -> String {
    let mut path = String::from("/api/scenes/");
    for b in id.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            path.push(b as char);
        } else {
            path.push_str(&format!("%{b:02X}"));
        }
    }
    path.push_str("/scene.glb");
    path
}

/// The `UnsupportedVersion` message for a peer that announced `theirs`:
/// what this side speaks and what to do about it.
pub fn version_mismatch(theirs: u16) -> String {
    let what = if theirs < MIN_PROTOCOL_VERSION {
        "the client is older than this server: since version 2, delta tiles are residuals onto the tile the client holds, which a version 1 client would draw as texels; upgrade the client"
    } else if theirs < 3 {
        "this scene has triangles lit on their mesh's own lightmap UVs, whose texture coordinates only version 3's SurfaceInfo carries; upgrade the client"
    } else if theirs < PROTOCOL_VERSION {
        "version 3 clients are served without lights; this request needs version 4 (SetLight, Lights, SceneInfo.lights); upgrade the client"
    } else {
        "the client is newer than this server; upgrade the server or use a client that speaks this version"
    };
    format!("this server speaks protocol {PROTOCOL_VERSION}, the client sent {theirs}: {what}")
}

/// The largest encoded message, in bytes, that a decoder accepts. Larger
/// frames are rejected with [`DecodeError::TooLarge`] before any parsing, so
/// a peer cannot make us allocate more than a bounded amount per frame.
pub const MAX_FRAME_BYTES: usize = 8 * 1024 * 1024;

/// The default edge length of a lightmap tile, in texels.
pub const DEFAULT_TILE_SIZE: u16 = 8;

#[cfg(test)]
mod tests {
    use super::{scene_glb_path, seq_is_newer};

    #[test]
    fn seqs_compare_in_serial_number_order_so_none_freezes() {
        assert!(seq_is_newer(1, 0));
        assert!(seq_is_newer(8, 7));
        assert!(!seq_is_newer(7, 7));
        assert!(!seq_is_newer(6, 7));
        assert!(!seq_is_newer(0, 0), "the first seq is at least 1");
        // The largest value is newer than a small one...
        assert!(seq_is_newer(u64::MAX / 2, 1));
        // ...and still has values newer than itself: 0, 1, ... after u64::MAX.
        assert!(seq_is_newer(0, u64::MAX));
        assert!(seq_is_newer(5, u64::MAX));
        assert!(seq_is_newer(u64::MAX, u64::MAX - 1));
        // Exactly half way round is not newer either way.
        assert!(!seq_is_newer(1 << 63, 0));
        assert!(seq_is_newer(0, 1 << 63) == seq_is_newer(1 << 63, 0));
        // Whatever a driver sent, latest + 1 is accepted.
        for latest in [
            0,
            1,
            1 << 62,
            (1 << 63) - 1,
            1 << 63,
            u64::MAX - 1,
            u64::MAX,
        ] {
            assert!(seq_is_newer(latest.wrapping_add(1), latest), "{latest}");
        }
    }

    #[test]
    fn the_scene_glb_path_percent_encodes_the_id_as_one_segment() {
        assert_eq!(
            scene_glb_path("cornell-large"),
            "/api/scenes/cornell-large/scene.glb"
        );
        assert_eq!(scene_glb_path("a b/c"), "/api/scenes/a%20b%2Fc/scene.glb");
        assert_eq!(scene_glb_path("é"), "/api/scenes/%C3%A9/scene.glb");
    }
}
