//! The lightmap codec's contract: a client that applies what the encoder
//! publishes holds exactly the encoder's state, bit for bit, at every
//! version; bad input changes nothing.

use lightwire_protocol::lightmap::{ApplyError, Encoder, Lightmap, merge};
use lightwire_protocol::*;
use proptest::prelude::*;

fn client_for(e: &Encoder) -> Lightmap {
    let s = e.state();
    Lightmap::new(s.width, s.height, s.tile_size, s.format)
}

fn seqs(object: u32, seq: u64) -> Vec<ObjectSeq> {
    vec![ObjectSeq { object, seq }]
}

fn gradient(w: u32, h: u32, t: f32) -> Vec<[f32; 3]> {
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            [x * 0.37 + t, y * 1.3 + 0.01 * t, (x * y).sin().abs() * 5.0]
        })
        .collect()
}

#[test]
fn tiles_are_clipped_at_the_border() {
    let m = Lightmap::new(10, 9, 8, PixelFormat::Rgb9e5);
    assert_eq!((m.tiles_x(), m.tiles_y(), m.tile_count()), (2, 2, 4));
    let sizes: Vec<_> = (0..4)
        .map(|i| m.tile_rect(i).map(|r| (r.x, r.y, r.width, r.height)))
        .collect();
    assert_eq!(
        sizes,
        vec![
            Some((0, 0, 8, 8)),
            Some((8, 0, 2, 8)),
            Some((0, 8, 8, 1)),
            Some((8, 8, 2, 1))
        ]
    );
    assert_eq!(m.tile_rect(4), None);
}

#[test]
fn first_publish_from_zero_sends_only_nonzero_tiles_and_keyframe_sends_all() {
    let mut e = Encoder::new(16, 8, 8, PixelFormat::Rgb9e5, 0.0);
    let mut rgb = vec![[0.0; 3]; 16 * 8];
    rgb[15] = [1.0, 1.0, 1.0]; // in tile 1 only
    let d = e.publish(&rgb, seqs(0, 1));
    assert_eq!((d.base_version, d.version), (0, 1));
    assert_eq!(d.tiles.iter().map(|t| t.index).collect::<Vec<_>>(), vec![1]);
    let k = e.keyframe();
    assert_eq!(k.tiles.len(), 2);
    assert_eq!(k.version, 1);
    assert_eq!(k.reflected, seqs(0, 1));

    let mut late = client_for(&e);
    late.apply_keyframe(&k).unwrap();
    assert_eq!(&late, e.state());
}

#[test]
fn a_change_below_epsilon_sends_no_tile_and_the_state_keeps_the_old_value() {
    let mut e = Encoder::new(8, 8, 8, PixelFormat::Rgb9e5, 0.05);
    let mut rgb = vec![[1.0, 2.0, 4.0]; 64];
    let mut client = client_for(&e);
    client.apply_delta(&e.publish(&rgb, vec![])).unwrap();
    let before = e.state().clone();

    rgb[10] = [1.03, 2.0, 4.0]; // 3 % < 5 %
    let d = e.publish(&rgb, seqs(3, 9));
    assert!(
        d.tiles.is_empty(),
        "a 3 % change must not be sent at epsilon 5 %"
    );
    assert_eq!(d.reflected, seqs(3, 9));
    assert_eq!(
        e.state().texels,
        before.texels,
        "the encoder keeps the old quantized texels"
    );
    client.apply_delta(&d).unwrap();
    assert_eq!(&client, e.state());

    rgb[10] = [1.08, 2.0, 4.0]; // 8 % > 5 %
    let d = e.publish(&rgb, vec![]);
    assert_eq!(d.tiles.len(), 1);
    client.apply_delta(&d).unwrap();
    assert_eq!(&client, e.state());
    assert!((client.texel(2, 1)[0] - 1.08).abs() < 1.08 / 500.0);
}

#[test]
fn near_black_changes_are_judged_against_the_floor() {
    let mut e = Encoder::new(4, 4, 4, PixelFormat::Rgb9e5, 0.1);
    let floor = e.floor();
    e.publish(&[[0.0; 3]; 16], vec![]);
    // 0 -> floor * 0.05 is an infinite relative change but below epsilon * floor.
    let d = e.publish(&[[floor * 0.05; 3]; 16], vec![]);
    assert!(d.tiles.is_empty());
    let d = e.publish(&[[floor * 0.2; 3]; 16], vec![]);
    assert_eq!(d.tiles.len(), 1);
}

#[test]
fn wrong_base_is_rejected_and_leaves_the_state_untouched() {
    let mut e = Encoder::new(12, 12, 4, PixelFormat::Rgb9e5, 0.0);
    let mut client = client_for(&e);
    let d1 = e.publish(&gradient(12, 12, 0.0), vec![]);
    let d2 = e.publish(&gradient(12, 12, 1.0), vec![]);
    let pristine = client.clone();
    assert_eq!(
        client.apply_delta(&d2),
        Err(ApplyError::WrongBase { have: 0, base: 1 })
    );
    assert_eq!(client, pristine);
    client.apply_delta(&d1).unwrap();
    let after_d1 = client.clone();
    assert_eq!(
        client.apply_delta(&d1),
        Err(ApplyError::WrongBase { have: 1, base: 0 })
    );
    assert_eq!(client, after_d1);
    client.apply_delta(&d2).unwrap();
    assert_eq!(&client, e.state());
}

