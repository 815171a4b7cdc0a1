//! The golden vectors: each message spelled out by hand here, its bytes
//! committed in `tests/vectors/NAME.bin` and described in
//! `tests/vectors/manifest.json`. `tests/golden_vectors.rs` checks both
//! directions; `examples/gen_vectors.rs` rewrites the files after an
//! intentional protocol change (and PROTOCOL_VERSION bump).
//!
//! Tile payloads are literal bytes (zstd frames holding one raw block), so
//! the vectors do not depend on the zstd version that would compress them.

#![allow(dead_code)]

use lightwire_protocol::*;

/// Which decoder a vector is for.
#[derive(Clone, Debug, PartialEq)]
pub enum Msg {
    Client(ClientMessage),
    Server(ServerMessage),
}

impl Msg {
    pub fn encode(&self) -> Vec<u8> {
        match self {
            Msg::Client(m) => encode_client(m),
            Msg::Server(m) => encode_server(m),
        }
    }

    pub fn decode_like(&self, bytes: &[u8]) -> Result<Msg, DecodeError> {
        match self {
            Msg::Client(_) => decode_client(bytes).map(Msg::Client),
            Msg::Server(_) => decode_server(bytes).map(Msg::Server),
        }
    }

    pub fn direction(&self) -> &'static str {
        match self {
            Msg::Client(_) => "client",
            Msg::Server(_) => "server",
        }
    }

    pub fn to_json(&self) -> serde_json::Value {
        match self {
            Msg::Client(m) => serde_json::to_value(m).unwrap(),
            Msg::Server(m) => serde_json::to_value(m).unwrap(),
        }
    }
}

pub struct Vector {
    pub name: &'static str,
    pub description: &'static str,
    pub msg: Msg,
}

pub fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

pub fn to_hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// The 3x2 RGB9E5 lightmap (tile size 2) of the keyframe and delta vectors.
pub const ATLAS: (u32, u32, u16) = (3, 2, 2);

/// Tile 0 (2x2 texels) of the keyframe: row 0 = (1, 0.5, 0.25), (0, 0, 0);
/// row 1 = (2, 2, 2), (65408, 0, 0).
pub const KEY_TILE0: &str = "28b52ffd201081000000010181000000000001028cff0100f8";
/// Tile 1 (clipped to 1x2 texels) of the keyframe: (0.125, 0.0625, 1), (3, 0, 0).
pub const KEY_TILE1: &str = "28b52ffd20084100002020008480010088";
/// The delta's residual payload (PROTOCOL.md §5), one zstd frame holding a
/// raw block of 9 bytes: the tile bitmap `02` (tile 1 only), then tile 1's
/// residual in byte planes, taking the keyframe's (0.125, 0.0625, 1),
/// (3, 0, 0) to (1, 1, 1), (0, 0, 0).
pub const DELTA_RESIDUAL: &str = "28b52ffd200949000002c000e000000003f1";

/// The decoded texels, row-major, after the keyframe.
pub const KEY_RGB: [[f32; 3]; 6] = [
    [1.0, 0.5, 0.25],
    [0.0, 0.0, 0.0],
    [0.125, 0.0625, 1.0],
    [2.0, 2.0, 2.0],
    [65408.0, 0.0, 0.0],
    [3.0, 0.0, 0.0],
];

/// The decoded texels, row-major, after keyframe then delta: the
/// keyframe's with texel 2 taken to (1, 1, 1) and texel 5 to (0, 0, 0).
pub const DELTA_RGB: [[f32; 3]; 6] = {
    let mut rgb = KEY_RGB;
    rgb[2] = [1.0, 1.0, 1.0];
    rgb[5] = [0.0, 0.0, 0.0];
    rgb
};

const QUARTER_TURN_Y: [f32; 4] = [
    0.0,
    std::f32::consts::FRAC_1_SQRT_2,
    0.0,
    std::f32::consts::FRAC_1_SQRT_2,
];

