//! The lightmap codec's contract: a client that applies what the encoder
//! publishes holds exactly the encoder's state, bit for bit, at every
//! version; bad input changes nothing.

mod common;

use common::vectors::{light_field, spot};
use lightwire_protocol::lightmap::{
    ApplyError, Encoder, Lightmap, dequantize, merge, quantize_into, residual,
};
use lightwire_protocol::*;
use proptest::prelude::*;

fn client_for(e: &Encoder) -> Lightmap {
    let s = e.state();
    Lightmap::new(s.width, s.height, s.tile_size, s.format)
}

/// The tiles a delta of `e`'s layout carries.
/// An 8 x 8 encoder at a 5% budget that has published a flat lightmap,
/// the lightmap, and a client that holds it.
fn flat_at_5_percent() -> (Encoder, Vec<[f32; 3]>, Lightmap) {
    let mut e = Encoder::new(8, 8, 8, PixelFormat::Rgb9e5, 0.05);
    let rgb = vec![[1.0, 2.0, 4.0]; 64];
    let mut client = client_for(&e);
    client.apply_delta(&e.publish(&rgb, vec![])).unwrap();
    (e, rgb, client)
}

fn tiles(e: &Encoder, d: &Delta) -> Vec<u32> {
    e.state()
        .layout()
        .delta_tiles(d)
        .expect("the delta decodes")
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
    assert_eq!(tiles(&e, &d), vec![1]);
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
    let (mut e, mut rgb, mut client) = flat_at_5_percent();
    let before = e.state().clone();

    rgb[10] = [1.03, 2.0, 4.0]; // 3 % < 5 %
    let d = e.publish(&rgb, seqs(3, 9));
    assert!(
        tiles(&e, &d).is_empty(),
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
    assert_eq!(tiles(&e, &d).len(), 1);
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
    assert!(tiles(&e, &d).is_empty());
    let d = e.publish(&[[floor * 0.2; 3]; 16], vec![]);
    assert_eq!(tiles(&e, &d).len(), 1);
}

#[test]
fn wrong_base_is_rejected_and_leaves_the_state_untouched() {
    let mut e = Encoder::new(12, 12, 4, PixelFormat::Rgb9e5, 0.0);
    let mut client = client_for(&e);
    let d1 = e.publish(&gradient(12, 12, 0.0), vec![]);
    let d2 = e.publish(&gradient(12, 12, 1.0), vec![]);
    // Refused as based on `base` while the client holds `have`, which it
    // still holds after.
    let refused = |client: &mut Lightmap, d: &Delta, (have, base)| {
        let before = client.clone();
        assert_eq!(
            client.apply_delta(d),
            Err(ApplyError::WrongBase { have, base })
        );
        assert_eq!(*client, before);
    };
    refused(&mut client, &d2, (0, 1));
    client.apply_delta(&d1).unwrap();
    refused(&mut client, &d1, (1, 0));
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

    let layout = e.state().layout();
    let m = merge(&layout, &a, &b).unwrap();
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
        merge(&layout, &b, &a),
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
                Some(p) => merge(&e.state().layout(), &p, &d).unwrap(),
                None => d,
            });
            if i % 2 == 1 {
                skipper.apply_delta(&pending.take().unwrap()).unwrap();
                prop_assert_eq!(&skipper, e.state());
            }
        }
    }
}

/// The quantized form of `rgb`, texel by texel, as the encoder's targets.
fn quantized(format: PixelFormat, rgb: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let mut bytes = vec![0u8; format.bytes_per_texel()];
    rgb.iter()
        .map(|&c| {
            quantize_into(format, c, &mut bytes);
            dequantize(format, &bytes)
        })
        .collect()
}

/// How many texels quantize differently in `a` and `b`.
fn quantized_bytes(a: &[[f32; 3]], b: &[[f32; 3]]) -> usize {
    let (mut x, mut y) = ([0u8; 4], [0u8; 4]);
    a.iter()
        .zip(b)
        .filter(|(p, q)| {
            quantize_into(PixelFormat::Rgb9e5, **p, &mut x);
            quantize_into(PixelFormat::Rgb9e5, **q, &mut y);
            x != y
        })
        .count()
}

/// The largest budget measure (|target - held| / max(held, target, floor),
/// per channel) over every texel.
fn worst_deviation(held: &Lightmap, target: &[[f32; 3]], floor: f32) -> f32 {
    held.to_rgb()
        .iter()
        .zip(target)
        .flat_map(|(h, t)| {
            (0..3).map(move |c| {
                let d = (h[c] - t[c]).abs();
                if d == 0.0 {
                    0.0
                } else {
                    d / h[c].max(t[c]).max(floor)
                }
            })
        })
        .fold(0.0, f32::max)
}

/// A light field sweeping across the atlas, like the light a moving box
/// throws: a smooth base, a bright spot that travels, a shadow that turns.
fn moving_light(w: u32, h: u32, frame: u32) -> Vec<[f32; 3]> {
    let t = frame as f32 * 0.004;
    light_field(w, h, |x, y| {
        let spot = spot(x, y, t, 0.4, 20.0);
        let shadow = 0.6 + 0.4 * ((x - 0.5) * t.cos() + (y - 0.5) * t.sin()).tanh();
        let base = 0.2 + 0.3 * y;
        [
            (base + 2.0 * spot) * shadow,
            (base * 0.8 + 1.5 * spot) * shadow,
            (base * 0.5 + 0.2 * spot) * shadow + 1e-4,
        ]
    })
}

