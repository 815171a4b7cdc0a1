//! Published lightmap versions, encoded once for every client, and the
//! [`Publisher`] that makes them.
//!
//! A session sends each client one of three frames for the newest
//! publication (see [`Publication::frame_for`]):
//!
//! - the **delta** when the client holds exactly its base version;
//! - a **merged delta** (`lightwire_protocol::lightmap::merge` of the last
//!   few deltas: tiles only one carries pass through, residuals of a tile
//!   several carry are composed) when the client holds one of the [`CATCH_UP`] versions
//!   before that, and the merge is smaller than a keyframe: a client that
//!   fell a little behind catches up for the price of the tiles that
//!   changed, not the whole atlas;
//! - the **keyframe** otherwise (a new client, a resync, far behind).
//!
//! Merged deltas are computed lazily, once per publication and base, the
//! first time a session needs one, and shared by every session that needs
//! the same one; a publication never holds more than [`CATCH_UP`] of them.
//! Memory per scene is therefore bounded by the newest publication and the
//! `CATCH_UP` deltas before it, whatever clients do.

use std::sync::{Arc, OnceLock};

use bytes::Bytes;
use lightwire_protocol::lightmap::{Layout, merge};
use lightwire_protocol::{
    Delta, Keyframe, LightStatus, ObjectPose, SceneInfo, ServerMessage, encode_server,
};
use tokio::sync::watch;

/// How many versions behind a client may be and still get a merged delta.
/// Clients fall behind by a few versions when one send blocks briefly;
/// further behind, a keyframe is as cheap as the merge and simpler.
pub const CATCH_UP: usize = 4;

/// A complete lightmap version as sent to clients. Frames are encoded on
/// first use and shared by every session (`Bytes`), so fan-out costs a
/// reference count per client, not an encode.
pub struct Publication {
    /// The scene this version belongs to. A session compares it with the
    /// description it sent in `Welcome`, so a relay whose upstream changed
    /// scenes never sends tiles of one scene to a client of another.
    pub scene: Arc<SceneInfo>,
    /// This version.
    pub version: u64,
    /// The version `delta` applies to (`None`: keyframe only, e.g. the
    /// first version of a relay's new scene description).
    pub base_version: Option<u64>,
    /// Every tile of this version.
    pub keyframe: Keyframe,
    /// The last deltas up to this version, oldest first; the last one is
    /// this version's delta (`base_version -> version`), and each one's
    /// version is the next one's base. At most [`CATCH_UP`].
    recent: Vec<Arc<Delta>>,
    /// Encoded frames: `[i]` brings a client from `recent[i].base_version`
    /// to `version` (`None` once computed: a keyframe is smaller).
    catch_up: Vec<OnceLock<Option<Bytes>>>,
    keyframe_frame: OnceLock<Bytes>,
    /// The poses of the dynamic objects this version was lit for (empty
    /// when unknown: a relay whose upstream does not send them), and
    /// their encoded `Poses` frame, for the sessions whose clients asked.
    pub poses: Arc<[ObjectPose]>,
    poses_frame: OnceLock<Bytes>,
    /// The lights' states this version was lit with (empty for a scene
    /// without lights, and on a relay), and their encoded `Lights` frame,
    /// for the sessions whose clients asked.
    pub lights: Arc<[LightStatus]>,
    lights_frame: OnceLock<Bytes>,
    /// Total payload of the keyframe's tiles, the bar a merge must beat.
    keyframe_bytes: usize,
}

fn tile_bytes(tiles: &[lightwire_protocol::Tile]) -> usize {
    tiles.iter().map(|t| t.data.len() + 8).sum()
}

impl Publication {
    /// The encoded `Keyframe` frame.
    pub fn keyframe_frame(&self) -> Bytes {
        self.keyframe_frame
            .get_or_init(|| {
                Bytes::from(encode_server(&ServerMessage::Keyframe(
                    self.keyframe.clone(),
                )))
            })
            .clone()
    }

    /// The encoded `Poses` frame of this version ([`Publication::poses`]).
    pub fn poses_frame(&self) -> Bytes {
        self.poses_frame
            .get_or_init(|| {
                Bytes::from(encode_server(&ServerMessage::Poses {
                    version: self.version,
                    poses: self.poses.to_vec(),
                }))
            })
            .clone()
    }

    /// The encoded `Lights` frame of this version ([`Publication::lights`]).
    pub fn lights_frame(&self) -> Bytes {
        self.lights_frame
            .get_or_init(|| {
                Bytes::from(encode_server(&ServerMessage::Lights {
                    version: self.version,
                    lights: self.lights.to_vec(),
                }))
            })
            .clone()
    }

    /// This version's own delta, if it has one.
    pub fn delta(&self) -> Option<&Delta> {
        self.recent.last().map(|d| d.as_ref())
    }

