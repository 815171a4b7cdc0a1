//! The double-buffered local lightmap.
//!
//! A renderer must never see a half-applied version (DESIGN.md,
//! "Amortization and double buffering"; PROTOCOL.md §1.4). The connection
//! task therefore applies every keyframe and delta to a **back** buffer
//! that only it touches; when a frame applied completely, the back buffer
//! becomes the new **front** [`Frame`], an immutable `Arc` that renderers
//! hold for as long as they like without locking. The new back buffer
//! starts as a copy of the new front (one memcpy of the atlas), so the
//! next delta applies onto exactly the version the front shows.
//!
//! A delta is applied only onto its exact base version; anything else is
//! refused without touching either buffer, and the caller asks the server
//! for a `Resync`. The protocol crate's [`Lightmap`] validates every tile
//! before writing any, so a hostile or corrupt frame also changes nothing.
//!
//! Memory stays at two atlases plus whatever old fronts renderers still
//! hold: [`DoubleBuffer::recycle`] takes a retired front back and reuses
//! its allocation when nobody else holds it.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use lightwire_protocol::lightmap::{ApplyError, Lightmap};
use lightwire_protocol::{Delta, Keyframe, LightStatus, ObjectPose, ObjectSeq, Pose, SceneInfo};

/// One complete lightmap version: what a renderer draws.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The scene this lightmap belongs to (its layout matches `lightmap`).
    pub scene: Arc<SceneInfo>,
    /// The texels, at [`Lightmap::version`].
    pub lightmap: Lightmap,
    /// Latest transform seq per object that this version reflects.
    pub reflected: BTreeMap<u32, u64>,
    /// The dynamic objects' poses this version was lit for, as the
    /// server's `Poses` last gave them (empty from a server that sends
    /// none; PROTOCOL.md §3).
    pub poses: BTreeMap<u32, Pose>,
    /// The lights' states this version was lit with, by light index, each
    /// with the seq of the `SetLight` that set it (0: the scene file's),
    /// as the server's `Lights` last gave them (empty unless the client
    /// asked, [`Options::lights`](crate::Options::lights), and the server
    /// offers them; PROTOCOL.md §3).
    pub lights: BTreeMap<u32, LightStatus>,
    /// When this version was completed locally.
    pub applied_at: Instant,
}

impl Frame {
    /// The lightmap version.
    pub fn version(&self) -> u64 {
        self.lightmap.version
    }

    /// FNV-1a (64-bit) of the quantized texel bytes: equal checksums mean
    /// (with overwhelming likelihood) bit-identical lightmaps. Load reports
    /// use it to show that every viewer ended on the server's state without
    /// shipping whole lightmaps.
    pub fn checksum(&self) -> u64 {
        fnv1a64(&self.lightmap.texels)
    }
}

/// FNV-1a, 64-bit (the offset basis and prime of the FNV reference).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// What a successful apply produced.
#[derive(Clone, Debug)]
pub struct Applied {
    /// The new front.
    pub frame: Arc<Frame>,
    /// Transforms this version reflects that the previous front did not
    /// (empty for the first keyframe a buffer receives: it is a catch-up,
    /// not a delivery of anything this client saw being sent).
    pub newly_reflected: Vec<ObjectSeq>,
    /// Light states this version is the first to show: a seq other than
    /// the previous front's for that light (empty for the first keyframe,
    /// as above).
    pub newly_lit: Vec<LightStatus>,
    /// Tiles the frame wrote (every tile for a keyframe).
    pub tiles: usize,
}

/// Front and back buffers for one scene layout; see the module docs.
#[derive(Debug)]
pub struct DoubleBuffer {
    scene: Arc<SceneInfo>,
    /// Where frames are applied; at the front's version between frames.
    back: Lightmap,
    /// The reflected seqs of `back`.
    back_reflected: BTreeMap<u32, u64>,
    /// The poses of the next version (`Poses` comes just before it).
    poses: BTreeMap<u32, Pose>,
    /// The lights' states of the next version (`Lights` comes just
    /// before it, after any `Poses`).
    lights: BTreeMap<u32, LightStatus>,
    front: Option<Arc<Frame>>,
    /// A retired front whose allocation the next swap can reuse.
    spare: Option<Lightmap>,
}