#[test]
fn ten_thousand_versions_stay_bit_exact_and_within_the_budget_then_converge() {
    let (w, h, eps) = (40, 24, 1.0 / 64.0);
    let mut e = Encoder::new(w, h, 8, PixelFormat::Rgb9e5, eps);
    let floor = e.floor();
    let mut client = client_for(&e);
    // A second receiver that only ever gets merges of three deltas, and a
    // third that joins from a keyframe half way.
    let mut merging = client_for(&e);
    let mut chain: Option<Delta> = None;
    let mut late: Option<Lightmap> = None;
    let mut worst = 0.0f32;
    let (mut sent_texels, mut changed_texels) = (0usize, 0usize);
    let mut previous = vec![[0.0f32; 3]; (w * h) as usize];
    for frame in 0..10_000u32 {
        let rgb = moving_light(w, h, frame);
        let d = e.publish(&rgb, vec![]);
        let before = client.texels.clone();
        client.apply_delta(&d).expect("every delta applies");
        sent_texels += before
            .chunks_exact(4)
            .zip(client.texels.chunks_exact(4))
            .filter(|(a, b)| a != b)
            .count();
        changed_texels += quantized_bytes(&previous, &rgb);
        previous = rgb.clone();
        worst = worst.max(worst_deviation(
            &client,
            &quantized(PixelFormat::Rgb9e5, &rgb),
            floor,
        ));
        if let Some(l) = late.as_mut() {
            l.apply_delta(&d).expect("applies after the keyframe");
        } else if frame == 5_000 {
            let mut l = client_for(&e);
            l.apply_keyframe(&e.keyframe()).expect("keyframe applies");
            late = Some(l);
        }
        chain = Some(match chain.take() {
            Some(c) => merge(&e.state().layout(), &c, &d).expect("consecutive deltas merge"),
            None => d,
        });
        if frame % 3 == 2 {
            merging
                .apply_delta(&chain.take().expect("a chain"))
                .expect("the merge applies");
        }
        if frame % 1000 == 999 {
            assert_eq!(
                &client,
                e.state(),
                "receiver and server part at version {}",
                e.state().version
            );
        }
    }
    assert_eq!(&client, e.state());
    assert_eq!(late.as_ref(), Some(e.state()));
    if let Some(c) = chain.take() {
        merging.apply_delta(&c).expect("the last merge applies");
    }
    assert_eq!(&merging, e.state());
    assert!(
        worst <= eps,
        "a receiver deviated by {worst} of the budget measure; the budget is {eps}"
    );
    assert!(
        e.pending_texels() > 0,
        "the sequence must leave texels waiting, or the convergence below is not tested"
    );
    assert!(
        sent_texels * 2 < changed_texels,
        "the budget must hold changes back: {sent_texels} texel updates sent for {changed_texels} quantized changes"
    );

    // The scene holds still: one more publish of the same light sends
    // everything that waited, exactly.
    let last = moving_light(w, h, 9_999);
    let d = e.publish(&last, vec![]);
    client.apply_delta(&d).expect("applies");
    assert_eq!(e.pending_texels(), 0);
    let mut exact = Lightmap::new(w, h, 8, PixelFormat::Rgb9e5);
    let mut bytes = vec![0u8; 4];
    for (i, c) in last.iter().enumerate() {
        quantize_into(PixelFormat::Rgb9e5, *c, &mut bytes);
        exact.texels[i * 4..i * 4 + 4].copy_from_slice(&bytes);
    }
    assert_eq!(
        client.texels, exact.texels,
        "after settling, receivers hold the solver's lightmap exactly"
    );
}

#[test]
fn what_waits_is_sent_once_the_lightmap_holds_still() {
    let (mut e, mut rgb, mut client) = flat_at_5_percent();
    rgb[10] = [1.03, 2.0, 4.0];
    let d = e.publish(&rgb, vec![]);
    assert!(tiles(&e, &d).is_empty(), "3 % waits at a 5 % budget");
    client.apply_delta(&d).unwrap();
    assert_eq!(e.pending_texels(), 1);
    let d = e.publish(&rgb, vec![]);
    assert_eq!(
        tiles(&e, &d).len(),
        1,
        "the same lightmap again sends what waited"
    );
    client.apply_delta(&d).unwrap();
    assert_eq!(e.pending_texels(), 0);
    assert!((client.texel(2, 1)[0] - 1.03).abs() < 1.03 / 500.0);
    assert!(
        {
            let d = e.publish(&rgb, vec![]);
            tiles(&e, &d).is_empty()
        },
        "nothing left to send"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Residuals are exact on any texel bytes and compose like the deltas
    /// they come from.
    #[test]
    fn residuals_apply_exactly_and_compose(
        rgba in any::<bool>(),
        a in proptest::collection::vec(any::<u8>(), 64),
        b in proptest::collection::vec(any::<u8>(), 64),
        c in proptest::collection::vec(any::<u8>(), 64),
    ) {
        let format = if rgba { PixelFormat::Rgba16f } else { PixelFormat::Rgb9e5 };
        let (ab, bc) = (residual::encode(format, &a, &b), residual::encode(format, &b, &c));
        let mut x = a.clone();
        residual::apply(format, &mut x, &ab);
        prop_assert_eq!(&x, &b);
        let mut y = a.clone();
        residual::apply(format, &mut y, &residual::compose(format, &ab, &bc));
        prop_assert_eq!(&y, &c);
        // Any bytes are a residual, and composing arbitrary ones is
        // applying them in turn.
        let mut one = a.clone();
        residual::apply(format, &mut one, &b);
        residual::apply(format, &mut one, &c);
        let mut both = a.clone();
        residual::apply(format, &mut both, &residual::compose(format, &b, &c));
        prop_assert_eq!(one, both);
    }
}
