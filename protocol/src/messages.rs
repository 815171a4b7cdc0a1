//! The message types, exactly as they travel. Field order here *is* the wire
//! order (bincode writes fields in declaration order), and variant order is
//! the wire discriminant: never reorder, only append — and bump
//! [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION) for anything else.

use bincode::{Decode, Encode};
use serde::{Deserialize, Serialize};

use crate::ErrorCode;

/// Microseconds since the Unix epoch (0 if the clock is before it): the
/// clock of `Stats::server_time_us` and of a transform's `client_time_us`.
pub fn unix_micros() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// What a token lets a connection do. Decided by the server, announced in
/// [`ServerMessage::Welcome`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Encode, Decode, Serialize, Deserialize)]
pub enum Role {
    /// Watches lightmaps and stats; may not send transforms (wire value 0).
    Viewer,
    /// A viewer that may also move dynamic objects (wire value 1).
    Driver,
    /// A driver that may also use administrative endpoints (wire value 2).
    Admin,
}

/// A rigid transform with uniform scale: `p' = translation + rotation * (scale * p)`.
#[derive(Clone, Copy, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct Pose {
    /// World-space translation.
    pub translation: [f32; 3],
    /// Unit quaternion, in the order x, y, z, w.
    pub rotation: [f32; 4],
    /// Uniform scale, strictly positive.
    pub scale: f32,
}

impl Pose {
    /// The identity pose.
    pub const IDENTITY: Pose = Pose {
        translation: [0.0; 3],
        rotation: [0.0, 0.0, 0.0, 1.0],
        scale: 1.0,
    };

    /// Largest accepted deviation of `|rotation|` from 1.
    pub const ROTATION_TOLERANCE: f64 = 1e-3;

    /// Largest accepted magnitude of each translation component, in scene
    /// units (metres): 100 km. Beyond it, squared distances and the
    /// products of the solver's `f32` arithmetic lose the precision light
    /// needs (a translation of 1e30 squares to infinity).
    pub const MAX_TRANSLATION: f32 = 1e5;

    /// Accepted range of the uniform scale, both ends included: an object
    /// may shrink or grow a thousandfold, not to a point or past the
    /// precision of element areas (which scale with its square).
    pub const SCALE_RANGE: (f32, f32) = (1e-3, 1e3);

    /// Checks what the codec cannot: every number finite, each translation
    /// component within [`Pose::MAX_TRANSLATION`], the rotation a unit
    /// quaternion within [`Pose::ROTATION_TOLERANCE`], the scale within
    /// [`Pose::SCALE_RANGE`]. The server answers a failing transform with
    /// [`ErrorCode::InvalidPose`] and the returned reason.
    pub fn validate(&self) -> Result<(), &'static str> {
        if !self.translation.iter().all(|v| v.is_finite()) {
            return Err("translation is not finite");
        }
        if !self.rotation.iter().all(|v| v.is_finite()) {
            return Err("rotation is not finite");
        }
        if !self.scale.is_finite() {
            return Err("scale is not finite");
        }
        if self.scale <= 0.0 {
            return Err("scale is not positive");
        }
        if self
            .translation
            .iter()
            .any(|v| v.abs() > Self::MAX_TRANSLATION)
        {
            return Err("translation is out of range (each component at most 1e5 in magnitude)");
        }
        if self.scale < Self::SCALE_RANGE.0 || self.scale > Self::SCALE_RANGE.1 {
            return Err("scale is out of range (1e-3 to 1e3)");
        }
        let norm = self
            .rotation
            .iter()
            .map(|&v| f64::from(v) * f64::from(v))
            .sum::<f64>()
            .sqrt();
        if (norm - 1.0).abs() > Self::ROTATION_TOLERANCE {
            return Err("rotation is not a unit quaternion (|q| differs from 1 by more than 1e-3)");
        }
        Ok(())
    }
}

impl Default for Pose {
    fn default() -> Self {
        Pose::IDENTITY
    }
}

/// "Object `object` at transform sequence number `seq`": what a published
/// frame reflects, so a driver can measure transform-to-light latency.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Encode, Decode, Serialize, Deserialize)]
pub struct ObjectSeq {
    /// Index into [`SceneInfo::objects`].
    pub object: u32,
    /// The latest transform sequence number of that object that the frame includes.
    pub seq: u64,
}