    /// The delta frame that brings a client holding `held` to this
    /// version: this version's delta, or a merge of the last few; `None`
    /// when the client must get the keyframe instead.
    pub fn frame_for(&self, held: u64) -> Option<Bytes> {
        let start = self.recent.iter().position(|d| d.base_version == held)?;
        self.catch_up[start]
            .get_or_init(|| {
                let chain = &self.recent[start..];
                let layout = Layout::of_scene(&self.scene);
                let mut merged = (*chain[0]).clone();
                for next in &chain[1..] {
                    // The chain is consecutive by construction; a broken
                    // link means a keyframe, never a wrong delta.
                    merged = merge(&layout, &merged, next).ok()?;
                }
                if chain.len() > 1 && merged.residual.len() >= self.keyframe_bytes {
                    return None;
                }
                Some(Bytes::from(encode_server(&ServerMessage::Delta(merged))))
            })
            .clone()
    }
}

/// Makes [`Publication`]s and hands the newest to every session through a
/// `watch` channel (which holds only the newest: nothing queues).
pub struct Publisher {
    tx: watch::Sender<Option<Arc<Publication>>>,
}

impl Publisher {
    /// A publisher and the receiver sessions watch.
    pub fn new() -> (Self, watch::Receiver<Option<Arc<Publication>>>) {
        let (tx, rx) = watch::channel(None);
        (Self { tx }, rx)
    }

    /// Publishes a new version: `keyframe` holds every tile of it; `delta`
    /// brings the previous version to it (`None` for a keyframe-only
    /// version, which also starts a new chain of deltas). A delta whose
    /// base is not the previous version also starts a new chain, so merged
    /// deltas are only ever built from consecutive versions. `poses`: the
    /// dynamic objects' poses the version was lit for
    /// ([`Publication::poses`]).
    pub fn publish(
        &self,
        scene: Arc<SceneInfo>,
        keyframe: Keyframe,
        delta: Option<Delta>,
        poses: Arc<[ObjectPose]>,
    ) -> Arc<Publication> {
        self.publish_lit(scene, keyframe, delta, (poses, Arc::default()))
    }

    /// [`Publisher::publish`], with the lights' states the version was lit
    /// with ([`Publication::lights`]).
    pub fn publish_lit(
        &self,
        scene: Arc<SceneInfo>,
        keyframe: Keyframe,
        delta: Option<Delta>,
        (poses, lights): (Arc<[ObjectPose]>, Arc<[LightStatus]>),
    ) -> Arc<Publication> {
        let previous = self.tx.borrow().clone();
        let mut recent: Vec<Arc<Delta>> = Vec::new();
        if let Some(delta) = delta {
            if let Some(p) = previous
                .filter(|p| p.version == delta.base_version && Arc::ptr_eq(&p.scene, &scene))
            {
                let keep = p.recent.len().min(CATCH_UP - 1);
                recent.extend(p.recent[p.recent.len() - keep..].iter().cloned());
            }
            recent.push(Arc::new(delta));
        }
        let publication = Arc::new(Publication {
            scene,
            version: keyframe.version,
            base_version: recent.last().map(|d| d.base_version),
            keyframe_bytes: tile_bytes(&keyframe.tiles),
            keyframe,
            catch_up: recent.iter().map(|_| OnceLock::new()).collect(),
            recent,
            keyframe_frame: OnceLock::new(),
            poses,
            poses_frame: OnceLock::new(),
            lights,
            lights_frame: OnceLock::new(),
        });
        self.tx.send_replace(Some(publication.clone()));
        publication
    }