impl DoubleBuffer {
    /// Empty buffers for `scene`'s atlas. Fails (saying why) for layouts a
    /// well-behaved server never sends: tile size 0, an atlas over
    /// [`lightwire_protocol::lightmap::MAX_ATLAS_TEXELS`].
    pub fn new(scene: Arc<SceneInfo>) -> Result<Self, ApplyError> {
        let back = Lightmap::for_scene(&scene)?;
        Ok(DoubleBuffer {
            scene,
            back,
            back_reflected: BTreeMap::new(),
            poses: BTreeMap::new(),
            lights: BTreeMap::new(),
            front: None,
            spare: None,
        })
    }

    /// The scene these buffers are laid out for.
    pub fn scene(&self) -> &Arc<SceneInfo> {
        &self.scene
    }

    /// Takes `scene`, a description of the same scene as
    /// [`DoubleBuffer::scene`] whose lights may be in other states
    /// ([`SceneInfo::same_description`]: a reconnect's `Welcome` after a
    /// driver changed a light), and keeps the lightmap: the versions
    /// completed from now on carry `scene` (the front keeps the one it
    /// was lit with). Returns false, changing nothing, for a different
    /// scene, which needs new buffers ([`DoubleBuffer::new`]).
    pub fn relit(&mut self, scene: Arc<SceneInfo>) -> bool {
        if !self.scene.same_description(&scene) {
            return false;
        }
        self.scene = scene;
        true
    }

    /// The newest complete version, once a keyframe arrived.
    pub fn front(&self) -> Option<&Arc<Frame>> {
        self.front.as_ref()
    }

    /// The version deltas must be based on (`None` before the first keyframe).
    pub fn version(&self) -> Option<u64> {
        self.front.as_ref().map(|f| f.version())
    }

    /// Takes a `Poses` message: the poses of the version that follows
    /// (and of those after it, until the next `Poses`). Objects not
    /// dynamic in the scene, and invalid poses, are left out.
    pub fn set_poses(&mut self, poses: &[ObjectPose]) {
        for p in poses {
            let dynamic = self
                .scene
                .objects
                .get(p.object as usize)
                .is_some_and(|o| o.dynamic);
            if dynamic && p.pose.validate().is_ok() {
                self.poses.insert(p.object, p.pose);
            }
        }
    }

    /// Forgets the poses a previous connection sent (frames from now on
    /// carry only those of the new one).
    pub fn clear_poses(&mut self) {
        self.poses.clear();
    }

    /// Takes a `Lights` message: the states of the version that follows
    /// (and of those after it, until the next `Lights`). Entries for a
    /// light the scene does not have, and invalid states, are left out.
    pub fn set_lights(&mut self, lights: &[LightStatus]) {
        for l in lights {
            if (l.light as usize) < self.scene.lights.len() && l.state.validate().is_ok() {
                self.lights.insert(l.light, *l);
            }
        }
    }

    /// Forgets the lights' states a previous connection sent.
    pub fn clear_lights(&mut self) {
        self.lights.clear();
    }

    /// Replaces everything with a keyframe and swaps it to the front.
    pub fn apply_keyframe(&mut self, k: &Keyframe) -> Result<Applied, ApplyError> {
        self.back.apply_keyframe(k)?;
        let previous = self.front.is_some().then(|| self.back_reflected.clone());
        self.back_reflected = k.reflected.iter().map(|r| (r.object, r.seq)).collect();
        let newly = match previous {
            None => Vec::new(),
            Some(before) => newer(&self.back_reflected, &before),
        };
        Ok(self.swap(newly, k.tiles.len()))
    }

