//! The relay's copy of one upstream scene, and its own version numbers.
//!
//! A relay's viewers hold **relay versions**, not the solver's. Within one
//! upstream connection the two move together (an upstream delta
//! `u -> u'` becomes the relay delta `r -> r + (u' - u)`), but they part
//! when the upstream connection is replaced: a restarted solver starts its
//! versions again from 1, and even the same solver may have moved on while
//! the relay was away. Viewers of the relay must never receive a delta onto
//! a state they do not hold, so the relay never forwards a delta across
//! connections. Instead:
//!
//! - an upstream **delta** is applied only onto the upstream version the
//!   mirror holds *on the current connection*; anything else is refused
//!   (the caller asks upstream for a `Resync` and waits for its keyframe);
//! - an upstream **keyframe** is compared tile by tile with the mirror's
//!   state. If nothing differs, the relay version stays (its viewers
//!   already hold that exact state) and only the upstream version it
//!   corresponds to moves. Otherwise the relay publishes a new version
//!   `max(u, r + 1)` with a delta carrying exactly the differing tiles,
//!   so a viewer holding `r` is resynced by a delta, not a keyframe.
//!
//! Relay versions therefore only ever increase, across solver restarts and
//! reconnects, and "holds relay version r" always names one exact state.
//! While a relay has followed one solver run since it started, relay and
//! solver versions are equal, which keeps logs and tests easy to read.

use std::collections::BTreeMap;
use std::sync::Arc;

use lightwire_protocol::lightmap::{ApplyError, Lightmap};
use lightwire_protocol::{Delta, Keyframe, LightStatus, ObjectPose, ObjectSeq, SceneInfo};

/// Why an upstream frame was not taken.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MirrorError {
    /// A delta before the first keyframe of this connection, or after a
    /// refused frame: ask for a resync.
    #[error("no keyframe on this connection yet (waiting for one)")]
    NotSynced,
    /// The frame does not apply (wrong base, bad tiles, ...).
    #[error(transparent)]
    Apply(#[from] ApplyError),
    /// Upstream version numbers that would push relay versions past
    /// `u64::MAX`: a broken or hostile upstream.
    #[error("upstream version {0} would overflow the relay's version numbers")]
    VersionOverflow(u64),
}

/// A version to publish.
pub struct Publish {
    pub keyframe: Keyframe,
    /// From the previous relay version; `None` for the first version of a
    /// new scene description (nobody can hold its base).
    pub delta: Option<Delta>,
}

/// The relay's state of one scene.
pub struct Mirror {
    pub info: Arc<SceneInfo>,
    /// Exactly what the relay's viewers hold at relay version `map.version`.
    map: Lightmap,
    /// The newest compressed texels of every tile (each decodes to the
    /// tile's texels in `map`), from which relay keyframes are built: an
    /// upstream keyframe's tiles as they came, tiles a delta changed
    /// compressed again from `map` (delta tiles are residuals).
    tiles: Vec<Vec<u8>>,
    /// The latest seq per object the state reflects.
    reflected: BTreeMap<u32, u64>,
    /// The upstream version `map` equals on the current connection.
    upstream: Option<u64>,
    /// Nothing published with this description yet.
    fresh: bool,
    /// The dynamic objects' poses of the upstream's newest version, as its
    /// `Poses` gave them (empty until it sends any), published with the
    /// next relay version.
    pub poses: Arc<[ObjectPose]>,
    /// The same for the lights' states, as the upstream's `Lights` gave
    /// them (empty until it sends any: an upstream without `CAP_LIGHTS`).
    pub lights: Arc<[LightStatus]>,
}

impl Mirror {
    /// An empty mirror for `info`. `last_version` is the newest relay
    /// version published so far (0 if none): versions continue after it.
    pub fn new(info: Arc<SceneInfo>, last_version: u64) -> Result<Self, ApplyError> {
        let mut map = Lightmap::for_scene(&info)?;
        map.version = last_version;
        let tiles = vec![Vec::new(); map.tile_count() as usize];
        Ok(Self {
            info,
            map,
            tiles,
            reflected: BTreeMap::new(),
            upstream: None,
            fresh: true,
            poses: Arc::default(),
            lights: Arc::default(),
        })
    }

