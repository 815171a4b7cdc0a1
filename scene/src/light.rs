//! Lights a scene brings besides its emitting surfaces (issue 59): point,
//! spot and directional lights as glTF's `KHR_lights_punctual` defines
//! them, in Lightwire's radiometric units, and a sky. A point or spot
//! light gives a surface the direct irradiance `E = I(ω) cos θ / d²` times
//! the range window; a directional light (the sun) `E_n cos θ` where its
//! disc is not hidden; the sky `∫ L(ω) cos θ dω` over the directions the
//! scene leaves open. The solvers compute it per element with visibility
//! and then treat it as reflected light to pass on
//! (`lightwire_solve::lights`).

use glam::Vec3;

/// What kind of punctual light, and its geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightKind {
    /// Radiates equally in every direction.
    Point,
    /// Radiates into a cone about `direction` (unit): full intensity within
    /// `inner` of it, none beyond `outer` (radians, `0 <= inner < outer <=
    /// π/2`), glTF's smooth falloff between.
    Spot {
        direction: Vec3,
        inner: f32,
        outer: f32,
    },
    /// Light arriving from a distant disc (the sun): travelling along
    /// `direction` (unit), from directions within `angular_radius`
    /// (radians; 0: a point, hard shadows) of `-direction`. Its
    /// `intensity` is the irradiance at normal incidence (W/m²) and its
    /// position is unused.
    Directional {
        direction: Vec3,
        angular_radius: f32,
    },
}

/// A point, spot or directional light, of the static world or riding
/// with a dynamic object.
#[derive(Debug, Clone, PartialEq)]
pub struct Light {
    pub name: String,
    pub kind: LightKind,
    /// Where the light is (world space, with its object at its initial
    /// pose).
    pub position: Vec3,
    /// Radiant intensity per channel on its axis, W/sr (a directional
    /// light's irradiance at normal incidence, W/m²): its colour times its
    /// intensity.
    pub intensity: Vec3,
    /// glTF's `range`: beyond it the light gives nothing, and it fades
    /// towards it by glTF's recommended window; `None`: no cut-off (the
    /// inverse square alone).
    pub range: Option<f32>,
    /// The object the light rides with ([`crate::STATIC_OBJECT`]: the
    /// static world): its position and direction are those above carried
    /// from the object's initial pose to its pose ([`Light::placed`]), a
    /// lamp on a moving box.
    pub object: u32,
}

impl Light {
    /// The light carried along with its object from the object's pose
    /// `from` to `to`: its position and a spot's or sun's direction move
    /// as the object's points and directions do (`to ∘ from⁻¹`).
    pub fn placed(&self, from: &crate::Pose, to: &crate::Pose) -> Light {
        let inverse = from.rotation.inverse();
        let point = |p: Vec3| {
            to.transform_point(inverse * (p - from.translation) / from.scale.max(f32::MIN_POSITIVE))
        };
        let turn = |d: Vec3| (to.rotation * (inverse * d)).normalize_or(d);
        let mut light = self.clone();
        light.position = point(self.position);
        match &mut light.kind {
            LightKind::Point => {}
            LightKind::Spot { direction, .. } | LightKind::Directional { direction, .. } => {
                *direction = turn(*direction);
            }
        }
        light
    }

    /// Radiant intensity (W/sr per channel) the light sends in the unit
    /// direction `towards` (from the light), at distance `distance`, with
    /// the range window folded in: what, divided by `distance²` and times
    /// the cosine at the receiver, is the irradiance there.
    pub fn intensity_towards(&self, towards: Vec3, distance: f32) -> Vec3 {
        let window = self.range.map_or(1.0, |range| {
            // KHR_lights_punctual's recommended smooth cut-off:
            // clamp(1 - (d / range)⁴, 0, 1)².
            let r = (distance / range).powi(4);
            (1.0 - r).clamp(0.0, 1.0).powi(2)
        });
        self.intensity * (self.cone(towards) * window)
    }

    /// The spot's angular falloff in the unit direction `towards` (1 for a
    /// point light): KHR_lights_punctual's, a smoothstep-like square of the
    /// cosine's linear ramp from the outer to the inner cone.
    pub fn cone(&self, towards: Vec3) -> f32 {
        match self.kind {
            LightKind::Point | LightKind::Directional { .. } => 1.0,
            LightKind::Spot {
                direction,
                inner,
                outer,
            } => {
                let (cos_inner, cos_outer) = (inner.cos(), outer.cos());
                let scale = 1.0 / (cos_inner - cos_outer).max(1e-3);
                let t = ((direction.dot(towards) - cos_outer) * scale).clamp(0.0, 1.0);
                t * t
            }
        }
    }
}