    /// Applies a delta onto exactly its base version and swaps it to the
    /// front. Before the first keyframe every delta is refused
    /// ([`ApplyError::WrongBase`] with `have: 0`, the "no version" of
    /// [`Lightmap`]); on any error neither buffer changes.
    pub fn apply_delta(&mut self, d: &Delta) -> Result<Applied, ApplyError> {
        if self.front.is_none() {
            return Err(ApplyError::WrongBase {
                have: 0,
                base: d.base_version,
            });
        }
        let tiles = self.back.apply_delta_tiles(d)?.len();
        let before = self.back_reflected.clone();
        for r in &d.reflected {
            let seq = self.back_reflected.entry(r.object).or_insert(r.seq);
            *seq = (*seq).max(r.seq);
        }
        let newly = newer(&self.back_reflected, &before);
        Ok(self.swap(newly, tiles))
    }

    /// Gives a retired front back (e.g. the value a `watch` channel
    /// replaced) so the next swap reuses its allocation if nobody else
    /// holds it.
    pub fn recycle(&mut self, old: Arc<Frame>) {
        if let Ok(frame) = Arc::try_unwrap(old) {
            if frame.lightmap.texels.len() == self.back.texels.len() {
                self.spare = Some(frame.lightmap);
            }
        }
    }

    /// Moves the completed back buffer to the front and makes a new back
    /// buffer at the same version.
    fn swap(&mut self, newly_reflected: Vec<ObjectSeq>, tiles: usize) -> Applied {
        // A light whose seq differs from the previous front's was set
        // since (seqs are in serial-number order, so "differs", not
        // "greater"); the first front is a catch-up.
        let newly_lit = match &self.front {
            None => Vec::new(),
            Some(front) => self
                .lights
                .values()
                .filter(|l| front.lights.get(&l.light).is_none_or(|f| f.seq != l.seq))
                .copied()
                .collect(),
        };
        let mut next_back = match self.spare.take() {
            Some(mut spare) => {
                spare.texels.copy_from_slice(&self.back.texels);
                spare.version = self.back.version;
                spare
            }
            None => self.back.clone(),
        };
        std::mem::swap(&mut next_back, &mut self.back);
        let frame = Arc::new(Frame {
            scene: self.scene.clone(),
            lightmap: next_back,
            reflected: self.back_reflected.clone(),
            poses: self.poses.clone(),
            lights: self.lights.clone(),
            applied_at: Instant::now(),
        });
        if let Some(old) = self.front.replace(frame.clone()) {
            self.recycle(old);
        }
        Applied {
            frame,
            newly_reflected,
            newly_lit,
            tiles,
        }
    }
}

