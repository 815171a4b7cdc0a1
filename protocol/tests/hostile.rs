//! Whatever arrives, decoding and applying return errors, never panic, and
//! never change state on error.

mod common;

use common::vectors;
use lightwire_protocol::lightmap::{ApplyError, Encoder, Lightmap};
use lightwire_protocol::*;
use proptest::prelude::*;

#[test]
fn empty_frame_is_malformed() {
    let e = decode_client(&[]).unwrap_err();
    assert!(
        matches!(e, DecodeError::Malformed(ref s) if s.contains("at byte 0 of 0")),
        "{e}"
    );
}

#[test]
fn every_truncation_of_every_vector_is_an_error() {
    for v in vectors::all() {
        let bytes = v.msg.encode();
        for cut in 0..bytes.len() {
            let r = v.msg.decode_like(&bytes[..cut]);
            assert!(
                matches!(r, Err(DecodeError::Malformed(_))),
                "{} cut at {cut}: {r:?}",
                v.name
            );
        }
    }
}

#[test]
fn trailing_bytes_are_an_error_that_says_where() {
    let mut bytes = encode_client(&ClientMessage::Ping { nonce: 1 });
    bytes.extend_from_slice(&[0, 0]);
    let e = decode_client(&bytes).unwrap_err();
    assert_eq!(
        e,
        DecodeError::TrailingBytes {
            message: "ClientMessage",
            consumed: 2,
            len: 4
        }
    );
    assert_eq!(
        e.to_string(),
        "ClientMessage ends at byte 2 but the frame has 4 bytes (2 trailing)"
    );
    assert_eq!(e.code(), ErrorCode::BadFrame);
}

#[test]
fn oversized_frames_are_refused_before_parsing() {
    let bytes = vec![0u8; MAX_FRAME_BYTES + 1];
    let e = decode_server(&bytes).unwrap_err();
    assert_eq!(
        e,
        DecodeError::TooLarge {
            len: MAX_FRAME_BYTES + 1,
            max: MAX_FRAME_BYTES
        }
    );
    assert_eq!(e.code(), ErrorCode::TooLarge);
}

#[test]
fn unknown_discriminants_are_named() {
    let e = decode_client(&[9]).unwrap_err();
    assert!(e.to_string().contains("unknown discriminant 9"), "{e}");
    // Welcome with role 7
    let mut bytes = vectors::all()
        .into_iter()
        .find(|v| v.name == "server_welcome")
        .unwrap()
        .msg
        .encode();
    // variant 0, version 1, "lightwire/0.1" (1 + 13 bytes): role is byte 16
    assert_eq!(bytes[16], 1);
    bytes[16] = 7;
    let e = decode_server(&bytes).unwrap_err();
    assert!(e.to_string().contains("at byte 17"), "{e}");
}

#[test]
fn huge_length_claims_fail_without_allocating_them() {
    // Hello whose client string claims u64::MAX bytes.
    let e =
        decode_client(&[0, 1, 0xfd, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff]).unwrap_err();
    assert!(matches!(e, DecodeError::Malformed(_)), "{e}");
    // Keyframe claiming 2^32 tiles (would be 128 GiB of Tile slots).
    let e = decode_server(&[1, 0, 0, 0xfd, 0, 0, 0, 0, 1, 0, 0, 0]).unwrap_err();
    assert!(e.to_string().contains("decode budget"), "{e}");
    // Delta whose residual claims 8 MiB of data in an 8-byte frame.
    let e = decode_server(&[2, 0, 1, 0, 0xfc, 0, 0, 0x80, 0]).unwrap_err();
    assert!(matches!(e, DecodeError::Malformed(_)), "{e}");
}

#[test]
fn over_long_varints_are_accepted_but_never_written() {
    // Ping nonce 5 spelled with a 2-byte varint: bincode 2.0.1 accepts it.
    let m = decode_client(&[3, 0xfb, 5, 0]).unwrap();
    assert_eq!(m, ClientMessage::Ping { nonce: 5 });
    assert_eq!(encode_client(&m), vec![3, 5]);
}

#[test]
fn a_large_legitimate_keyframe_decodes() {
    // 300k tiny tiles: bincode claims 32 bytes per Tile slot, far more than
    // the wire size; the decode budget must still admit it.
    let tiles = (0..300_000u32)
        .map(|index| Tile {
            index,
            data: vec![0; 9],
        })
        .collect();
    let msg = ServerMessage::Keyframe(Keyframe {
        version: 1,
        reflected: vec![],
        tiles,
    });
    let bytes = encode_server(&msg);
    assert!(bytes.len() <= MAX_FRAME_BYTES);
    assert_eq!(decode_server(&bytes).unwrap(), msg);
}