pub fn keyframe() -> Keyframe {
    Keyframe {
        version: 1,
        reflected: vec![ObjectSeq { object: 0, seq: 7 }],
        tiles: vec![
            Tile {
                index: 0,
                data: hex(KEY_TILE0),
            },
            Tile {
                index: 1,
                data: hex(KEY_TILE1),
            },
        ],
    }
}

pub fn delta() -> Delta {
    Delta {
        base_version: 1,
        version: 2,
        reflected: vec![ObjectSeq {
            object: 0,
            seq: 300,
        }],
        residual: hex(DELTA_RESIDUAL),
    }
}

pub fn scene() -> SceneInfo {
    SceneInfo {
        id: "cornell".into(),
        atlas_width: 3,
        atlas_height: 2,
        tile_size: 2,
        format: PixelFormat::Rgb9e5,
        objects: vec![ObjectInfo {
            name: "box".into(),
            dynamic: true,
            pose: Pose::IDENTITY,
        }],
        materials: vec![MaterialInfo {
            name: "light".into(),
            albedo: [0.5, 0.5, 0.5],
            emission: [1.0, 1.0, 1.0],
        }],
        surfaces: vec![surface(
            "top",
            [
                [0.0, 1.0, 0.0],
                [1.0, 1.0, 0.0],
                [1.0, 1.0, 1.0],
                [0.0, 1.0, 1.0],
            ],
            Vec::new(),
        )],
        lights: Vec::new(),
    }
}

/// The spot light of [`scene_with_lights`] and [`set_light`]: on, warm,
/// 2.5 W/sr, at (0.5, 0.9, 0.5) pointing straight down.
pub fn spot_state() -> LightState {
    LightState {
        on: true,
        color: [1.0, 0.75, 0.5],
        intensity: 2.5,
        position: [0.5, 0.9, 0.5],
        direction: [0.0, -1.0, 0.0],
    }
}

/// [`scene`] with two lights (version 4): a spot "lamp" (range 4 m, cone
/// 0.25 to 0.5 rad) and a directional "sun" (1,000 W/m², travelling along
/// (0, -0.6, -0.8), angular radius 0.0046 rad), switched off.
pub fn scene_with_lights() -> SceneInfo {
    let mut scene = scene();
    scene.lights = vec![
        LightInfo {
            name: "lamp".into(),
            kind: LightType::Spot,
            range: Some(4.0),
            cone: [0.25, 0.5],
            angular_radius: 0.0,
            state: spot_state(),
        },
        LightInfo {
            name: "sun".into(),
            kind: LightType::Directional,
            range: None,
            cone: [0.0, 0.0],
            angular_radius: 0.0046,
            state: LightState {
                on: false,
                color: [1.0, 1.0, 1.0],
                intensity: 1000.0,
                position: [0.0, 0.0, 0.0],
                direction: [0.0, -0.6, -0.8],
            },
        },
    ];
    scene
}

/// A surface of [`scene`]'s object and material with these `corners`,
/// lit on the whole atlas, its corners' lightmap coordinates `uvs`.
fn surface(name: &str, corners: [[f32; 3]; 4], uvs: Vec<[f32; 2]>) -> SurfaceInfo {
    SurfaceInfo {
        name: name.into(),
        object: 0,
        material: 0,
        corners,
        rect: [0, 0, 3, 2],
        uvs,
    }
}

/// [`scene`] with a second surface: a triangle lit on its mesh's own
/// lightmap UVs, whose corners' lightmap coordinates travel in `uvs`
/// (version 3).
pub fn scene_with_uvs() -> SceneInfo {
    let mut scene = scene();
    scene.surfaces.push(surface(
        "floor/0",
        [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, -1.0],
            [1.0, 0.0, -1.0],
        ],
        vec![[0.25, 0.75], [0.75, 0.75], [0.5, 0.25], [0.5, 0.25]],
    ));
    scene
}

/// The `Hello` of the vectors' client "lw/1".
fn hello(token: Option<&str>, capabilities: u32) -> Msg {
    Msg::Client(ClientMessage::Hello {
        protocol_version: PROTOCOL_VERSION,
        client: "lw/1".into(),
        token: token.map(Into::into),
        capabilities,
    })
}