#[test]
fn merged_deltas_equal_applying_them_in_turn() {
    let mut e = Encoder::new(20, 13, 8, PixelFormat::Rgb9e5, 0.01);
    let mut base_client = client_for(&e);
    base_client
        .apply_delta(&e.publish(&gradient(20, 13, 0.0), seqs(0, 1)))
        .unwrap();
    let mut rgb = gradient(20, 13, 0.0);
    rgb[0] = [9.0; 3];
    let a = e.publish(&rgb, seqs(0, 2));
    rgb[19] = [7.0; 3];
    rgb[0] = [3.0; 3];
    let b = e.publish(
        &rgb,
        vec![
            ObjectSeq { object: 0, seq: 3 },
            ObjectSeq { object: 1, seq: 1 },
        ],
    );

    let mut one_by_one = base_client.clone();
    one_by_one.apply_delta(&a).unwrap();
    one_by_one.apply_delta(&b).unwrap();

    let m = merge(&a, &b).unwrap();
    assert_eq!((m.base_version, m.version), (a.base_version, b.version));
    assert_eq!(
        m.reflected,
        vec![
            ObjectSeq { object: 0, seq: 3 },
            ObjectSeq { object: 1, seq: 1 }
        ]
    );
    let mut merged = base_client.clone();
    merged.apply_delta(&m).unwrap();
    assert_eq!(merged, one_by_one);
    assert_eq!(&merged, e.state());

    assert_eq!(
        merge(&b, &a),
        Err(ApplyError::WrongBase {
            have: b.version,
            base: a.base_version
        })
    );
}

#[test]
fn rgba16f_streams_bit_exactly_too() {
    let mut e = Encoder::new(9, 7, 4, PixelFormat::Rgba16f, 0.0);
    let mut client = client_for(&e);
    for t in 0..4 {
        client
            .apply_delta(&e.publish(&gradient(9, 7, t as f32), vec![]))
            .unwrap();
        assert_eq!(&client, e.state());
    }
    assert_eq!(client.texels.len(), 9 * 7 * 8);
    let [r, g, _] = client.texel(1, 0);
    assert!((r - (0.37 + 3.0)).abs() < 0.01 && (g - 0.03).abs() < 1e-4);
}

#[test]
fn encoder_and_lightmap_can_move_between_threads() {
    fn is_send<T: Send>() {}
    fn is_send_sync<T: Send + Sync>() {}
    is_send::<Encoder>();
    is_send_sync::<Lightmap>();
}

/// A random lightmap sequence: random size, tile size, format, epsilon;
/// each frame perturbs some texels of the previous one.
/// One frame's edits: (texel index, new value).
type Frame = Vec<(usize, [f32; 3])>;

fn arb_sequence() -> impl Strategy<Value = (u32, u32, u16, PixelFormat, f32, Vec<Frame>)> {
    (
        1u32..24,
        1u32..24,
        1u16..10,
        prop_oneof![Just(PixelFormat::Rgb9e5), Just(PixelFormat::Rgba16f)],
        prop_oneof![Just(0.0f32), Just(0.01), Just(0.2)],
    )
        .prop_flat_map(|(w, h, ts, f, eps)| {
            let n = (w * h) as usize;
            let edit = (
                0..n,
                proptest::array::uniform3(prop_oneof![0.0f32..4.0, 0.0f32..0.01, Just(0.0)]),
            );
            let frame = proptest::collection::vec(edit, 0..12);
            (
                Just(w),
                Just(h),
                Just(ts),
                Just(f),
                Just(eps),
                proptest::collection::vec(frame, 1..8),
            )
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    #[test]
    fn a_client_applying_every_delta_is_bit_identical_to_the_encoder(
        (w, h, ts, format, eps, frames) in arb_sequence(), join_at in 0usize..8
    ) {
        let mut e = Encoder::new(w, h, ts, format, eps);
        let mut client = client_for(&e);
        let mut late: Option<Lightmap> = None;
        let mut rgb = vec![[0.0f32; 3]; (w * h) as usize];
        let mut pending: Option<Delta> = None;
        let mut skipper = client_for(&e); // receives merged deltas every other frame
        for (i, frame) in frames.iter().enumerate() {
            for &(texel, value) in frame {
                rgb[texel] = value;
            }
            let d = e.publish(&rgb, seqs(0, i as u64));
            // the delta also survives the wire
            let ServerMessage::Delta(d) = decode_server(&encode_server(&ServerMessage::Delta(d))).unwrap() else {
                unreachable!()
            };
            client.apply_delta(&d).unwrap();
            prop_assert_eq!(&client, e.state());
            if let Some(l) = late.as_mut() {
                l.apply_delta(&d).unwrap();
                prop_assert_eq!(&*l, e.state());
            } else if i == join_at {
                let mut l = client_for(&e);
                l.apply_keyframe(&e.keyframe()).unwrap();
                prop_assert_eq!(&l, e.state());
                late = Some(l);
            }
            pending = Some(match pending.take() {
                Some(p) => merge(&p, &d).unwrap(),
                None => d,
            });
            if i % 2 == 1 {
                skipper.apply_delta(&pending.take().unwrap()).unwrap();
                prop_assert_eq!(&skipper, e.state());
            }
        }
    }
}
