//! Every message survives encode -> decode unchanged.

mod common;

use lightwire_protocol::*;
use proptest::prelude::*;

fn roundtrip_client(m: &ClientMessage) {
    let bytes = encode_client(m);
    assert_eq!(&decode_client(&bytes).unwrap(), m);
}

fn roundtrip_server(m: &ServerMessage) {
    let bytes = encode_server(m);
    assert_eq!(&decode_server(&bytes).unwrap(), m);
}

#[test]
fn every_vector_message_roundtrips() {
    for v in common::vectors::all() {
        match &v.msg {
            common::vectors::Msg::Client(m) => roundtrip_client(m),
            common::vectors::Msg::Server(m) => roundtrip_server(m),
        }
    }
}

#[test]
fn every_role_and_format_roundtrips() {
    for role in [Role::Viewer, Role::Driver, Role::Admin] {
        for format in [PixelFormat::Rgb9e5, PixelFormat::Rgba16f] {
            let mut scene = common::vectors::scene();
            scene.format = format;
            roundtrip_server(&ServerMessage::Welcome {
                protocol_version: PROTOCOL_VERSION,
                server: String::new(),
                role,
                capabilities: u32::MAX,
                scene,
            });
        }
    }
}

#[test]
fn every_error_code_value_roundtrips() {
    for v in (0..=300u16).chain([1000, 40000, u16::MAX]) {
        let code = ErrorCode::from_u16(v);
        assert_eq!(code.as_u16(), v);
        roundtrip_server(&ServerMessage::Error {
            code,
            message: code.to_string(),
        });
    }
    assert_eq!(ErrorCode::from_u16(5), ErrorCode::Forbidden);
    assert_eq!(ErrorCode::from_u16(11), ErrorCode::UnknownLight);
    assert_eq!(ErrorCode::from_u16(12), ErrorCode::InvalidLight);
    assert_eq!(ErrorCode::from_u16(13), ErrorCode::Other(13));
}

#[test]
fn extreme_integers_and_floats_roundtrip() {
    roundtrip_client(&ClientMessage::Transform {
        object: u32::MAX,
        seq: u64::MAX,
        pose: Pose {
            translation: [f32::MAX, f32::MIN_POSITIVE, -0.0],
            rotation: [f32::INFINITY, f32::NEG_INFINITY, 1e-45, 0.0],
            scale: f32::MIN,
        },
        client_time_us: 0,
    });
    // NaN != NaN, so compare bits.
    let bytes = encode_client(&ClientMessage::Transform {
        object: 0,
        seq: 0,
        pose: Pose {
            scale: f32::NAN,
            ..Pose::IDENTITY
        },
        client_time_us: 0,
    });
    let ClientMessage::Transform { pose, .. } = decode_client(&bytes).unwrap() else {
        panic!()
    };
    assert_eq!(pose.scale.to_bits(), f32::NAN.to_bits());
    assert!(
        pose.validate().is_err(),
        "codec passes NaN through; validate() rejects it"
    );
}

fn arb_pose() -> impl Strategy<Value = Pose> {
    (any::<[f32; 3]>(), any::<[f32; 4]>(), any::<f32>()).prop_map(
        |(translation, rotation, scale)| Pose {
            translation,
            rotation,
            scale,
        },
    )
}

fn arb_light_state() -> impl Strategy<Value = LightState> {
    (
        any::<bool>(),
        any::<[f32; 3]>(),
        any::<f32>(),
        any::<[f32; 3]>(),
        any::<[f32; 3]>(),
    )
        .prop_map(|(on, color, intensity, position, direction)| LightState {
            on,
            color,
            intensity,
            position,
            direction,
        })
}

fn arb_client() -> impl Strategy<Value = ClientMessage> {
    prop_oneof![
        (
            any::<u16>(),
            ".{0,20}",
            proptest::option::of(".{0,40}"),
            any::<u32>()
        )
            .prop_map(|(protocol_version, client, token, capabilities)| {
                ClientMessage::Hello {
                    protocol_version,
                    client,
                    token,
                    capabilities,
                }
            }),
        (any::<u32>(), any::<u64>(), arb_pose(), any::<u64>()).prop_map(
            |(object, seq, pose, client_time_us)| ClientMessage::Transform {
                object,
                seq,
                pose,
                client_time_us
            }
        ),
        proptest::option::of(any::<u64>())
            .prop_map(|have_version| ClientMessage::Resync { have_version }),
        any::<u64>().prop_map(|nonce| ClientMessage::Ping { nonce }),
        (any::<u32>(), any::<u64>(), arb_light_state(), any::<u64>()).prop_map(
            |(light, seq, state, client_time_us)| ClientMessage::SetLight {
                light,
                seq,
                state,
                client_time_us
            }
        ),
    ]
}

