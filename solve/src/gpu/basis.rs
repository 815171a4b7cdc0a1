//! Each light's light, kept apart (issue 60 item 2): a change of a light's
//! intensity, colour or on/off that does not move it is then exact at once.
//!
//! Radiosity is linear in what the sources send, channel by channel: the
//! solution is the light of the emitting surfaces and the sky, `B_rest`,
//! plus for every light `k` its intensity (per channel) times `U_k`, the
//! solution of the scene lit by that light alone at unit white intensity,
//! every bounce included. A [`Basis`] holds `B_rest` and every `U_k`; the
//! state for any intensities is [`Basis::compose`], and a switch, a dim
//! or a recolour is one composition, the same arithmetic a fresh session
//! with the new intensities does, so the two agree to rounding.
//!
//! Each group's solution ([`groups`]) is a session of its own
//! (`DynamicSolver`, the same options, no basis of its own; its
//! `Building` runs them) run to its corrected state at the
//! current poses: `1 + lights` solves, built one after the other in the
//! background once the session is idle (after the first published state,
//! which does not wait for it). Memory: `(1 + lights) × elements × 12`
//! bytes on the CPU (cornell-point at the file's density: 2 × 2,939 × 12 =
//! 70 KB). A basis holds for the poses and the light positions and
//! directions it was built at: a move of an object or of a light makes
//! the session follow by shooting the change (thesis §2.2.5,
//! `ProgressiveSolver::set_light`) and build the basis again when the
//! scene holds still. [`wanted`] says when a basis is worth its solves.

use glam::Vec3;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Light, Scene};

/// The solutions a state is composed of; see the module doc.
#[derive(Debug, Clone)]
pub struct Basis {
    /// The emitting surfaces' and the sky's light.
    rest: Vec<Vec3>,
    /// Per light, its light at unit white intensity.
    unit: Vec<Vec<Vec3>>,
    /// The lights as they were when the basis was built: a light whose
    /// kind, position or range differs from these is not in the basis.
    built_for: Vec<Light>,
}

impl Basis {
    /// The basis of the solutions `rest` (the emitters' and the sky's)
    /// and `unit` (each light's at unit white intensity), built for
    /// `built_for`.
    pub fn new(rest: Vec<Vec3>, unit: Vec<Vec<Vec3>>, built_for: Vec<Light>) -> Self {
        Self {
            rest,
            unit,
            built_for,
        }
    }

    /// The state of the scene lit by `lights` (the basis's lights, each
    /// with any intensity): `rest + Σ_k I_k ⊙ unit_k`, in light order.
    pub fn compose(&self, lights: &[Light]) -> Vec<Vec3> {
        let mut b = self.rest.clone();
        for (light, unit) in lights.iter().zip(&self.unit) {
            if light.intensity == Vec3::ZERO {
                continue;
            }
            for (b, u) in b.iter_mut().zip(unit) {
                *b += light.intensity * *u;
            }
        }
        b
    }

    /// Whether `lights` differ from the lights the basis was built for in
    /// their intensities only (what [`Basis::compose`] can follow).
    pub fn covers(&self, lights: &[Light]) -> bool {
        lights.len() == self.built_for.len()
            && lights
                .iter()
                .zip(&self.built_for)
                .all(|(l, b)| l.kind == b.kind && l.position == b.position && l.range == b.range)
    }

    /// Bytes the basis holds.
    pub fn bytes(&self) -> usize {
        (1 + self.unit.len()) * self.rest.len() * std::mem::size_of::<Vec3>()
    }
}

/// Whether a session of `scene` on `atlas` keeps a basis: it has lights
/// to change, and `(1 + lights) × elements` is within `limit` (0: never).
pub fn wanted(scene: &Scene, atlas: &Atlas, limit: usize) -> bool {
    !scene.lights.is_empty()
        && (1 + scene.lights.len()).saturating_mul(atlas.elements.len()) <= limit
}

/// The scene of each group: the emitting surfaces and the sky without the
/// lights, then each light alone, at unit white intensity, with nothing
/// emitting. `None` for a group that gives no light (its solution is 0).
pub fn groups(scene: &Scene) -> Vec<Option<Scene>> {
    let mut rest = scene.clone();
    rest.lights.clear();
    let rest_lit = rest.materials.iter().any(|m| m.emission != Vec3::ZERO)
        || rest
            .sky
            .as_ref()
            .is_some_and(|s| s.zenith != Vec3::ZERO || s.horizon != Vec3::ZERO);
    let mut dark = scene.clone();
    for m in &mut dark.materials {
        m.emission = Vec3::ZERO;
    }
    dark.sky = None;
    let mut groups = vec![rest_lit.then_some(rest)];
    for light in &scene.lights {
        let mut alone = dark.clone();
        alone.lights = vec![Light {
            intensity: Vec3::ONE,
            ..light.clone()
        }];
        groups.push(Some(alone));
    }
    groups
}