/// Radiance from every direction the scene leaves open (W/(m² sr) per
/// channel), `+y` up: `horizon + (zenith - horizon) cos θ` at `θ` from the
/// zenith above the horizon; below it an endless diffuse ground of albedo
/// `ground_albedo` (black by default: the ground is then the scene's own
/// geometry, or nothing), lit by this sky and the suns once
/// ([`Sky::with_ground`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sky {
    pub zenith: Vec3,
    pub horizon: Vec3,
    /// The albedo of the ground below the horizon, per channel in [0, 1).
    pub ground_albedo: Vec3,
    /// The radiance of that ground ([`Sky::with_ground`]).
    pub ground: Vec3,
}

impl Sky {
    /// A sky from zenith to horizon over a black ground.
    pub fn new(zenith: Vec3, horizon: Vec3) -> Sky {
        Sky {
            zenith,
            horizon,
            ground_albedo: Vec3::ZERO,
            ground: Vec3::ZERO,
        }
    }

    /// The irradiance this sky alone gives an open horizontal plane facing
    /// up: `∫ L cos θ dω` with `L = h + (z − h) cos θ` is `π h + (2π/3)
    /// (z − h)`.
    pub fn irradiance_up(&self) -> Vec3 {
        std::f32::consts::PI * (self.horizon / 3.0 + self.zenith * (2.0 / 3.0))
    }

    /// The same sky over a ground of `albedo`, lit by the sky
    /// ([`Self::irradiance_up`]) and by the directional lights among
    /// `lights` (`E cos` of each sun's elevation; point and spot lights are
    /// the scene's own, not the ground's): a Lambertian ground's radiance
    /// is `albedo × E / π`. One bounce: the ground's light does not return
    /// to the sky.
    pub fn with_ground(self, albedo: Vec3, lights: &[Light]) -> Sky {
        let suns: Vec3 = lights
            .iter()
            .filter_map(|l| match l.kind {
                LightKind::Directional { direction, .. } => {
                    Some(l.intensity * (-direction.y).max(0.0))
                }
                _ => None,
            })
            .sum();
        Sky {
            ground_albedo: albedo,
            ground: albedo * (self.irradiance_up() + suns) / std::f32::consts::PI,
            ..self
        }
    }

    /// The radiance arriving from the unit direction `from` (pointing
    /// away from the receiver, towards the sky).
    pub fn radiance(&self, from: Vec3) -> Vec3 {
        if from.y <= 0.0 {
            return self.ground;
        }
        self.horizon + (self.zenith - self.horizon) * from.y
    }