/// The capabilities of a server that serves `scene.glb` and sends `Poses`.
const GLB_AND_POSES: u32 = CAP_SCENE_GLB | CAP_POSES;

/// The `Welcome` of the vectors' server "lightwire/0.1" to a driver.
pub fn welcome(capabilities: u32, scene: SceneInfo) -> ServerMessage {
    ServerMessage::Welcome {
        protocol_version: PROTOCOL_VERSION,
        server: "lightwire/0.1".into(),
        role: Role::Driver,
        capabilities,
        scene,
    }
}

pub fn all() -> Vec<Vector> {
    use ClientMessage as C;
    use ServerMessage as S;
    vec![
        Vector {
            name: "client_hello",
            description: "Hello with a token: protocol 4, client \"lw/1\", token \"t0k\", no capabilities",
            msg: hello(Some("t0k"), 0),
        },
        Vector {
            name: "client_hello_no_token",
            description: "Hello in development mode (token None); capabilities 0x1_0000 shows a 4-byte varint",
            msg: hello(None, 0x1_0000),
        },
        Vector {
            name: "client_transform",
            description: "Transform object 2 to seq 300 (3-byte varint): translate (1, -0.5, 2.25), quarter turn about +y, scale 1, client time 1.7e15 us (9-byte varint)",
            msg: Msg::Client(C::Transform {
                object: 2,
                seq: 300,
                pose: Pose {
                    translation: [1.0, -0.5, 2.25],
                    rotation: QUARTER_TURN_Y,
                    scale: 1.0,
                },
                client_time_us: 1_700_000_000_000_000,
            }),
        },
        Vector {
            name: "client_resync_none",
            description: "Resync from a client that holds no lightmap",
            msg: Msg::Client(C::Resync { have_version: None }),
        },
        Vector {
            name: "client_resync_some",
            description: "Resync from a client at version 42",
            msg: Msg::Client(C::Resync {
                have_version: Some(42),
            }),
        },
        Vector {
            name: "client_ping",
            description: "Ping with nonce 0xDEADBEEF (5-byte varint)",
            msg: Msg::Client(C::Ping { nonce: 0xDEAD_BEEF }),
        },
        Vector {
            name: "server_welcome",
            description: "Welcome as a driver to scene \"cornell\": 3x2 RGB9E5 atlas, tile size 2, one dynamic object, one material, one surface",
            msg: Msg::Server(welcome(0, scene())),
        },
        Vector {
            name: "server_welcome_scene_glb",
            description: "Welcome as server_welcome, with capability bit 0 (CAP_SCENE_GLB): the scene's glTF binary is at /api/scenes/cornell/scene.glb",
            msg: Msg::Server(welcome(CAP_SCENE_GLB, scene())),
        },
        Vector {
            name: "server_keyframe",
            description: "Keyframe version 1 of the 3x2 atlas: tile 0 (2x2) and tile 1 (clipped to 1x2), reflecting object 0 at seq 7",
            msg: Msg::Server(S::Keyframe(keyframe())),
        },
        Vector {
            name: "server_delta",
            description: "Delta 1 -> 2 onto server_keyframe: tile 1 only (a residual), reflecting object 0 at seq 300",
            msg: Msg::Server(S::Delta(delta())),
        },
        Vector {
            name: "server_stats",
            description: "Stats for version 2",
            msg: Msg::Server(S::Stats(Stats {
                version: 2,
                unshot_fraction: 0.125,
                tick_ms: 16.5,
                solve_ms: 10.25,
                redistribution_ms: 2.0,
                clients: 3,
                server_time_us: 1_700_000_000_000_123,
            })),
        },
        Vector {
            name: "server_error",
            description: "Error Forbidden (5): a viewer sent a Transform",
            msg: Msg::Server(S::Error {
                code: ErrorCode::Forbidden,
                message: "viewer may not send Transform".into(),
            }),
        },
        Vector {
            name: "server_error_unknown_code",
            description: "Error with code 1000, unknown to v1: decodes to ErrorCode::Other(1000) (3-byte varint)",
            msg: Msg::Server(S::Error {
                code: ErrorCode::Other(1000),
                message: "future".into(),
            }),
        },
        Vector {
            name: "client_hello_poses",
            description: "Hello as client_hello with capability bit 0 (HELLO_POSES): send me Poses",
            msg: hello(Some("t0k"), lightwire_protocol::HELLO_POSES),
        },
        Vector {
            name: "server_welcome_poses",
            description: "Welcome as server_welcome, with capability bits 0 and 1 (CAP_SCENE_GLB | CAP_POSES): the server sends Poses to clients that ask",
            msg: Msg::Server(welcome(GLB_AND_POSES, scene())),
        },
        Vector {
            name: "server_poses",
            description: "Poses for version 2 (sent before server_delta): object 0 at seq 300, translated (1, -0.5, 2.25) and turned a quarter about +y, scale 1",
            msg: Msg::Server(S::Poses {
                version: 2,
                poses: vec![ObjectPose {
                    object: 0,
                    seq: 300,
                    pose: Pose {
                        translation: [1.0, -0.5, 2.25],
                        rotation: QUARTER_TURN_Y,
                        scale: 1.0,
                    },
                }],
            }),
        },
        Vector {
            name: "server_welcome_uvs",
            description: "Welcome as server_welcome_poses, with a second surface: a triangle (third corner repeated) lit on its mesh's own lightmap UVs, its corners' lightmap coordinates in uvs (u, v) = (0.25, 0.75), (0.75, 0.75), (0.5, 0.25), (0.5, 0.25)",
            msg: Msg::Server(welcome(GLB_AND_POSES, scene_with_uvs())),
        },
        Vector {
            name: "server_pong",
            description: "Pong echoing nonce 0xDEADBEEF",
            msg: Msg::Server(S::Pong { nonce: 0xDEAD_BEEF }),
        },
        Vector {
            name: "client_hello_lights",
            description: "Hello as client_hello with capability bits 0 and 1 (HELLO_POSES | HELLO_LIGHTS): send me Poses and Lights",
            msg: hello(
                Some("t0k"),
                lightwire_protocol::HELLO_POSES | lightwire_protocol::HELLO_LIGHTS,
            ),
        },
        Vector {
            name: "server_welcome_lights",
            description: "Welcome as server_welcome_poses with capability bit 2 (CAP_LIGHTS) and two lights: spot \"lamp\" (range 4, cone 0.25 to 0.5 rad, on, colour (1, 0.75, 0.5), 2.5 W/sr at (0.5, 0.9, 0.5) pointing down) and directional \"sun\" (angular radius 0.0046 rad, off, white, 1000 W/m2 along (0, -0.6, -0.8))",
            msg: Msg::Server(welcome(GLB_AND_POSES | CAP_LIGHTS, scene_with_lights())),
        },
        Vector {
            name: "client_set_light",
            description: "SetLight light 0 to seq 5: the lamp of server_welcome_lights dimmed to 1.25 W/sr, moved to (0.25, 0.9, 0.5) and turned to (0.6, -0.8, 0), client time 1.7e15 us",
            msg: Msg::Client(C::SetLight {
                light: 0,
                seq: 5,
                state: LightState {
                    intensity: 1.25,
                    position: [0.25, 0.9, 0.5],
                    direction: [0.6, -0.8, 0.0],
                    ..spot_state()
                },
                client_time_us: 1_700_000_000_000_000,
            }),
        },
        Vector {
            name: "server_lights",
            description: "Lights for version 2 (sent before server_delta): the lamp at seq 5 as client_set_light set it, the sun off as the scene file has it (seq 0)",
            msg: Msg::Server(S::Lights {
                version: 2,
                lights: vec![
                    LightStatus {
                        light: 0,
                        seq: 5,
                        state: LightState {
                            intensity: 1.25,
                            position: [0.25, 0.9, 0.5],
                            direction: [0.6, -0.8, 0.0],
                            ..spot_state()
                        },
                    },
                    LightStatus {
                        light: 1,
                        seq: 0,
                        state: scene_with_lights().lights[1].state,
                    },
                ],
            }),
        },
    ]
}