/// A dynamic object's pose in a published version
/// ([`ServerMessage::Poses`]).
#[derive(Clone, Copy, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct ObjectPose {
    /// Index into [`SceneInfo::objects`].
    pub object: u32,
    /// The transform sequence number that set this pose (0: the scene
    /// file's pose, no transform yet).
    pub seq: u64,
    /// The pose the version's lightmap was lit for.
    pub pose: Pose,
}

/// Messages a client sends. Wire discriminants: Hello 0, Transform 1, Resync 2, Ping 3,
/// SetLight 4 (since version 4).
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub enum ClientMessage {
    /// First message of every connection.
    Hello {
        /// Must equal [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION), else the
        /// server answers [`ErrorCode::UnsupportedVersion`] and closes.
        protocol_version: u16,
        /// Free-form client name and version, for logs.
        client: String,
        /// Access token; `None` in development mode.
        token: Option<String>,
        /// Capability bits; v1 defines none (send 0, ignore unknown bits).
        capabilities: u32,
    },
    /// Move a dynamic object (drivers and admins only).
    Transform {
        /// Index into [`SceneInfo::objects`]; must be a dynamic object.
        object: u32,
        /// Per-object sequence number, newer than the last accepted one
        /// in serial-number order ([`seq_is_newer`](crate::seq_is_newer));
        /// the latest wins.
        seq: u64,
        /// The new pose; see [`Pose::validate`].
        pose: Pose,
        /// The client's clock when it sent this, in microseconds; echoed
        /// nowhere, useful to the client's own latency bookkeeping and logs.
        client_time_us: u64,
    },
    /// "My lightmap is not at the version you think": ask for a fresh keyframe.
    Resync {
        /// The version the client holds, if any (for logs and metrics).
        have_version: Option<u64>,
    },
    /// Liveness / round-trip probe; answered by [`ServerMessage::Pong`].
    Ping {
        /// Echoed verbatim.
        nonce: u64,
    },
    /// Set a light's state: on or off, colour, intensity, and where it is
    /// and points (drivers and admins only; since version 4).
    SetLight {
        /// Index into [`SceneInfo::lights`].
        light: u32,
        /// Per-light sequence number, newer than the last accepted one in
        /// serial-number order ([`seq_is_newer`](crate::seq_is_newer));
        /// the latest wins.
        seq: u64,
        /// The light's whole new state; see [`LightState::validate`].
        state: LightState,
        /// The client's clock when it sent this, in microseconds, as
        /// `Transform`'s.
        client_time_us: u64,
    },
}

/// Messages the server sends. Wire discriminants: Welcome 0, Keyframe 1,
/// Delta 2, Stats 3, Error 4, Pong 5, Poses 6, Lights 7 (since version 4).
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub enum ServerMessage {
    /// Answer to a successful Hello; followed by a Keyframe (preceded by
    /// `Poses` for a client that asked for them).
    Welcome {
        /// The server's [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION).
        protocol_version: u16,
        /// Free-form server name and version, for logs.
        server: String,
        /// What this connection may do.
        role: Role,
        /// Capability bits: [`CAP_SCENE_GLB`](crate::CAP_SCENE_GLB); ignore
        /// bits you do not know.
        capabilities: u32,
        /// Everything a thin client needs to draw the scene.
        scene: SceneInfo,
    },
    /// A whole lightmap.
    Keyframe(Keyframe),
    /// The tiles that changed from `base_version` to `version`.
    Delta(Delta),
    /// Solver and service statistics, for dashboards.
    Stats(Stats),
    /// Something the client sent was refused.
    Error {
        /// Machine-readable reason; see [`ErrorCode`].
        code: ErrorCode,
        /// Human-readable detail.
        message: String,
    },
    /// Answer to [`ClientMessage::Ping`].
    Pong {
        /// The ping's nonce.
        nonce: u64,
    },
    /// Where the dynamic objects are in lightmap version `version`: sent
    /// only to a client whose `Hello` set
    /// [`HELLO_POSES`](crate::HELLO_POSES), immediately before the
    /// `Keyframe` or `Delta` of `version`, whenever a pose differs from
    /// those last sent on the connection (so before the first lightmap,
    /// when the poses are known and the scene has dynamic objects). Every
    /// dynamic object, in object order.
    Poses {
        /// The version these poses were lit for.
        version: u64,
        /// One per dynamic object.
        poses: Vec<ObjectPose>,
    },
    /// The lights' states in lightmap version `version`: sent only to a
    /// client whose `Hello` set [`HELLO_LIGHTS`](crate::HELLO_LIGHTS) (and
    /// announced version 4 or later), immediately before the `Keyframe` or
    /// `Delta` of `version`, whenever a state differs from those last sent
    /// on the connection (so before the first lightmap, when the scene has
    /// lights). Every light, in light order. Since version 4.
    Lights {
        /// The version these states were lit with.
        version: u64,
        /// One per light of [`SceneInfo::lights`].
        lights: Vec<LightStatus>,
    },
}

