//! Golden vectors: the committed bytes in `tests/vectors/` are the protocol.
//! Every vector must decode to the value written by hand in
//! `common/vectors.rs`, and that value must encode to the identical bytes.
//! A codec change that alters any byte fails here; regenerate with
//! `cargo run -p lightwire-protocol --example gen_vectors` only together
//! with a PROTOCOL_VERSION bump and a PROTOCOL.md update.

mod common;

use std::path::PathBuf;

use common::vectors::{self, ATLAS, DELTA_RGB, KEY_RGB, hex, to_hex};
use lightwire_protocol::lightmap::Lightmap;
use lightwire_protocol::*;

fn vector_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/vectors")
}

fn read_vector(name: &str) -> Vec<u8> {
    let path = vector_dir().join(format!("{name}.bin"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
}

#[test]
fn every_vector_decodes_to_its_value_and_reencodes_to_the_same_bytes() {
    for v in vectors::all() {
        let bytes = read_vector(v.name);
        let decoded = v
            .msg
            .decode_like(&bytes)
            .unwrap_or_else(|e| panic!("{}: {e}", v.name));
        assert_eq!(decoded, v.msg, "{}: decoded value differs", v.name);
        assert_eq!(
            to_hex(&decoded.encode()),
            to_hex(&bytes),
            "{}: re-encoding the decoded value changes the bytes",
            v.name
        );
        assert_eq!(
            to_hex(&v.msg.encode()),
            to_hex(&bytes),
            "{}: encoding the expected value differs from the committed vector",
            v.name
        );
    }
}

#[test]
fn manifest_lists_every_vector_with_its_bytes() {
    let text = std::fs::read_to_string(vector_dir().join("manifest.json")).unwrap();
    let manifest: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(manifest["protocol_version"], u64::from(PROTOCOL_VERSION));
    let entries = manifest["vectors"].as_array().unwrap();
    let all = vectors::all();
    assert_eq!(
        entries.len(),
        all.len(),
        "manifest and vectors::all() disagree"
    );
    for (entry, v) in entries.iter().zip(&all) {
        assert_eq!(entry["name"], v.name);
        assert_eq!(entry["decoder"], v.msg.direction());
        assert_eq!(entry["message"], v.msg.to_json(), "{}", v.name);
        assert_eq!(
            entry["hex"].as_str().unwrap(),
            to_hex(&read_vector(v.name)),
            "{}: manifest hex differs from the .bin file",
            v.name
        );
    }
}

/// A few vectors spelled out byte by byte, as PROTOCOL.md explains them.
#[test]
fn layout_by_hand() {
    // Ping: variant 3, nonce 0xDEADBEEF as varint tag 0xFC + u32 LE.
    assert_eq!(read_vector("client_ping"), hex("03fcefbeadde"));
    // Resync: variant 2, Option tag 1, 42.
    assert_eq!(read_vector("client_resync_some"), hex("02012a"));
    // Hello: variant 0, version 4, "lw/1", Some("t0k"), capabilities 0.
    assert_eq!(
        read_vector("client_hello"),
        hex(concat!(
            "00", "04", "04", "6c772f31", "01", "03", "74306b", "00"
        ))
    );
    // A surface's uvs: vector length 4, then (u, v) as two f32 LE each.
    let uvs = concat!(
        "04", "0000803e", "0000403f", "0000403f", "0000403f", "0000003f", "0000803e", "0000003f",
        "0000803e"
    );
    // Version 4's SceneInfo ends with its lights: none, a zero length.
    assert!(to_hex(&read_vector("server_welcome_uvs")).ends_with(&format!("{uvs}00")));
    // SetLight: variant 4, light 0, seq 5, on, colour (1, 0.75, 0.5),
    // intensity 1.25, position (0.25, 0.9, 0.5), direction (0.6, -0.8, 0),
    // client time as a 9-byte varint (tag 0xFD + u64 LE).
    assert_eq!(
        read_vector("client_set_light"),
        hex(concat!(
            "04",
            "00",
            "05",
            "01",
            "0000803f",
            "0000403f",
            "0000003f",
            "0000a03f",
            "0000803e",
            "6666663f",
            "0000003f",
            "9a99193f",
            "cdcc4cbf",
            "00000000",
            "fd00401e18240a0600"
        ))
    );
    // Error: variant 4, code 1000 as varint 0xFB + u16 LE, "future".
    assert_eq!(
        read_vector("server_error_unknown_code"),
        hex(concat!("04", "fbe803", "06", "667574757265"))
    );
}

#[test]
fn keyframe_and_delta_vectors_reconstruct_known_texels() {
    let (w, h, ts) = ATLAS;
    let mut client = Lightmap::new(w, h, ts, PixelFormat::Rgb9e5);
    let ServerMessage::Keyframe(k) = decode_server(&read_vector("server_keyframe")).unwrap() else {
        panic!("server_keyframe is not a Keyframe")
    };
    client.apply_keyframe(&k).unwrap();
    assert_eq!(client.version, 1);
    assert_eq!(client.to_rgb(), KEY_RGB.to_vec());

    let ServerMessage::Delta(d) = decode_server(&read_vector("server_delta")).unwrap() else {
        panic!("server_delta is not a Delta")
    };
    client.apply_delta(&d).unwrap();
    assert_eq!(client.version, 2);
    assert_eq!(client.to_rgb(), DELTA_RGB.to_vec());
}

/// The recorded streams of `sequences.json` (residual deltas compressed by
/// the real zstd) reconstruct their final texels, frame by frame and
/// through the merged delta; and the encoder today still makes the same
/// decisions (same final state), whatever bytes its zstd writes.
#[test]
fn recorded_sequences_reconstruct_their_final_state() {
    let path = vector_dir().join("sequences.json");
    let text = std::fs::read_to_string(&path).expect("sequences.json");
    let json: serde_json::Value = serde_json::from_str(&text).expect("json");
    let recorded = json["sequences"].as_array().expect("sequences");
    let expected = vectors::sequences();
    assert_eq!(recorded.len(), expected.len());
    for (r, e) in recorded.iter().zip(&expected) {
        assert_eq!(r["name"], e.name);
        let mut client = Lightmap::new(e.width, e.height, e.tile_size, e.format);
        let frames: Vec<Vec<u8>> = r["frames"]
            .as_array()
            .expect("frames")
            .iter()
            .map(|f| hex(f.as_str().expect("hex")))
            .collect();
        let mut after_keyframe = None;
        for (i, f) in frames.iter().enumerate() {
            match decode_server(f).unwrap_or_else(|err| panic!("{} frame {i}: {err}", e.name)) {
                ServerMessage::Keyframe(k) => {
                    client.apply_keyframe(&k).expect("keyframe applies");
                    after_keyframe = Some(client.clone());
                }
                ServerMessage::Delta(d) => client.apply_delta(&d).expect("delta applies"),
                other => panic!("{} frame {i}: unexpected {other:?}", e.name),
            }
        }
        let final_texels = hex(r["final_texels"].as_str().expect("hex"));
        assert_eq!(client.texels, final_texels, "{}: frame by frame", e.name);
        assert_eq!(
            client.version,
            r["final_version"].as_u64().expect("version")
        );
        assert_eq!(
            final_texels, e.final_texels,
            "{}: the encoder decides as it did",
            e.name
        );
        let ServerMessage::Delta(m) =
            decode_server(&hex(r["merged"].as_str().expect("hex"))).expect("merged decodes")
        else {
            panic!("merged is not a Delta")
        };
        let mut merged = after_keyframe.expect("a keyframe first");
        merged.apply_delta(&m).expect("the merge applies");
        assert_eq!(merged.texels, final_texels, "{}: through the merge", e.name);
    }
}

/// A version 4 server answers a version 3 client with version 3's
/// `Welcome` (`SceneInfo` without `lights`): `tests/vectors/v3/` holds the
/// bytes version 3 committed, which it must reproduce, lights or none.
#[test]
fn a_version_3_client_gets_version_3_s_welcome() {
    use vectors::welcome;
    let glb_and_poses = CAP_SCENE_GLB | CAP_POSES;
    for (name, capabilities, scene) in [
        ("server_welcome", 0, vectors::scene()),
        ("server_welcome_scene_glb", CAP_SCENE_GLB, vectors::scene()),
        ("server_welcome_poses", glb_and_poses, vectors::scene()),
        (
            "server_welcome_uvs",
            glb_and_poses,
            vectors::scene_with_uvs(),
        ),
    ] {
        let path = vector_dir().join("v3").join(format!("{name}.bin"));
        let committed = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let bytes =
            encode_welcome_for(3, &welcome(capabilities, scene.clone())).expect("a Welcome");
        assert_eq!(to_hex(&bytes), to_hex(&committed), "{name}");
        // Version 4's bytes are the same plus `lights` (an empty vector,
        // one byte) and the version.
        let v4 =
            encode_welcome_for(PROTOCOL_VERSION, &welcome(capabilities, scene)).expect("a Welcome");
        assert_eq!(v4, read_vector(name));
        assert_eq!(v4.len(), bytes.len() + 1);
        assert_eq!((bytes[1], v4[1]), (3, 4), "{name}: the version byte");
    }
    // A scene with lights is described to a version 3 client without them.
    let lit = welcome(glb_and_poses, vectors::scene_with_lights());
    assert_eq!(
        encode_welcome_for(3, &lit),
        encode_welcome_for(3, &welcome(glb_and_poses, vectors::scene()))
    );
}

/// A version 4 server answers a version 2 client with version 2's
/// `Welcome` (`SurfaceInfo` without `uvs`, `SceneInfo` without `lights`):
/// `tests/vectors/v2/` holds the bytes version 2 committed, which it must
/// reproduce, and it refuses when a surface needs `uvs`.
#[test]
fn a_version_2_client_gets_version_2_s_welcome() {
    use vectors::welcome;
    for (name, capabilities) in [
        ("server_welcome", 0),
        ("server_welcome_poses", CAP_SCENE_GLB | CAP_POSES),
    ] {
        let path = vector_dir().join("v2").join(format!("{name}.bin"));
        let committed = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let bytes = encode_welcome_for(2, &welcome(capabilities, vectors::scene()))
            .unwrap_or_else(|| panic!("{name}: no surface needs uvs"));
        assert_eq!(to_hex(&bytes), to_hex(&committed), "{name}");
        // The version 4 bytes are the same plus `uvs` and `lights` (empty
        // vectors, one byte each) and the version.
        let v4 = encode_welcome_for(PROTOCOL_VERSION, &welcome(capabilities, vectors::scene()))
            .expect("a Welcome");
        assert_eq!(v4, read_vector(name));
        assert_eq!(v4.len(), bytes.len() + 2);
    }
    assert!(
        encode_welcome_for(2, &welcome(0, vectors::scene_with_uvs())).is_none(),
        "a surface with uvs cannot be described to a version 2 client"
    );
    assert!(encode_welcome_for(1, &welcome(0, vectors::scene())).is_none());
    assert!(encode_welcome_for(2, &ServerMessage::Pong { nonce: 1 }).is_none());
}