/// A recorded stream for receivers in other languages: what an [`Encoder`]
/// at a 1/64 budget publishes while a light field moves, as the frames a
/// client receives (a keyframe, then deltas of residual tiles compressed by
/// the real zstd), with the state a receiver must end with. Written to
/// `tests/vectors/sequences.json`; only decoding is normative (another zstd
/// may compress the same tiles to other bytes).
pub struct Sequence {
    pub name: &'static str,
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    pub tile_size: u16,
    pub epsilon: f32,
    /// Encoded `ServerMessage`s in order: one `Keyframe`, then `Delta`s.
    pub frames: Vec<Vec<u8>>,
    /// One `Delta` from the keyframe's version to the last: the merge of
    /// every delta.
    pub merged: Vec<u8>,
    /// The texels a receiver holds after the last frame (wire layout).
    pub final_texels: Vec<u8>,
    pub final_version: u64,
}

/// A light field of `w` x `h` texels, row by row: `light(x, y)` with `x`
/// and `y` the texel's place across the field, from 0 up to 1.
pub fn light_field(w: u32, h: u32, light: impl Fn(f32, f32) -> [f32; 3]) -> Vec<[f32; 3]> {
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
            light(x, y)
        })
        .collect()
}

/// A round spot's brightness at `(x, y)` (up to 1 at its centre, falling
/// off as fast as `sharpness` says): its centre `radius` from the middle
/// of the field at the angle `t`.
pub fn spot(x: f32, y: f32, t: f32, radius: f32, sharpness: f32) -> f32 {
    (-((x - 0.5 - radius * t.cos()).powi(2) + (y - 0.5 - radius * t.sin()).powi(2)) * sharpness)
        .exp()
}