    /// The newest publication.
    pub fn latest(&self) -> Option<Arc<Publication>> {
        self.tx.borrow().clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightwire_protocol::PixelFormat;
    use lightwire_protocol::lightmap::{Encoder, Lightmap};

    fn scene(width: u32, height: u32) -> Arc<SceneInfo> {
        Arc::new(SceneInfo {
            id: "test".into(),
            atlas_width: width,
            atlas_height: height,
            tile_size: 8,
            format: PixelFormat::Rgb9e5,
            objects: vec![],
            materials: vec![],
            surfaces: vec![],
            lights: Vec::new(),
        })
    }

    /// Encodes `rgb` as the next version and publishes it with its delta.
    fn publish_delta(
        publisher: &Publisher,
        info: &Arc<SceneInfo>,
        encoder: &mut Encoder,
        rgb: &[[f32; 3]],
    ) {
        let delta = encoder.publish(rgb, vec![]);
        publisher.publish(
            info.clone(),
            encoder.keyframe(),
            Some(delta),
            Arc::default(),
        );
    }

    fn image(width: u32, height: u32, step: u32, changed_tiles: u32) -> Vec<[f32; 3]> {
        // Tile columns 0..changed_tiles brighten with `step`.
        (0..width * height)
            .map(|i| {
                let x = i % width;
                let bump = if x / 8 < changed_tiles {
                    step as f32
                } else {
                    0.0
                };
                [1.0 + bump, 0.5, 0.25]
            })
            .collect()
    }

    fn decode(frame: &Bytes) -> ServerMessage {
        lightwire_protocol::decode_server(frame).expect("own frames decode")
    }

    /// The contract of `frame_for`: whatever frame a client at `held` gets,
    /// applying it yields exactly the newest version's state.
    #[test]
    fn a_client_a_few_versions_behind_catches_up_with_one_merged_delta() {
        let (w, h) = (64, 8); // 8 tiles in a row
        let info = scene(w, h);
        let mut encoder = Encoder::new(w, h, 8, PixelFormat::Rgb9e5, 0.0);
        let (publisher, rx) = Publisher::new();
        let mut states = vec![];
        for step in 1..=6 {
            // Version 1 sends every tile (onto the empty state); after
            // that only the first two tile columns change.
            publish_delta(&publisher, &info, &mut encoder, &image(w, h, step, 2));
            states.push(encoder.state().clone());
        }
        let newest = rx.borrow().clone().expect("published");
        assert_eq!(newest.version, 6);
        for held in 1..=6u64 {
            let frame = newest.frame_for(held);
            let behind = 6 - held as usize;
            if behind == 0 || behind > CATCH_UP {
                // Up to date (nothing to send) or too far behind.
                assert!(
                    frame.is_none() || behind == 0,
                    "{behind} behind gets a keyframe"
                );
                continue;
            }
            let frame = frame.unwrap_or_else(|| panic!("{behind} behind gets a delta"));
            let ServerMessage::Delta(d) = decode(&frame) else {
                panic!("a delta frame")
            };
            assert_eq!((d.base_version, d.version), (held, 6));
            assert_eq!(
                encoder
                    .state()
                    .layout()
                    .delta_tiles(&d)
                    .expect("decodes")
                    .len(),
                2,
                "only the tiles that changed"
            );
            let mut map = states[held as usize - 1].clone();
            map.apply_delta(&d).expect("applies onto its base");
            assert_eq!(&map, encoder.state(), "held {held}: state after catch-up");
        }
        // Too far behind: keyframe.
        assert!(newest.frame_for(1).is_none());
        let mut fresh = Lightmap::new(w, h, 8, PixelFormat::Rgb9e5);
        let ServerMessage::Keyframe(k) = decode(&newest.keyframe_frame()) else {
            panic!("a keyframe")
        };
        fresh.apply_keyframe(&k).expect("applies");
        assert_eq!(&fresh, encoder.state());
    }

    #[test]
    fn a_merge_as_large_as_a_keyframe_is_not_sent() {
        // Noise, other noise, then a flat light: the newest keyframe
        // compresses to almost nothing, while the merged residual from the
        // first noise to it cannot be compressed at all.
        let (w, h) = (16, 8); // two tiles
        let info = scene(w, h);
        let mut encoder = Encoder::new(w, h, 8, PixelFormat::Rgb9e5, 0.0);
        let (publisher, _rx) = Publisher::new();
        let mut seed = 12345u32;
        let mut noise = || {
            (0..w * h)
                .map(|_| {
                    [0; 3].map(|_| {
                        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                        (seed >> 8) as f32 / (1 << 24) as f32 * 4.0
                    })
                })
                .collect::<Vec<[f32; 3]>>()
        };
        let flat = vec![[0.5f32, 0.25, 0.125]; (w * h) as usize];
        for image in [noise(), noise(), flat] {
            publish_delta(&publisher, &info, &mut encoder, &image);
        }
        let newest = publisher.latest().expect("published");
        assert!(
            newest.frame_for(2).is_some(),
            "its own delta is always sent"
        );
        assert!(newest.frame_for(1).is_none(), "the merge is no smaller");
    }

    #[test]
    fn a_new_chain_never_merges_across_a_break() {
        let (w, h) = (64, 8);
        let info = scene(w, h);
        let mut encoder = Encoder::new(w, h, 8, PixelFormat::Rgb9e5, 0.0);
        let (publisher, _rx) = Publisher::new();
        for step in 1..=2 {
            publish_delta(&publisher, &info, &mut encoder, &image(w, h, step, 1));
        }
        // A keyframe-only version, then a delta on it.
        let _ = encoder.publish(&image(w, h, 3, 1), vec![]);
        publisher.publish(info.clone(), encoder.keyframe(), None, Arc::default());
        publish_delta(&publisher, &info, &mut encoder, &image(w, h, 4, 1));
        let newest = publisher.latest().expect("published");
        assert!(newest.frame_for(3).is_some());
        assert!(
            newest.frame_for(2).is_none(),
            "version 3 had no delta: no chain through it"
        );
        // Another scene description: no delta reaches across it either.
        let other = scene(w, h);
        publish_delta(&publisher, &other, &mut encoder, &image(w, h, 5, 1));
        let newest = publisher.latest().expect("published");
        assert!(newest.frame_for(4).is_some(), "its own delta");
        assert!(newest.frame_for(3).is_none());
    }
}