fn arb_tiles() -> impl Strategy<Value = Vec<Tile>> {
    proptest::collection::vec(
        (any::<u32>(), proptest::collection::vec(any::<u8>(), 0..40))
            .prop_map(|(index, data)| Tile { index, data }),
        0..8,
    )
}

fn arb_reflected() -> impl Strategy<Value = Vec<ObjectSeq>> {
    proptest::collection::vec(
        (any::<u32>(), any::<u64>()).prop_map(|(object, seq)| ObjectSeq { object, seq }),
        0..4,
    )
}

fn arb_server() -> impl Strategy<Value = ServerMessage> {
    prop_oneof![
        (any::<u64>(), arb_reflected(), arb_tiles()).prop_map(|(version, reflected, tiles)| {
            ServerMessage::Keyframe(Keyframe {
                version,
                reflected,
                tiles,
            })
        }),
        (
            any::<u64>(),
            any::<u64>(),
            arb_reflected(),
            proptest::collection::vec(any::<u8>(), 0..64)
        )
            .prop_map(|(base_version, version, reflected, residual)| {
                ServerMessage::Delta(Delta {
                    base_version,
                    version,
                    reflected,
                    residual,
                })
            }),
        (
            any::<u64>(),
            any::<f32>(),
            any::<f32>(),
            any::<u32>(),
            any::<u64>()
        )
            .prop_map(
                |(version, unshot_fraction, tick_ms, clients, server_time_us)| ServerMessage::Stats(
                    Stats {
                        version,
                        unshot_fraction,
                        tick_ms,
                        solve_ms: tick_ms * 0.5,
                        redistribution_ms: 0.25,
                        clients,
                        server_time_us
                    }
                )
            ),
        (any::<u16>(), ".{0,30}").prop_map(|(c, message)| ServerMessage::Error {
            code: ErrorCode::from_u16(c),
            message
        }),
        any::<u64>().prop_map(|nonce| ServerMessage::Pong { nonce }),
        (
            any::<u64>(),
            proptest::collection::vec(
                (any::<u32>(), any::<u64>(), arb_light_state())
                    .prop_map(|(light, seq, state)| LightStatus { light, seq, state }),
                0..4
            )
        )
            .prop_map(|(version, lights)| ServerMessage::Lights { version, lights }),
    ]
}

proptest! {
    #[test]
    fn arbitrary_client_messages_roundtrip(m in arb_client()) {
        // Compare encodings: NaN payloads make `==` on values unusable.
        let bytes = encode_client(&m);
        prop_assert_eq!(encode_client(&decode_client(&bytes).unwrap()), bytes);
    }

    #[test]
    fn arbitrary_server_messages_roundtrip(m in arb_server()) {
        let bytes = encode_server(&m);
        prop_assert_eq!(encode_server(&decode_server(&bytes).unwrap()), bytes);
    }
}

/// PROTOCOL.md §4: extreme but finite poses are refused, the bounds
/// themselves accepted.
#[test]
fn poses_beyond_the_stated_bounds_are_invalid() {
    let at = |translation: [f32; 3], scale: f32| Pose {
        translation,
        scale,
        ..Pose::IDENTITY
    };
    let max = Pose::MAX_TRANSLATION;
    let (lo, hi) = Pose::SCALE_RANGE;
    for ok in [
        at([max, -max, 0.0], 1.0),
        at([0.0; 3], lo),
        at([0.0; 3], hi),
    ] {
        assert_eq!(ok.validate(), Ok(()), "{ok:?}");
    }
    for bad in [
        at([1e30, 0.0, 0.0], 1.0),
        at([0.0, 0.0, -1.0001e5], 1.0),
        at([0.0; 3], 1e-30),
        at([0.0; 3], 0.999e-3),
        at([0.0; 3], 1.001e3),
        at([0.0; 3], f32::MAX),
    ] {
        assert!(bad.validate().is_err(), "{bad:?} must be refused");
    }
}