    /// Takes the upstream's `Lights`: every entry must name a light of the
    /// description, once, with a valid state (else nothing changes).
    pub fn on_lights(&mut self, lights: Vec<LightStatus>) -> Result<(), String> {
        let mut seen = vec![false; self.info.lights.len()];
        for l in &lights {
            match seen.get_mut(l.light as usize) {
                Some(s) if !*s => *s = true,
                Some(_) => return Err(format!("Lights names light {} twice", l.light)),
                None => {
                    return Err(format!(
                        "Lights names light {}, not a light of the description",
                        l.light
                    ));
                }
            }
            l.state
                .validate()
                .map_err(|why| format!("Lights: light {}: {why}", l.light))?;
        }
        self.lights = lights.into();
        Ok(())
    }

    /// Takes the upstream's `Poses`: every entry must name a dynamic object
    /// of the description, with a valid pose (else nothing changes).
    pub fn on_poses(&mut self, poses: Vec<ObjectPose>) -> Result<(), String> {
        for p in &poses {
            if !self
                .info
                .objects
                .get(p.object as usize)
                .is_some_and(|o| o.dynamic)
            {
                return Err(format!(
                    "Poses names object {}, not a dynamic object",
                    p.object
                ));
            }
            p.pose
                .validate()
                .map_err(|why| format!("Poses: object {}: {why}", p.object))?;
        }
        self.poses = poses.into();
        Ok(())
    }

    /// The relay version of the state.
    pub fn version(&self) -> u64 {
        self.map.version
    }

    /// The upstream version the state equals, on the current connection.
    pub fn upstream_version(&self) -> Option<u64> {
        self.upstream
    }

    /// Forgets which upstream version the state equals: the connection is
    /// gone, or a frame was refused and a keyframe must come first.
    pub fn unsync(&mut self) {
        self.upstream = None;
    }

    /// The state as a relay keyframe.
    pub fn keyframe(&self) -> Keyframe {
        Keyframe::new(self.map.version, &self.reflected, &self.tiles)
    }

    /// Takes an upstream keyframe. `Ok(None)`: the state did not change,
    /// nothing to publish (the relay version stays).
    pub fn on_keyframe(&mut self, k: &Keyframe) -> Result<Option<Publish>, MirrorError> {
        let mut next = self.map.clone();
        next.apply_keyframe(k)?;
        let changed: Vec<u32> = (0..self.map.tile_count())
            .filter(|&i| self.fresh || tile_differs(&self.map, &next, i))
            .collect();
        self.upstream = Some(k.version);
        let reflected: Vec<ObjectSeq> = k
            .reflected
            .iter()
            .filter(|r| self.reflected.get(&r.object) != Some(&r.seq))
            .copied()
            .collect();
        for t in &k.tiles {
            // apply_keyframe checked: every index once, in range.
            self.tiles[t.index as usize] = t.data.clone();
        }
        self.reflected = k.reflected.iter().map(|r| (r.object, r.seq)).collect();
        if changed.is_empty() && !self.fresh {
            return Ok(None);
        }
        let base = self.map.version;
        let version = k.version.max(
            base.checked_add(1)
                .ok_or(MirrorError::VersionOverflow(k.version))?,
        );
        next.version = version;
        // Delta tiles are residuals onto what the viewers hold (the old
        // state), so they are computed here; keyframe tiles are the
        // upstream's, as they came.
        let delta = (!self.fresh).then(|| Delta {
            base_version: base,
            version,
            reflected,
            residual: self.map.delta_payload(&next, &changed),
        });
        self.map = next;
        self.fresh = false;
        Ok(Some(Publish {
            keyframe: self.keyframe(),
            delta,
        }))
    }

    /// Takes an upstream delta, which must apply onto the upstream version
    /// the state equals on this connection.
    pub fn on_delta(&mut self, d: &Delta) -> Result<Publish, MirrorError> {
        let Some(upstream) = self.upstream else {
            return Err(MirrorError::NotSynced);
        };
        if d.base_version != upstream {
            return Err(ApplyError::WrongBase {
                have: upstream,
                base: d.base_version,
            }
            .into());
        }
        if d.version <= d.base_version {
            return Err(ApplyError::NotIncreasing {
                base: d.base_version,
                version: d.version,
            }
            .into());
        }
        let base = self.map.version;
        let version = base
            .checked_add(d.version - d.base_version)
            .ok_or(MirrorError::VersionOverflow(d.version))?;
        let renumbered = Delta {
            base_version: base,
            version,
            reflected: d.reflected.clone(),
            residual: d.residual.clone(),
        };
        // Checks the whole payload before writing any texel: on error
        // nothing changed.
        let changed = self.map.apply_delta_tiles(&renumbered)?;
        // Delta tiles are residuals; keyframes need the tiles' texels.
        for index in changed {
            self.tiles[index as usize] = self.map.keyframe_tile(index).data;
        }
        for r in &d.reflected {
            self.reflected.insert(r.object, r.seq);
        }
        self.upstream = Some(d.version);
        Ok(Publish {
            keyframe: self.keyframe(),
            delta: Some(renumbered),
        })
    }
}