    /// Whether any channel is lit.
    pub fn is_lit(&self) -> bool {
        self.zenith.max_element() > 0.0 || self.horizon.max_element() > 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spot(inner_deg: f32, outer_deg: f32) -> Light {
        Light {
            name: "spot".into(),
            kind: LightKind::Spot {
                direction: Vec3::NEG_Y,
                inner: inner_deg.to_radians(),
                outer: outer_deg.to_radians(),
            },
            position: Vec3::ZERO,
            intensity: Vec3::splat(2.0),
            range: None,
            object: crate::STATIC_OBJECT,
        }
    }

    /// A lamp riding with its object keeps its place on it: carried from
    /// one pose to another, its position and direction move as the
    /// object's own points and directions do, and back again.
    #[test]
    fn a_light_placed_with_its_object_moves_as_the_object_does() {
        use crate::Pose;
        use glam::Quat;
        let from = Pose {
            translation: Vec3::new(1.0, 0.5, 2.0),
            rotation: Quat::from_rotation_y(0.3),
            scale: 1.0,
        };
        let to = Pose {
            translation: Vec3::new(-2.0, 1.0, 0.0),
            rotation: Quat::from_rotation_z(1.1) * Quat::from_rotation_y(-0.4),
            scale: 1.0,
        };
        let local = Vec3::new(0.2, 0.9, -0.1);
        let mut lamp = spot(10.0, 30.0);
        lamp.position = from.transform_point(local);
        let down = from.transform_normal(Vec3::NEG_Y);
        lamp.kind = LightKind::Spot {
            direction: down,
            inner: 0.1,
            outer: 0.5,
        };
        let there = lamp.placed(&from, &to);
        assert!(there.position.distance(to.transform_point(local)) < 1e-5);
        let LightKind::Spot { direction, .. } = there.kind else {
            panic!("still a spot");
        };
        assert!(direction.distance(to.transform_normal(Vec3::NEG_Y)) < 1e-5);
        let back = there.placed(&to, &from);
        assert!(back.position.distance(lamp.position) < 1e-5);
        assert_eq!(lamp.placed(&from, &from).intensity, lamp.intensity);
    }

    #[test]
    fn a_spot_is_full_inside_its_inner_cone_dark_outside_its_outer_and_smooth_between() {
        let s = spot(20.0, 40.0);
        let at = |deg: f32| {
            let a = deg.to_radians();
            s.cone(Vec3::new(a.sin(), -a.cos(), 0.0))
        };
        assert_eq!(at(0.0), 1.0);
        assert_eq!(at(19.9), 1.0);
        assert_eq!(at(40.1), 0.0);
        assert_eq!(at(90.0), 0.0);
        // glTF's falloff: the square of the cosine's ramp.
        let c = |deg: f32| deg.to_radians().cos();
        let t = (c(30.0) - c(40.0)) / (c(20.0) - c(40.0));
        assert!((at(30.0) - t * t).abs() < 1e-5, "{}", at(30.0));
        // Monotone between.
        let mut last = 1.0;
        for k in 0..=40 {
            let v = at(20.0 + k as f32 * 0.5);
            assert!(v <= last + 1e-6);
            last = v;
        }
    }

    #[test]
    fn the_sky_runs_from_horizon_to_zenith_and_is_black_below() {
        let sky = Sky::new(Vec3::splat(2.0), Vec3::splat(1.0));
        assert_eq!(sky.radiance(Vec3::Y), Vec3::splat(2.0));
        assert_eq!(
            sky.radiance(Vec3::new(1.0, 1.0, 0.0).normalize()).x,
            1.0 + 0.5f32.sqrt()
        );
        assert_eq!(
            sky.radiance(Vec3::new(1.0, -0.01, 0.0).normalize()),
            Vec3::ZERO
        );
    }

    #[test]
    fn a_ground_of_stated_albedo_reflects_the_sky_and_the_sun_below_the_horizon() {
        // Uniform sky L = 2: E = 2π; a sun of 800 W/m² at 30° elevation:
        // E = 400; ground albedo 0.25: L_g = 0.25 (2π + 400) / π.
        let sun = Light {
            name: "sun".into(),
            kind: LightKind::Directional {
                direction: Vec3::new(30f32.to_radians().cos(), -0.5, 0.0),
                angular_radius: 0.0,
            },
            position: Vec3::ZERO,
            intensity: Vec3::splat(800.0),
            range: None,
            object: crate::STATIC_OBJECT,
        };
        let sky = Sky::new(Vec3::splat(2.0), Vec3::splat(2.0));
        assert!((sky.irradiance_up().x - 2.0 * std::f32::consts::PI).abs() < 1e-5);
        let grounded = sky.with_ground(Vec3::splat(0.25), &[sun]);
        let want = 0.25 * (2.0 * std::f32::consts::PI + 400.0) / std::f32::consts::PI;
        assert!(
            (grounded.radiance(Vec3::NEG_Y).x - want).abs() < 1e-3,
            "{grounded:?}"
        );
        assert_eq!(
            grounded.radiance(Vec3::Y),
            Vec3::splat(2.0),
            "the sky above unchanged"
        );
        // A gradient sky's irradiance: π h + (2π/3)(z − h), against a sum
        // over the hemisphere (by rings of θ).
        let g = Sky::new(Vec3::splat(3.0), Vec3::splat(1.0));
        let n = 20_000;
        let sum: f32 = (0..n)
            .map(|k| {
                let t = (k as f32 + 0.5) / n as f32 * std::f32::consts::FRAC_PI_2;
                let from = Vec3::new(t.sin(), t.cos(), 0.0);
                g.radiance(from).x * t.cos() * t.sin() * 2.0 * std::f32::consts::PI
            })
            .sum::<f32>()
            * std::f32::consts::FRAC_PI_2
            / n as f32;
        assert!(
            (sum - g.irradiance_up().x).abs() < 1e-3 * sum,
            "{sum} vs {:?}",
            g.irradiance_up()
        );
    }

    #[test]
    fn the_range_window_is_gltfs_and_cuts_at_the_range() {
        let mut p = spot(20.0, 40.0);
        p.kind = LightKind::Point;
        p.range = Some(4.0);
        let i = |d: f32| p.intensity_towards(Vec3::X, d).x / 2.0;
        assert!((i(0.0) - 1.0).abs() < 1e-6);
        assert!((i(2.0) - (1.0f32 - 1.0 / 16.0).powi(2)).abs() < 1e-6);
        assert_eq!(i(4.0), 0.0);
        assert_eq!(i(5.0), 0.0);
    }
}