impl ServerMessage {
    /// The message's name as PROTOCOL.md spells it, for logs and errors.
    pub fn name(&self) -> &'static str {
        match self {
            ServerMessage::Welcome { .. } => "Welcome",
            ServerMessage::Keyframe(_) => "Keyframe",
            ServerMessage::Delta(_) => "Delta",
            ServerMessage::Stats(_) => "Stats",
            ServerMessage::Error { .. } => "Error",
            ServerMessage::Pong { .. } => "Pong",
            ServerMessage::Poses { .. } => "Poses",
            ServerMessage::Lights { .. } => "Lights",
        }
    }
}

/// The scene as a thin client sees it: atlas layout, objects, materials, and
/// the quads to draw with their place in the atlas.
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct SceneInfo {
    /// Scene identifier (the `{id}` of `/ws/scenes/{id}`).
    pub id: String,
    /// Lightmap width in texels.
    pub atlas_width: u32,
    /// Lightmap height in texels.
    pub atlas_height: u32,
    /// Tile edge length in texels (default [`DEFAULT_TILE_SIZE`](crate::DEFAULT_TILE_SIZE)).
    pub tile_size: u16,
    /// Pixel format of every tile payload.
    pub format: PixelFormat,
    /// Objects; [`ObjectSeq::object`] and [`SurfaceInfo::object`] index this.
    pub objects: Vec<ObjectInfo>,
    /// Materials; [`SurfaceInfo::material`] indexes this.
    pub materials: Vec<MaterialInfo>,
    /// Quads to draw.
    pub surfaces: Vec<SurfaceInfo>,
    /// The point, spot and directional lights, which
    /// [`ClientMessage::SetLight`] and [`LightStatus::light`] index.
    /// Since version 4.
    pub lights: Vec<LightInfo>,
}

impl SceneInfo {
    /// Whether `self` and `other` describe the same scene, whatever states
    /// their lights are in (PROTOCOL.md §3, "The lights' states a
    /// `Welcome` tells"): a `Welcome` tells the lights as they are now,
    /// which a driver's `SetLight` changes without changing the scene.
    /// Everything else counts, the lights' names, kinds, ranges, cones and
    /// angular radii included. A peer that reconnects (a relay to its
    /// upstream, a client to its server) keeps what it holds when the new
    /// `Welcome`'s description is the same.
    pub fn same_description(&self, other: &SceneInfo) -> bool {
        if self.lights.len() != other.lights.len() {
            return false;
        }
        let mut other = other.clone();
        for (theirs, mine) in other.lights.iter_mut().zip(&self.lights) {
            theirs.state = mine.state;
        }
        *self == other
    }
}

/// What kind of light (wire values: Point 0, Spot 1, Directional 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Encode, Decode, Serialize, Deserialize)]
pub enum LightType {
    /// Radiates equally in every direction from its position.
    Point,
    /// Radiates into a cone about its direction from its position.
    Spot,
    /// Light from a distant disc (the sun), travelling along its direction.
    Directional,
}

