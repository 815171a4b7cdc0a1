//! Between the protocol's types and the scene's, in one place.
//!
//! A driver's `Transform` is checked here when a session reads it
//! ([`check_transform`]: one of the dynamic objects of the scene its client
//! was welcomed with, a valid pose). It then waits in the inbox in wire
//! form, so that a relay forwards exactly the bits its driver sent, and the
//! tick loop converts it here ([`from_wire`]) when it hands poses to the
//! solver; the versions that reflect it echo its seq ([`newly_reflected`]).
//! Scenes go out to clients as a [`SceneInfo`] ([`scene_info`]).
//! Nothing past this module (the solvers, `gpu/`) sees a wire type.

use glam::{Quat, Vec3};
use lightwire_protocol::{
    ErrorCode, LightState, LightStatus, ObjectSeq, Pose as WirePose, SceneInfo,
};

use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Light, LightKind, Pose, Scene};

/// Why a client frame is refused: the `Error` frame's code, the kind
/// counted in `lightwire_bad_frames_total`, and the frame's message.
pub type Refusal = (ErrorCode, &'static str, String);

/// Checks a driver's transform of `object` to `pose` against `info`, the
/// description its client was welcomed with: the object must be one of its
/// dynamic objects (else `UnknownObject`), the pose valid
/// ([`WirePose::validate`]; else `InvalidPose`), in that order. Returns the
/// object's index.
pub fn check_transform(info: &SceneInfo, object: u32, pose: &WirePose) -> Result<usize, Refusal> {
    let index = object as usize;
    if !info.objects.get(index).is_some_and(|o| o.dynamic) {
        return Err(unknown_object(info, object));
    }
    pose.validate().map_err(|why| {
        (
            ErrorCode::InvalidPose,
            "invalid_pose",
            format!("object {object}: {why}"),
        )
    })?;
    Ok(index)
}

/// The refusal of a transform of `object`, which is not a dynamic object
/// of the scene `info` describes.
pub fn unknown_object(info: &SceneInfo, object: u32) -> Refusal {
    (
        ErrorCode::UnknownObject,
        "unknown_object",
        format!(
            "object {object} is not a dynamic object of scene \"{}\"",
            info.id
        ),
    )
}

/// Converts a wire pose (already checked by [`check_transform`]) to a
/// scene pose.
pub fn from_wire(p: &WirePose) -> Pose {
    Pose {
        translation: Vec3::from_array(p.translation),
        rotation: Quat::from_array(p.rotation).normalize(),
        scale: p.scale,
    }
}

/// What a version echoes (`reflected`, PROTOCOL.md §3): the seq per object
/// of its state, `now`, where it is newer than that of the previous
/// version's, `before`.
pub fn newly_reflected(now: &[u64], before: &[u64]) -> Vec<ObjectSeq> {
    now.iter()
        .zip(before)
        .enumerate()
        // A seq only ever changes to a newer one (serial-number order,
        // `seq_is_newer`: after 2^64 - 1 comes 0), so any change is news.
        .filter(|(_, (now, before))| now != before)
        .map(|(object, (seq, _))| ObjectSeq {
            object: object as u32,
            seq: *seq,
        })
        .collect()
}

/// Checks a driver's `SetLight` of `light` to `state` against `info`:
/// one of its lights (else `UnknownLight`), a valid state
/// ([`LightState::validate`]; else `InvalidLight`), in that order.
/// Returns the light's index.
pub fn check_light(info: &SceneInfo, light: u32, state: &LightState) -> Result<usize, Refusal> {
    let index = light as usize;
    if index >= info.lights.len() {
        return Err((
            ErrorCode::UnknownLight,
            "unknown_light",
            format!(
                "light {light} is not a light of scene \"{}\", which has {}",
                info.id,
                info.lights.len()
            ),
        ));
    }
    state.validate().map_err(|why| {
        (
            ErrorCode::InvalidLight,
            "invalid_light",
            format!("light {light}: {why}"),
        )
    })?;
    Ok(index)
}

/// The scene's light `base` in the wire state `state` (already checked by
/// [`check_light`]): its kind, cone, disc and range as they are, its
/// intensity `color × intensity` when on (black when off), its position,
/// and for a spot or directional light its direction (normalized). A light
/// that rides with a dynamic object keeps its own position and direction:
/// it goes where its object goes (PROTOCOL.md §4).
pub fn light_from_wire(base: &Light, state: &LightState) -> Light {
    if base.object != lightwire_scene::STATIC_OBJECT {
        let mut riding = light_from_wire(
            &Light {
                object: lightwire_scene::STATIC_OBJECT,
                ..base.clone()
            },
            state,
        );
        riding.position = base.position;
        riding.kind = base.kind;
        riding.object = base.object;
        return riding;
    }
    let sent = Vec3::from_array(state.direction);
    // The scene's own direction as `SceneInfo` gave it is kept to the bit
    // (normalizing a unit vector again may change its last bit, and a
    // light whose direction changed is no longer the one the session's
    // basis holds, `gpu::basis`: a switch would be shot, not composed).
    let direction = match base.kind {
        LightKind::Spot { direction, .. } | LightKind::Directional { direction, .. }
            if direction == sent =>
        {
            direction
        }
        _ => sent.normalize_or(Vec3::NEG_Y),
    };
    let kind = match base.kind {
        LightKind::Point => LightKind::Point,
        LightKind::Spot { inner, outer, .. } => LightKind::Spot {
            direction,
            inner,
            outer,
        },
        LightKind::Directional { angular_radius, .. } => LightKind::Directional {
            direction,
            angular_radius,
        },
    };
    let intensity = if state.on {
        Vec3::from_array(state.color) * state.intensity
    } else {
        Vec3::ZERO
    };
    Light {
        name: base.name.clone(),
        kind,
        position: Vec3::from_array(state.position),
        intensity,
        range: base.range,
        object: base.object,
    }
}

/// The scene's lights `base` in the states `statuses` give them (a
/// publication's `Lights`: the states a version was lit with), each as
/// [`light_from_wire`] makes it; a light without a status keeps its own.
pub fn lights_now(base: &[Light], statuses: &[LightStatus]) -> Vec<Light> {
    base.iter()
        .enumerate()
        .map(
            |(k, light)| match statuses.iter().find(|s| s.light as usize == k) {
                Some(s) => light_from_wire(light, &s.state),
                None => light.clone(),
            },
        )
        .collect()
}

/// `info` with its lights in the states `statuses` give them (PROTOCOL.md
/// §3: a `Welcome`'s `LightInfo.state` is the state the first lightmap it
/// sends was lit with). Statuses naming no light of `info` are ignored.
pub fn lit_info(info: &SceneInfo, statuses: &[LightStatus]) -> SceneInfo {
    let mut lit = info.clone();
    for s in statuses {
        if let Some(light) = lit.lights.get_mut(s.light as usize) {
            light.state = s.state;
        }
    }
    lit
}

/// Converts a scene pose to a wire pose.
pub fn to_wire(p: &Pose) -> WirePose {
    WirePose {
        translation: p.translation.to_array(),
        rotation: p.rotation.to_array(),
        scale: p.scale,
    }
}

/// Describes a scene for clients, its objects at their initial poses
/// (`bake::describe`, which `scene.glb` is written from too).
pub fn scene_info(scene: &Scene, atlas: &Atlas) -> SceneInfo {
    crate::bake::describe(scene, atlas, &scene.initial_poses())
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightwire_protocol::{DEFAULT_TILE_SIZE, ObjectInfo, PixelFormat};

    fn pose(scale: f32) -> WirePose {
        WirePose {
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale,
        }
    }

    /// A room (static) and a box (dynamic).
    fn info() -> SceneInfo {
        let object = |name: &str, dynamic| ObjectInfo {
            name: name.into(),
            dynamic,
            pose: pose(1.0),
        };
        SceneInfo {
            id: "room".into(),
            atlas_width: 1,
            atlas_height: 1,
            tile_size: DEFAULT_TILE_SIZE,
            format: PixelFormat::Rgb9e5,
            objects: vec![object("room", false), object("box", true)],
            materials: Vec::new(),
            surfaces: Vec::new(),
            lights: Vec::new(),
        }
    }

    #[test]
    fn a_transform_names_a_dynamic_object_before_its_pose_is_judged() {
        let info = info();
        assert_eq!(check_transform(&info, 1, &pose(1.0)), Ok(1));
        for object in [0, 2, u32::MAX] {
            let refused = check_transform(&info, object, &pose(-1.0));
            assert_eq!(refused.map_err(|r| r.0), Err(ErrorCode::UnknownObject));
        }
        let refused = check_transform(&info, 1, &pose(-1.0));
        assert_eq!(refused.map_err(|r| r.0), Err(ErrorCode::InvalidPose));
    }

    /// A light sent back as the scene described it is the scene's light
    /// to the bit; a state sets intensity, colour, on/off, position and
    /// direction and keeps the rest.
    #[test]
    fn a_light_sent_back_as_described_is_the_same_light() {
        let sun = Light {
            name: "sun".into(),
            kind: LightKind::Directional {
                direction: Vec3::new(0.25, -0.6, -0.76).normalize(),
                angular_radius: 0.0046,
            },
            position: Vec3::ZERO,
            intensity: Vec3::new(800.0, 760.0, 680.0),
            range: None,
            object: lightwire_scene::STATIC_OBJECT,
        };
        let described = crate::bake::light_info(&sun).state;
        assert_eq!(light_from_wire(&sun, &described), sun);
        let off = light_from_wire(
            &sun,
            &LightState {
                on: false,
                ..described
            },
        );
        assert_eq!(off.intensity, Vec3::ZERO);
        assert_eq!(off.kind, sun.kind);
        let turned = LightState {
            direction: [0.0, -2.0, 0.0],
            ..described
        };
        let LightKind::Directional { direction, .. } = light_from_wire(&sun, &turned).kind else {
            panic!("still a directional light")
        };
        assert_eq!(direction, Vec3::NEG_Y, "normalized");
    }

    /// A light riding with a dynamic object takes its state's on/off,
    /// colour and intensity from a `SetLight`, not its position or
    /// direction: it goes where its object goes.
    #[test]
    fn a_riding_light_keeps_its_place_whatever_a_set_light_says() {
        let lamp = Light {
            name: "lamp".into(),
            kind: LightKind::Spot {
                direction: Vec3::NEG_Y,
                inner: 0.1,
                outer: 0.4,
            },
            position: Vec3::new(1.0, 2.0, 3.0),
            intensity: Vec3::splat(4.0),
            range: None,
            object: 1,
        };
        let moved = LightState {
            position: [9.0, 9.0, 9.0],
            direction: [1.0, 0.0, 0.0],
            intensity: 2.0,
            color: [1.0, 0.5, 0.25],
            ..crate::bake::light_info(&lamp).state
        };
        let got = light_from_wire(&lamp, &moved);
        assert_eq!(got.position, lamp.position);
        assert_eq!(got.kind, lamp.kind);
        assert_eq!(got.object, 1);
        assert_eq!(got.intensity, Vec3::new(2.0, 1.0, 0.5));
    }

    /// A description whose lights only changed state is the same scene;
    /// one whose light moved kind, or whose geometry changed, is not. The
    /// states a publication lists replace the described ones.
    #[test]
    fn light_states_are_not_part_of_a_scene_s_description() {
        let lamp = crate::bake::light_info(&Light {
            name: "lamp".into(),
            kind: LightKind::Point,
            position: Vec3::new(0.0, 1.0, 0.0),
            intensity: Vec3::splat(4.0),
            range: None,
            object: lightwire_scene::STATIC_OBJECT,
        });
        let mut a = info();
        a.lights = vec![lamp.clone()];
        let off = LightState {
            on: false,
            ..lamp.state
        };
        let b = lit_info(
            &a,
            &[
                LightStatus {
                    light: 0,
                    seq: 3,
                    state: off,
                },
                LightStatus {
                    light: 7,
                    seq: 1,
                    state: off,
                },
            ],
        );
        assert_eq!(b.lights[0].state, off);
        assert_ne!(a, b);
        assert!(a.same_description(&b) && b.same_description(&a));
        let mut c = b.clone();
        c.lights[0].kind = lightwire_protocol::LightType::Spot;
        assert!(!a.same_description(&c));
        let mut d = b.clone();
        d.atlas_width = 2;
        assert!(!a.same_description(&d));
        let mut e = b;
        e.lights.clear();
        assert!(!a.same_description(&e));
    }

    #[test]
    fn a_version_echoes_only_the_seqs_that_moved_on() {
        let echoed = newly_reflected(&[0, 4, 7], &[0, 4, 5]);
        assert_eq!(echoed, vec![ObjectSeq { object: 2, seq: 7 }]);
        // After 2^64 - 1 comes 0: still news.
        let wrapped = newly_reflected(&[0, 4], &[u64::MAX, 4]);
        assert_eq!(wrapped, vec![ObjectSeq { object: 0, seq: 0 }]);
    }
}