fn published() -> (Encoder, Lightmap, Delta) {
    let mut e = Encoder::new(16, 16, 8, PixelFormat::Rgb9e5, 0.0);
    let mut client = Lightmap::new(16, 16, 8, PixelFormat::Rgb9e5);
    client
        .apply_delta(&e.publish(&vec![[0.5, 0.25, 1.0]; 256], vec![]))
        .unwrap();
    let next = e.publish(&vec![[2.0, 0.25, 1.0]; 256], vec![]);
    (e, client, next)
}

fn rejects(client: &mut Lightmap, d: &Delta, expected: ApplyError) {
    let before = client.clone();
    assert_eq!(client.apply_delta(d), Err(expected.clone()));
    assert_eq!(*client, before, "state changed on {expected}");
}

/// A delta whose residual payload is `raw`, compressed.
fn with_payload(good: &Delta, raw: &[u8]) -> Delta {
    Delta {
        residual: zstd::bulk::compress(raw, 3).unwrap(),
        ..good.clone()
    }
}

/// The delta is refused with a residual error that mentions `why`, and
/// changes nothing.
fn refuses(client: &mut Lightmap, d: &Delta, why: &str) {
    let before = client.clone();
    match client.apply_delta(d) {
        Err(ApplyError::Residual(reason)) => {
            assert!(
                reason.contains(why),
                "refused for {reason:?}, expected {why:?}"
            )
        }
        other => panic!("expected a residual error ({why}), got {other:?}"),
    }
    assert_eq!(*client, before, "state changed on a refused delta ({why})");
}

#[test]
fn bad_residual_payloads_are_rejected_atomically() {
    let (e, mut client, good) = published();
    assert_eq!(
        e.state().layout().delta_tiles(&good).unwrap(),
        vec![0, 1, 2, 3]
    );
    // 16 x 16 texels, tile size 8: 4 tiles of 256 bytes, a 1-byte bitmap.
    let residuals = vec![0u8; 4 * 256];

    let mut raw = vec![0b0001_0111];
    raw.extend_from_slice(&residuals);
    refuses(&mut client, &with_payload(&good, &raw), "sets tile 4");

    let mut raw = vec![0b0000_1111];
    raw.extend_from_slice(&residuals[..4 * 256 - 1]);
    refuses(
        &mut client,
        &with_payload(&good, &raw),
        "ends inside tile 3",
    );

    let mut raw = vec![0b0000_0001];
    raw.extend_from_slice(&[0; 257]);
    refuses(&mut client, &with_payload(&good, &raw), "1 bytes left over");

    refuses(
        &mut client,
        &with_payload(&good, &[]),
        "cannot hold the 1-byte tile bitmap",
    );

    // A zip bomb: 64 MiB of zeros in a few KiB, refused from its header.
    let bomb = with_payload(&good, &vec![0u8; 64 << 20]);
    assert!(bomb.residual.len() < 64 << 10);
    refuses(&mut client, &bomb, "at most 1025");

    let garbage = Delta {
        residual: vec![1, 2, 3],
        ..good.clone()
    };
    refuses(&mut client, &garbage, "not a zstd frame");

    let mut d = good.clone();
    d.version = d.base_version;
    rejects(
        &mut client,
        &d,
        ApplyError::NotIncreasing {
            base: 1,
            version: 1,
        },
    );

    client.apply_delta(&good).unwrap();
}

#[test]
fn frames_without_a_declared_size_are_refused() {
    let (_, mut client, good) = published();
    // zstd frame without content size: stream-compress 1 MiB.
    let mut enc = zstd::stream::Encoder::new(Vec::new(), 3).unwrap();
    enc.include_contentsize(false).unwrap();
    std::io::Write::write_all(&mut enc, &vec![7u8; 1 << 20]).unwrap();
    let data = enc.finish().unwrap();
    assert!(matches!(
        zstd::zstd_safe::get_frame_content_size(&data),
        Ok(None)
    ));
    let d = Delta {
        residual: data,
        ..good.clone()
    };
    refuses(&mut client, &d, "does not declare its content size");
}

/// A keyframe tile is one zstd frame that declares its size, with nothing
/// after it (PROTOCOL.md §5): a frame without the size, the tile's frame
/// followed by a second one, or by a stray byte, is refused and the
/// lightmap left as it was.
#[test]
fn a_keyframe_tile_is_one_frame_that_declares_its_size() {
    let (e, mut client, _) = published();
    let good = e.keyframe();
    let len = zstd::bulk::decompress(&good.tiles[0].data, 1 << 20)
        .unwrap()
        .len();
    let mut enc = zstd::stream::Encoder::new(Vec::new(), 3).unwrap();
    enc.include_contentsize(false).unwrap();
    std::io::Write::write_all(&mut enc, &vec![0u8; len]).unwrap();
    let unsized_frame = enc.finish().unwrap();
    let second = zstd::bulk::compress(&[0u8; 4], 3).unwrap();
    let two = [good.tiles[0].data.clone(), second].concat();
    let trailing = [good.tiles[0].data.clone(), vec![0]].concat();
    for (what, data, says) in [
        (
            "no size",
            unsized_frame,
            "does not declare its content size",
        ),
        ("two frames", two, "after the zstd frame"),
        ("a byte after", trailing, "after the zstd frame"),
    ] {
        let mut k = good.clone();
        k.tiles[0].data = data;
        let before = client.clone();
        let refused = client.apply_keyframe(&k);
        assert!(
            matches!(&refused, Err(ApplyError::Decompress { reason, .. }) if reason.contains(says)),
            "{what}: {refused:?}"
        );
        assert_eq!(client, before, "{what}: nothing changed");
    }
    client.apply_keyframe(&good).unwrap();
}