/// One light of the scene: what it is, which never changes, and its state
/// when the `Welcome` was built.
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct LightInfo {
    /// Name from the scene file (or the glTF node).
    pub name: String,
    /// What kind of light.
    pub kind: LightType,
    /// glTF's `range` of a point or spot light (metres), beyond which it
    /// gives nothing; `None`: the inverse square alone.
    pub range: Option<f32>,
    /// A spot's inner and outer cone angles, radians from its axis (glTF's
    /// smooth falloff between them); `[0, 0]` for other kinds.
    pub cone: [f32; 2],
    /// A directional light's angular radius, radians (0: hard shadows;
    /// the sun's is about 0.0046); 0 for other kinds.
    pub angular_radius: f32,
    /// Its state.
    pub state: LightState,
}

/// The part of a light that can change while clients watch.
#[derive(Clone, Copy, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct LightState {
    /// Whether it gives light at all.
    pub on: bool,
    /// Linear RGB colour, each channel in [0, 1].
    pub color: [f32; 3],
    /// Radiant intensity on the axis (W/sr) of a point or spot light; a
    /// directional light's irradiance at normal incidence (W/m²). The
    /// light sends `color × intensity` per channel.
    pub intensity: f32,
    /// Where a point or spot light is (world space, metres); carried but
    /// unused for a directional light.
    pub position: [f32; 3],
    /// Unit vector: a spot's axis, or where a directional light's light
    /// travels; carried but unused for a point light.
    pub direction: [f32; 3],
}

impl LightState {
    /// Largest accepted intensity (W/sr, or W/m² for a directional light):
    /// a thousand suns.
    pub const MAX_INTENSITY: f32 = 1e6;

    /// Largest accepted deviation of `|direction|` from 1.
    pub const DIRECTION_TOLERANCE: f64 = 1e-3;

    /// Checks what the codec cannot: every number finite, each colour
    /// channel in [0, 1], the intensity in [0, [`LightState::MAX_INTENSITY`]],
    /// each position component within [`Pose::MAX_TRANSLATION`], the
    /// direction a unit vector within [`LightState::DIRECTION_TOLERANCE`],
    /// in that order. The server answers a failing `SetLight` with
    /// [`ErrorCode::InvalidLight`] and the returned reason.
    pub fn validate(&self) -> Result<(), &'static str> {
        if !self.color.iter().all(|v| v.is_finite()) {
            return Err("color is not finite");
        }
        if !self.intensity.is_finite() {
            return Err("intensity is not finite");
        }
        if !self.position.iter().all(|v| v.is_finite()) {
            return Err("position is not finite");
        }
        if !self.direction.iter().all(|v| v.is_finite()) {
            return Err("direction is not finite");
        }
        if self.color.iter().any(|v| !(0.0..=1.0).contains(v)) {
            return Err("color is out of range (each channel in [0, 1])");
        }
        if !(0.0..=Self::MAX_INTENSITY).contains(&self.intensity) {
            return Err("intensity is out of range (0 to 1e6)");
        }
        if self
            .position
            .iter()
            .any(|v| v.abs() > Pose::MAX_TRANSLATION)
        {
            return Err("position is out of range (each component at most 1e5 in magnitude)");
        }
        let norm = self
            .direction
            .iter()
            .map(|&v| f64::from(v) * f64::from(v))
            .sum::<f64>()
            .sqrt();
        if (norm - 1.0).abs() > Self::DIRECTION_TOLERANCE {
            return Err("direction is not a unit vector (|d| differs from 1 by more than 1e-3)");
        }
        Ok(())
    }
}

/// A light's state in a published version ([`ServerMessage::Lights`]).
#[derive(Clone, Copy, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct LightStatus {
    /// Index into [`SceneInfo::lights`].
    pub light: u32,
    /// The `SetLight` sequence number that set this state (0: the scene
    /// file's state, no `SetLight` yet).
    pub seq: u64,
    /// The state the version's lightmap was lit with.
    pub state: LightState,
}

/// One object of the scene.
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct ObjectInfo {
    /// Name from the scene file.
    pub name: String,
    /// Whether drivers may move it.
    pub dynamic: bool,
    /// Its pose when the Welcome was built.
    pub pose: Pose,
}

/// One material of the scene.
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct MaterialInfo {
    /// Name from the scene file.
    pub name: String,
    /// Diffuse reflectance, linear RGB in [0, 1).
    pub albedo: [f32; 3],
    /// Emitted radiosity, linear RGB, >= 0.
    pub emission: [f32; 3],
}