/// Whether tile `index` holds different texels in `a` and `b` (same
/// layout).
fn tile_differs(a: &Lightmap, b: &Lightmap, index: u32) -> bool {
    let Some(rect) = a.tile_rect(index) else {
        return true;
    };
    let bpt = a.format.bytes_per_texel();
    let row = rect.width as usize * bpt;
    (rect.y..rect.y + rect.height).any(|y| {
        let start = (y as usize * a.width as usize + rect.x as usize) * bpt;
        a.texels[start..start + row] != b.texels[start..start + row]
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightwire_protocol::PixelFormat;
    use lightwire_protocol::lightmap::Encoder;

    const W: u32 = 32;
    const H: u32 = 8; // 4 tiles in a row

    fn info() -> Arc<SceneInfo> {
        Arc::new(SceneInfo {
            id: "t".into(),
            atlas_width: W,
            atlas_height: H,
            tile_size: 8,
            format: PixelFormat::Rgb9e5,
            objects: vec![],
            materials: vec![],
            surfaces: vec![],
            lights: Vec::new(),
        })
    }

    #[test]
    fn upstream_poses_are_kept_only_when_they_name_dynamic_objects_with_valid_poses() {
        use lightwire_protocol::{ObjectInfo, Pose};
        let mut scene = (*info()).clone();
        for (name, dynamic) in [("static", false), ("box", true)] {
            scene.objects.push(ObjectInfo {
                name: name.into(),
                dynamic,
                pose: Pose::IDENTITY,
            });
        }
        let mut mirror = Mirror::new(Arc::new(scene), 0).expect("layout");
        let at = |object, pose| ObjectPose {
            object,
            seq: 3,
            pose,
        };
        let moved = Pose {
            translation: [1.0, 0.0, 0.0],
            ..Pose::IDENTITY
        };
        mirror.on_poses(vec![at(1, moved)]).expect("the box");
        assert_eq!(&*mirror.poses, &[at(1, moved)]);
        for bad in [
            vec![at(0, moved)],
            vec![at(7, moved)],
            vec![at(
                1,
                Pose {
                    translation: [f32::NAN, 0.0, 0.0],
                    ..moved
                },
            )],
        ] {
            assert!(mirror.on_poses(bad.clone()).is_err(), "{bad:?}");
            assert_eq!(&*mirror.poses, &[at(1, moved)], "unchanged after {bad:?}");
        }
    }

    /// A solver run: an encoder whose versions start at 1.
    fn solver() -> Encoder {
        Encoder::new(W, H, 8, PixelFormat::Rgb9e5, 0.0)
    }

    /// An image whose tile `t` has brightness `levels[t]`.
    fn image(levels: [f32; 4]) -> Vec<[f32; 3]> {
        (0..W * H)
            .map(|i| [levels[((i % W) / 8) as usize], 0.5, 0.25])
            .collect()
    }

    /// A viewer of the relay: applies what the relay publishes, exactly as
    /// a session would send it (the delta if it holds the base, else the
    /// keyframe).
    fn viewer_applies(viewer: &mut Lightmap, p: &Publish) {
        match &p.delta {
            Some(d) if d.base_version == viewer.version => {
                viewer.apply_delta(d).expect("relay delta applies")
            }
            _ => viewer
                .apply_keyframe(&p.keyframe)
                .expect("keyframe applies"),
        }
    }

    #[test]
    fn versions_follow_the_solver_and_increase_across_its_restart() {
        let mut mirror = Mirror::new(info(), 0).expect("layout");
        let mut viewer = Lightmap::for_scene(&info()).expect("layout");

        // Run 1: keyframe v1, then deltas to v3.
        let mut run1 = solver();
        let _ = run1.publish(&image([1.0, 1.0, 1.0, 1.0]), vec![]);
        let p = mirror
            .on_keyframe(&run1.keyframe())
            .expect("ok")
            .expect("first");
        assert!(p.delta.is_none(), "the first version is keyframe-only");
        assert_eq!(p.keyframe.version, 1, "aligned with the solver");
        viewer_applies(&mut viewer, &p);
        for step in 2..=3 {
            let d = run1.publish(&image([step as f32, 1.0, 1.0, 1.0]), vec![]);
            let p = mirror.on_delta(&d).expect("applies");
            assert_eq!(p.keyframe.version, step);
            viewer_applies(&mut viewer, &p);
        }
        assert_eq!(viewer, *run1.state());

        // The solver restarts: versions start over, the light is different
        // in two tiles. The old connection's deltas are refused.
        mirror.unsync();
        let mut run2 = solver();
        let d = run2.publish(&image([1.0, 1.0, 1.0, 7.0]), vec![]);
        assert_eq!(mirror.on_delta(&d).err(), Some(MirrorError::NotSynced));
        let p = mirror
            .on_keyframe(&run2.keyframe())
            .expect("ok")
            .expect("changed");
        assert_eq!(p.keyframe.version, 4, "relay versions never go back");
        let delta = p.delta.as_ref().expect("a delta resyncs viewers");
        assert_eq!(delta.base_version, 3);
        let indices = viewer.layout().delta_tiles(delta).expect("decodes");
        assert_eq!(indices, vec![0, 3], "exactly the tiles that differ");
        viewer_applies(&mut viewer, &p);
        assert_eq!(viewer.texels, run2.state().texels, "viewer resynced");
        assert_eq!(viewer.version, 4);

        // Deltas of the new run continue from there.
        let d = run2.publish(&image([1.0, 2.0, 1.0, 7.0]), vec![]);
        let p = mirror.on_delta(&d).expect("applies");
        assert_eq!(p.keyframe.version, 5);
        viewer_applies(&mut viewer, &p);
        assert_eq!(viewer.texels, run2.state().texels);
    }

    #[test]
    fn a_reconnect_to_an_unchanged_solver_publishes_nothing() {
        let mut mirror = Mirror::new(info(), 0).expect("layout");
        let mut run = solver();
        let _ = run.publish(&image([1.0; 4]), vec![]);
        let _ = run.publish(&image([2.0; 4]), vec![]);
        mirror.on_keyframe(&run.keyframe()).expect("ok");
        assert_eq!(mirror.version(), 2);
        mirror.unsync();
        assert!(
            mirror.on_keyframe(&run.keyframe()).expect("ok").is_none(),
            "same state: viewers already hold it"
        );
        assert_eq!(mirror.version(), 2);
        // Deltas of the new connection still apply.
        let d = run.publish(&image([3.0; 4]), vec![]);
        assert_eq!(mirror.on_delta(&d).expect("applies").keyframe.version, 3);
    }

    #[test]
    fn bad_upstream_frames_change_nothing() {
        let mut mirror = Mirror::new(info(), 0).expect("layout");
        let mut run = solver();
        let _ = run.publish(&image([1.0; 4]), vec![]);
        mirror.on_keyframe(&run.keyframe()).expect("ok");
        let before = mirror.keyframe();
        let mut d = run.publish(&image([2.0; 4]), vec![]);
        d.residual = vec![0xde, 0xad];
        assert!(matches!(
            mirror.on_delta(&d),
            Err(MirrorError::Apply(ApplyError::Residual(_)))
        ));
        let wrong_base = Delta {
            base_version: 9,
            ..d.clone()
        };
        assert!(matches!(
            mirror.on_delta(&wrong_base),
            Err(MirrorError::Apply(ApplyError::WrongBase { .. }))
        ));
        let huge = Delta {
            base_version: 2,
            version: u64::MAX,
            reflected: vec![],
            residual: vec![],
        };
        let mut high = Mirror::new(info(), u64::MAX - 1).expect("layout");
        high.on_keyframe(&run.keyframe()).expect("ok");
        assert_eq!(
            high.on_delta(&huge).err(),
            Some(MirrorError::VersionOverflow(u64::MAX))
        );
        let mut truncated = run.keyframe();
        truncated.tiles.pop();
        assert!(mirror.on_keyframe(&truncated).is_err());
        assert_eq!(mirror.keyframe(), before, "state untouched");
    }
}
