//! Poses for the tests: the Cornell scenes' box turned about its vertical
//! axis, and the transform message that sends one.

use lightwire_protocol::{ClientMessage, Pose};

/// Where the box of the Cornell scenes (object 1) stands.
pub const CORNELL_BOX: [f32; 3] = [2.78, 0.85, 2.796];

/// The Cornell scenes' box in its place, turned by `angle` radians about
/// the vertical axis.
pub fn box_turned(angle: f32) -> Pose {
    Pose {
        translation: CORNELL_BOX,
        rotation: [0.0, (angle / 2.0).sin(), 0.0, (angle / 2.0).cos()],
        scale: 1.0,
    }
}

/// A transform of `object` to `pose` at `seq`, without a client time.
pub fn transform(object: u32, seq: u64, pose: Pose) -> ClientMessage {
    ClientMessage::Transform {
        object,
        seq,
        pose,
        client_time_us: 0,
    }
}

/// Checks that `got`, a pose the server sent back (in `Poses`), is `want`
/// as a client sent it: the same translation, the rotation within 1e-6 per
/// component (the server keeps it normalized).
pub fn assert_same_pose(got: &Pose, want: &Pose) {
    assert_eq!(got.translation, want.translation, "{got:?} vs {want:?}");
    for (g, w) in got.rotation.iter().zip(want.rotation) {
        assert!((g - w).abs() < 1e-6, "{got:?} vs {want:?}");
    }
}