/// One quad: geometry in object space plus its rectangle in the atlas.
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct SurfaceInfo {
    /// Name from the scene file.
    pub name: String,
    /// Index into [`SceneInfo::objects`].
    pub object: u32,
    /// Index into [`SceneInfo::materials`].
    pub material: u32,
    /// The four corners in object-local coordinates, in winding order.
    pub corners: [[f32; 3]; 4],
    /// Atlas rectangle: x, y, width, height in texels.
    pub rect: [u32; 4],
    /// Lightmap coordinates of the four corners, normalized (`u = x /
    /// atlas_width`, `v = y / atlas_height`, v = 0 the atlas's first row),
    /// when they do not follow from `rect` (a triangle, or a parallelogram
    /// of triangles, lit on its mesh's own lightmap UVs); empty otherwise.
    /// Since version 3.
    pub uvs: Vec<[f32; 2]>,
}

impl SurfaceInfo {
    /// The lightmap coordinates of the four corners as a client draws
    /// them: `uvs` when it holds four, else corner 0 at the centre of texel
    /// (x, y) of `rect`, corner 1 of (x + w - 1, y), corner 2 of (x + w - 1,
    /// y + h - 1), corner 3 of (x, y + h - 1) (PROTOCOL.md §3).
    pub fn corner_uvs(&self, atlas_width: u32, atlas_height: u32) -> [[f32; 2]; 4] {
        if let [a, b, c, d] = self.uvs[..] {
            return [a, b, c, d];
        }
        let [x, y, w, h] = self.rect.map(f64::from);
        let (aw, ah) = (
            f64::from(atlas_width.max(1)),
            f64::from(atlas_height.max(1)),
        );
        let u0 = ((x + 0.5) / aw) as f32;
        let u1 = ((x + w - 0.5) / aw) as f32;
        let v0 = ((y + 0.5) / ah) as f32;
        let v1 = ((y + h - 0.5) / ah) as f32;
        [[u0, v0], [u1, v0], [u1, v1], [u0, v1]]
    }
}

/// How a texel is stored in a tile payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Encode, Decode, Serialize, Deserialize)]
pub enum PixelFormat {
    /// 4 bytes per texel: shared-exponent RGB, see [`crate::lightmap::rgb9e5_encode`] (wire value 0).
    Rgb9e5,
    /// 8 bytes per texel: IEEE half floats R, G, B, A (A = 1) (wire value 1).
    Rgba16f,
}

impl PixelFormat {
    /// Bytes per texel in a (decompressed) tile payload.
    pub const fn bytes_per_texel(self) -> usize {
        match self {
            PixelFormat::Rgb9e5 => 4,
            PixelFormat::Rgba16f => 8,
        }
    }
}

/// Every tile of one lightmap version.
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct Keyframe {
    /// The version this keyframe is.
    pub version: u64,
    /// Latest transform seq per object included in this version.
    pub reflected: Vec<ObjectSeq>,
    /// All tiles, each index exactly once (any order).
    pub tiles: Vec<Tile>,
}

impl Keyframe {
    /// The keyframe of `version` whose tile `i` is `tiles[i]` (one zstd
    /// frame each, in index order), reflecting the latest seq per object of
    /// `reflected` (object -> seq, so sorted by object).
    pub fn new(
        version: u64,
        reflected: &std::collections::BTreeMap<u32, u64>,
        tiles: &[Vec<u8>],
    ) -> Keyframe {
        Keyframe {
            version,
            reflected: reflected
                .iter()
                .map(|(&object, &seq)| ObjectSeq { object, seq })
                .collect(),
            tiles: tiles
                .iter()
                .enumerate()
                .map(|(i, data)| Tile {
                    index: i as u32,
                    data: data.clone(),
                })
                .collect(),
        }
    }
}

/// What changed between two versions: residuals of the tiles that changed.
#[derive(Clone, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct Delta {
    /// Apply only onto exactly this version.
    pub base_version: u64,
    /// The version after applying; greater than `base_version`.
    pub version: u64,
    /// Transform seqs newly included since `base_version` (latest per object).
    pub reflected: Vec<ObjectSeq>,
    /// Empty when no tile changed; otherwise one zstd frame holding which
    /// tiles changed (a bitmap) and their residuals, in the layout of
    /// PROTOCOL.md §5 ([`crate::lightmap::residual`] reads and writes it).
    pub residual: Vec<u8>,
}