/// Entries of `now` whose seq is greater than in `before` (or new).
fn newer(now: &BTreeMap<u32, u64>, before: &BTreeMap<u32, u64>) -> Vec<ObjectSeq> {
    now.iter()
        .filter(|(object, seq)| before.get(object).is_none_or(|b| *seq > b))
        .map(|(&object, &seq)| ObjectSeq { object, seq })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightwire_protocol::PixelFormat;
    use lightwire_protocol::lightmap::Encoder;

    fn scene() -> Arc<SceneInfo> {
        Arc::new(SceneInfo {
            id: "t".into(),
            atlas_width: 10,
            atlas_height: 9,
            tile_size: 4,
            format: PixelFormat::Rgb9e5,
            objects: vec![],
            materials: vec![],
            surfaces: vec![],
            lights: Vec::new(),
        })
    }

    fn image(value: f32) -> Vec<[f32; 3]> {
        (0..90).map(|i| [value + i as f32, value, 1.0]).collect()
    }

    #[test]
    fn frames_carry_the_poses_sent_before_them_for_dynamic_objects_only() {
        use lightwire_protocol::{ObjectInfo, Pose};
        let mut info = (*scene()).clone();
        for (name, dynamic) in [("static", false), ("box", true)] {
            info.objects.push(ObjectInfo {
                name: name.into(),
                dynamic,
                pose: Pose::IDENTITY,
            });
        }
        let mut enc = Encoder::new(10, 9, 4, PixelFormat::Rgb9e5, 0.0);
        let _ = enc.publish(&image(1.0), vec![]);
        let mut buf = DoubleBuffer::new(Arc::new(info)).expect("layout");
        let moved = Pose {
            translation: [1.0, 2.0, 3.0],
            ..Pose::IDENTITY
        };
        let bad = Pose {
            scale: 0.0,
            ..Pose::IDENTITY
        };
        let entry = |object, pose| ObjectPose {
            object,
            seq: 4,
            pose,
        };
        // The static world, an object past the list and an invalid pose
        // are left out; the box's pose is kept.
        buf.set_poses(&[entry(0, moved), entry(1, moved), entry(9, moved)]);
        let first = buf.apply_keyframe(&enc.keyframe()).expect("applies").frame;
        assert_eq!(first.poses, BTreeMap::from([(1, moved)]));
        buf.set_poses(&[entry(1, bad)]);
        let d = enc.publish(&image(2.0), vec![]);
        let second = buf.apply_delta(&d).expect("applies").frame;
        assert_eq!(
            second.poses,
            BTreeMap::from([(1, moved)]),
            "until the next valid Poses"
        );
    }

    #[test]
    fn frames_carry_the_lights_sent_before_them_and_report_each_new_seq_once() {
        use lightwire_protocol::{LightInfo, LightState, LightType};
        let state = LightState {
            on: true,
            color: [1.0; 3],
            intensity: 8.0,
            position: [1.0, 2.0, 3.0],
            direction: [0.0, -1.0, 0.0],
        };
        let mut info = (*scene()).clone();
        info.lights.push(LightInfo {
            name: "bulb".into(),
            kind: LightType::Point,
            range: None,
            cone: [0.0; 2],
            angular_radius: 0.0,
            state,
        });
        let status = |light, seq, state| LightStatus { light, seq, state };
        let off = LightState { on: false, ..state };
        let bad = LightState {
            intensity: -1.0,
            ..state
        };
        let mut enc = Encoder::new(10, 9, 4, PixelFormat::Rgb9e5, 0.0);
        let _ = enc.publish(&image(1.0), vec![]);
        let mut buf = DoubleBuffer::new(Arc::new(info)).expect("layout");
        // A light past the list is left out.
        buf.set_lights(&[status(0, 0, state), status(3, 9, state)]);
        let first = buf.apply_keyframe(&enc.keyframe()).expect("applies");
        assert_eq!(
            first.frame.lights,
            BTreeMap::from([(0, status(0, 0, state))])
        );
        assert!(first.newly_lit.is_empty(), "the first front is a catch-up");
        buf.set_lights(&[status(0, 7, off)]);
        let second = buf
            .apply_delta(&enc.publish(&image(2.0), vec![]))
            .expect("applies");
        assert_eq!(second.newly_lit, vec![status(0, 7, off)]);
        assert_eq!(second.frame.lights[&0], status(0, 7, off));
        // The states hold for the versions after it, reported once; an
        // invalid state is left out.
        buf.set_lights(&[status(0, 8, bad)]);
        let third = buf
            .apply_delta(&enc.publish(&image(3.0), vec![]))
            .expect("applies");
        assert!(third.newly_lit.is_empty());
        assert_eq!(third.frame.lights[&0], status(0, 7, off));
        // A seq that wrapped round is a new one too.
        buf.set_lights(&[status(0, 0, state)]);
        let fourth = buf
            .apply_delta(&enc.publish(&image(4.0), vec![]))
            .expect("applies");
        assert_eq!(fourth.newly_lit, vec![status(0, 0, state)]);
    }

    #[test]
    fn a_delta_lands_in_the_back_and_the_front_swaps_only_when_complete() {
        let mut enc = Encoder::new(10, 9, 4, PixelFormat::Rgb9e5, 0.0);
        let d1 = enc.publish(&image(1.0), vec![ObjectSeq { object: 1, seq: 5 }]);
        let k1 = enc.keyframe();
        let mut buf = DoubleBuffer::new(scene()).expect("layout");
        assert!(buf.front().is_none());
        assert!(
            matches!(
                buf.apply_delta(&d1),
                Err(ApplyError::WrongBase { have: 0, .. })
            ),
            "no delta before the first keyframe"
        );
        let first = buf.apply_keyframe(&k1).expect("keyframe");
        assert_eq!(first.frame.version(), k1.version);
        assert!(
            first.newly_reflected.is_empty(),
            "a first keyframe is a catch-up"
        );
        let held = first.frame.clone(); // a renderer holding the front

        let d2 = enc.publish(&image(2.0), vec![ObjectSeq { object: 1, seq: 9 }]);
        let second = buf.apply_delta(&d2).expect("delta onto its base");
        assert_eq!(second.frame.version(), d2.version);
        assert_eq!(
            second.newly_reflected,
            vec![ObjectSeq { object: 1, seq: 9 }]
        );
        assert_eq!(
            second.frame.lightmap.texels,
            enc.state().texels,
            "bit-exact"
        );
        // The old front is untouched while someone holds it.
        assert_eq!(held.version(), k1.version);
        assert_ne!(held.lightmap.texels, second.frame.lightmap.texels);
        assert_eq!(buf.version(), Some(d2.version));
    }

    #[test]
    fn a_delta_on_the_wrong_base_or_with_a_bad_tile_changes_nothing() {
        let mut enc = Encoder::new(10, 9, 4, PixelFormat::Rgb9e5, 0.0);
        enc.publish(&image(1.0), vec![]);
        let mut buf = DoubleBuffer::new(scene()).expect("layout");
        let front = buf.apply_keyframe(&enc.keyframe()).expect("keyframe").frame;
        let d2 = enc.publish(&image(2.0), vec![]);
        let d3 = enc.publish(&image(3.0), vec![]);
        assert!(matches!(
            buf.apply_delta(&d3),
            Err(ApplyError::WrongBase { .. })
        ));
        let mut corrupt = d2.clone();
        corrupt.residual = vec![1, 2, 3];
        assert!(buf.apply_delta(&corrupt).is_err());
        assert!(
            Arc::ptr_eq(buf.front().expect("front"), &front),
            "front kept"
        );
        // The back buffer is still exactly at the front's version.
        buf.apply_delta(&d2).expect("the right delta still applies");
        let last = buf.apply_delta(&d3).expect("and the next one").frame;
        assert_eq!(last.lightmap.texels, enc.state().texels);
    }

    #[test]
    fn fnv1a64_matches_the_reference_vectors() {
        // From the FNV reference test suite.
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn a_retired_front_is_reused_when_nobody_holds_it() {
        let mut enc = Encoder::new(10, 9, 4, PixelFormat::Rgb9e5, 0.0);
        enc.publish(&image(1.0), vec![]);
        let mut buf = DoubleBuffer::new(scene()).expect("layout");
        buf.apply_keyframe(&enc.keyframe()).expect("keyframe");
        // Nobody outside holds fronts: every swap recycles the previous one.
        for v in 2..10 {
            let d = enc.publish(&image(v as f32), vec![]);
            let applied = buf.apply_delta(&d).expect("delta");
            drop(applied);
            assert!(buf.spare.is_some(), "the previous front became the spare");
        }
        assert_eq!(
            buf.front().expect("front").lightmap.texels,
            enc.state().texels
        );
    }

    #[test]
    fn keyframes_report_only_seqs_newer_than_the_previous_front() {
        let mut enc = Encoder::new(10, 9, 4, PixelFormat::Rgb9e5, 0.0);
        enc.publish(
            &image(1.0),
            vec![
                ObjectSeq { object: 0, seq: 3 },
                ObjectSeq { object: 1, seq: 4 },
            ],
        );
        let mut buf = DoubleBuffer::new(scene()).expect("layout");
        buf.apply_keyframe(&enc.keyframe()).expect("first");
        enc.publish(&image(2.0), vec![ObjectSeq { object: 1, seq: 8 }]);
        let resynced = buf
            .apply_keyframe(&enc.keyframe())
            .expect("resync keyframe");
        assert_eq!(
            resynced.newly_reflected,
            vec![ObjectSeq { object: 1, seq: 8 }]
        );
        assert_eq!(resynced.frame.reflected.get(&0), Some(&3));
    }
}