/// The light field of the sequences: a spot travelling over a gradient.
pub fn sequence_light(w: u32, h: u32, frame: u32) -> Vec<[f32; 3]> {
    let t = frame as f32 * 0.15;
    light_field(w, h, |x, y| {
        let spot = spot(x, y, t, 0.3, 12.0);
        [
            0.1 + 0.4 * y + 3.0 * spot,
            0.05 + 0.3 * x + 2.0 * spot,
            0.02 + 0.5 * spot,
        ]
    })
}

pub fn sequences() -> Vec<Sequence> {
    use lightwire_protocol::lightmap::{Encoder, merge};
    [
        ("rgb9e5", PixelFormat::Rgb9e5),
        ("rgba16f", PixelFormat::Rgba16f),
    ]
    .into_iter()
    .map(|(name, format)| {
        let (width, height, tile_size, epsilon) = (21, 11, 4, 1.0 / 64.0);
        let mut e = Encoder::new(width, height, tile_size, format, epsilon);
        e.publish(&sequence_light(width, height, 0), vec![]);
        let mut frames = vec![encode_server(&ServerMessage::Keyframe(e.keyframe()))];
        let mut merged: Option<Delta> = None;
        for frame in 1..=24 {
            // The last frame repeats the one before: what waited is sent.
            let d = e.publish(
                &sequence_light(width, height, frame.min(23)),
                vec![ObjectSeq {
                    object: 0,
                    seq: u64::from(frame),
                }],
            );
            frames.push(encode_server(&ServerMessage::Delta(d.clone())));
            merged = Some(match merged {
                Some(m) => merge(&e.state().layout(), &m, &d).expect("consecutive"),
                None => d,
            });
        }
        Sequence {
            name,
            format,
            width,
            height,
            tile_size,
            epsilon,
            frames,
            merged: encode_server(&ServerMessage::Delta(merged.expect("deltas"))),
            final_texels: e.state().texels.clone(),
            final_version: e.state().version,
        }
    })
    .collect()
}