/// One tile's pixels.
#[derive(Clone, Debug, PartialEq, Eq, Encode, Decode, Serialize, Deserialize)]
pub struct Tile {
    /// Row-major tile index: `tile_y * tiles_x + tile_x`.
    pub index: u32,
    /// One zstd frame; decompresses to the tile's texels, row-major, tile
    /// clipped at the atlas border, each texel little-endian in the
    /// scene's [`PixelFormat`].
    pub data: Vec<u8>,
}

/// Solver and service statistics for one tick.
#[derive(Clone, Copy, Debug, PartialEq, Encode, Decode, Serialize, Deserialize)]
pub struct Stats {
    /// The latest published lightmap version.
    pub version: u64,
    /// Unshot power over total emitted power (0 = converged).
    pub unshot_fraction: f32,
    /// Wall time of the last tick, milliseconds.
    pub tick_ms: f32,
    /// Time spent in the solver during the last tick, milliseconds.
    pub solve_ms: f32,
    /// Time spent redistributing for moved objects during the last tick, milliseconds.
    pub redistribution_ms: f32,
    /// Connected clients on this scene.
    pub clients: u32,
    /// Server clock, microseconds since the Unix epoch.
    pub server_time_us: u64,
}

impl Stats {
    /// What a scene reports before its first publication: version 0,
    /// nothing converged, no clients, no tick timed yet, stamped now.
    pub fn initial() -> Self {
        Self {
            version: 0,
            unshot_fraction: 1.0,
            tick_ms: 0.0,
            solve_ms: 0.0,
            redistribution_ms: 0.0,
            clients: 0,
            server_time_us: crate::unix_micros(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lamp(state: LightState) -> LightInfo {
        LightInfo {
            name: "lamp".into(),
            kind: LightType::Point,
            range: None,
            cone: [0.0; 2],
            angular_radius: 0.0,
            state,
        }
    }

    fn room(lights: Vec<LightInfo>) -> SceneInfo {
        SceneInfo {
            id: "room".into(),
            atlas_width: 1,
            atlas_height: 1,
            tile_size: crate::DEFAULT_TILE_SIZE,
            format: PixelFormat::Rgb9e5,
            objects: Vec::new(),
            materials: Vec::new(),
            surfaces: Vec::new(),
            lights,
        }
    }

    /// Two descriptions whose lights differ only in state are the same
    /// scene; any other difference, of a light or of the rest, is not.
    #[test]
    fn light_states_are_not_part_of_a_scene_s_description() {
        let on = LightState {
            on: true,
            color: [1.0; 3],
            intensity: 4.0,
            position: [0.0, 1.0, 0.0],
            direction: [0.0, -1.0, 0.0],
        };
        let moved_and_off = LightState {
            on: false,
            color: [1.0, 0.5, 0.25],
            intensity: 2.0,
            position: [0.5, 1.0, 0.0],
            direction: [1.0, 0.0, 0.0],
        };
        let a = room(vec![lamp(on)]);
        let b = room(vec![lamp(moved_and_off)]);
        assert_ne!(a, b);
        assert!(a.same_description(&b) && b.same_description(&a));
        assert!(a.same_description(&a));

        let differs = |change: fn(&mut SceneInfo)| {
            let mut c = b.clone();
            change(&mut c);
            assert!(!a.same_description(&c) && !c.same_description(&a), "{c:?}");
        };
        differs(|c| c.lights[0].name = "bulb".into());
        differs(|c| c.lights[0].kind = LightType::Spot);
        differs(|c| c.lights[0].range = Some(5.0));
        differs(|c| c.lights[0].cone = [0.1, 0.2]);
        differs(|c| c.lights[0].angular_radius = 0.0046);
        differs(|c| c.lights.clear());
        differs(|c| c.lights.push(c.lights[0].clone()));
        differs(|c| c.atlas_width = 2);
        differs(|c| c.id = "hall".into());
    }
}