#[test]
fn incomplete_keyframes_are_rejected() {
    let (e, mut client, _) = published();
    let mut k = e.keyframe();
    k.tiles.pop();
    let before = client.clone();
    assert_eq!(
        client.apply_keyframe(&k),
        Err(ApplyError::MissingTiles {
            expected: 4,
            got: 3
        })
    );
    assert_eq!(client, before);
}

#[test]
fn hostile_scene_layouts_are_refused() {
    let mut s = vectors::scene();
    s.tile_size = 0;
    assert!(matches!(
        Lightmap::for_scene(&s),
        Err(ApplyError::Layout(_))
    ));
    let mut s = vectors::scene();
    s.atlas_width = u32::MAX;
    s.atlas_height = u32::MAX;
    assert!(matches!(
        Lightmap::for_scene(&s),
        Err(ApplyError::Layout(_))
    ));
    assert!(Lightmap::for_scene(&vectors::scene()).is_ok());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
        let _ = decode_client(&bytes);
        let _ = decode_server(&bytes);
    }

    #[test]
    fn mutated_vectors_never_panic(i in 0usize..13, pos in any::<prop::sample::Index>(), byte in any::<u8>(), cut in any::<prop::sample::Index>()) {
        let all = vectors::all();
        let v = &all[i % all.len()];
        let mut bytes = v.msg.encode();
        let p = pos.index(bytes.len());
        bytes[p] = byte;
        let c = cut.index(bytes.len() + 1);
        if let Ok(m) = v.msg.decode_like(&bytes[..c]) {
            // Whatever decodes re-encodes to a frame that decodes to the
            // same encoding (not necessarily the same bytes: bincode accepts
            // over-long varints, and encoders always write the shortest).
            let again = m.encode();
            prop_assert_eq!(m.decode_like(&again).unwrap().encode(), again);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn random_payloads_never_panic_and_never_partially_apply(
        raw in proptest::collection::vec(any::<u8>(), 0..1100),
        compressed in any::<bool>(),
    ) {
        let (_, mut client, _) = published();
        let before = client.clone();
        let d = Delta {
            base_version: 1,
            version: 2,
            reflected: vec![],
            residual: if compressed { zstd::bulk::compress(&raw, 1).unwrap() } else { raw },
        };
        if client.apply_delta(&d).is_err() {
            prop_assert_eq!(client, before);
        }
    }
}

/// PROTOCOL.md §2: a varint may use a longer form than the shortest (bincode
/// 2.0.1 reads `FB 05 00` as 5), but never a form wider than its field's
/// type, even when the value would fit.
#[test]
fn a_varint_wider_than_its_field_is_refused_even_when_the_value_fits() {
    // Ping { nonce: u64 } is variant 3; its nonce accepts every form.
    assert_eq!(
        decode_client(&[0x03, 0xfd, 5, 0, 0, 0, 0, 0, 0, 0]).expect("u64 in FD form"),
        ClientMessage::Ping { nonce: 5 }
    );
    // Transform { object: u32, .. } is variant 1: object 5 in the u16 and
    // u32 forms decodes, in the u64 form it is malformed.
    let pose = [0u8; 32];
    let transform = |object: &[u8]| {
        let mut frame = vec![0x01];
        frame.extend_from_slice(object);
        frame.push(7); // seq
        frame.extend_from_slice(&pose);
        frame.push(0); // client_time_us
        frame
    };
    for object in [&[5u8][..], &[0xfb, 5, 0], &[0xfc, 5, 0, 0, 0]] {
        match decode_client(&transform(object)) {
            Ok(ClientMessage::Transform {
                object: 5, seq: 7, ..
            }) => {}
            other => panic!("{object:02x?}: {other:?}"),
        }
    }
    let err = decode_client(&transform(&[0xfd, 5, 0, 0, 0, 0, 0, 0, 0]))
        .expect_err("a u64-form varint in a u32 field");
    assert_eq!(err.code(), ErrorCode::BadFrame, "{err}");
}
