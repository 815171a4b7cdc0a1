//! Direct light from a scene's point, spot and directional lights and its
//! sky (issue 59), for the radiosity solvers: per element, the irradiance
//! each gives its sample point, with shadow rays. The solvers then treat
//! `ρ D` as light the element sends on, unshot, so every bounce after the
//! first is the radiosity solution's (the reference solver adds it to the
//! source term, the ray solver to its direct irradiance, taking the sky
//! from its own kept rays). The path tracer computes the same irradiance
//! on its own (`pathtrace`), so that it stays an independent oracle.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::raycast::{CosineGrid, Raycaster};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Light, LightKind, Pose, Scene};

/// Shadow rays per side of the stratified grid on a directional light's
/// disc (when it has one): 16 directions, so a soft sun's penumbra is
/// resolved to 1/16 of the disc.
pub const SUN_SIDE: usize = 4;

/// Cosine rays per side for the reference solver's sky
/// ([`sky_irradiance_at`]): 1,024 per element.
pub const SKY_SIDE: usize = 32;

/// The irradiance (W/m² per channel) the point, spot and directional
/// lights of `scene` give the point `x` (already off its surface) with unit
/// normal `n`, where `caster` does not hide them: `Σ I(ω) cos θ / d²` over
/// point and spot lights (hard shadows: a light is a point), and
/// `E_n cos θ` times the visible share of its disc ([`SUN_SIDE`]² shadow
/// rays to infinity, one for a disc of no size) over directional ones. Not
/// the sky ([`sky_irradiance_at`]).
pub fn irradiance_at(scene: &Scene, caster: &Raycaster, (x, n): (DVec3, DVec3)) -> Vec3 {
    lights_irradiance(&scene.lights, (x, n), |d, max| !caster.occluded(x, d, max))
}

/// [`irradiance_at`] with `open(direction, distance)` saying whether a
/// shadow ray from `x` reaches its light.
fn lights_irradiance(
    lights: &[Light],
    at: (DVec3, DVec3),
    open: impl FnMut(DVec3, f64) -> bool,
) -> Vec3 {
    lights_seen(lights, at, open, &mut Vec::new())
}

/// [`lights_irradiance`], with how many of each light's shadow rays are
/// open in `seen` (cleared first; 0 for a light that faces away): what a
/// shadow edge changes.
fn lights_seen(
    lights: &[Light],
    (x, n): (DVec3, DVec3),
    mut open: impl FnMut(DVec3, f64) -> bool,
    seen: &mut Vec<u32>,
) -> Vec3 {
    seen.clear();
    let mut e = Vec3::ZERO;
    for light in lights {
        seen.push(0);
        if let LightKind::Directional {
            direction,
            angular_radius,
        } = light.kind
        {
            let to_sun = -direction.as_dvec3();
            let cos = n.dot(to_sun);
            if cos <= 0.0 {
                continue;
            }
            let directions = disc_directions(to_sun, f64::from(angular_radius));
            let count = directions
                .iter()
                .filter(|&&d| n.dot(d) > 0.0 && open(d, f64::INFINITY))
                .count();
            if let Some(last) = seen.last_mut() {
                *last = count as u32;
            }
            e += light.intensity * (cos * count as f64 / directions.len() as f64) as f32;
            continue;
        }
        let d = light.position.as_dvec3() - x;
        let r = d.length();
        if r <= 0.0 {
            continue;
        }
        let dir = d / r;
        let cos = n.dot(dir);
        if cos <= 0.0 {
            continue;
        }
        // Outside a spot's cone or past the range: no shadow ray, and
        // seen as open (the cone's and the range's falloff are smooth, no
        // shadow edge).
        let i = light.intensity_towards(-dir.as_vec3(), r as f32);
        if i == Vec3::ZERO {
            if let Some(last) = seen.last_mut() {
                *last = 1;
            }
            continue;
        }
        if !open(dir, r * (1.0 - 1e-9)) {
            continue;
        }
        if let Some(last) = seen.last_mut() {
            *last = 1;
        }
        e += i * (cos / (r * r)) as f32;
    }
    e
}

/// Sub-samples per side of a texel that a shadow edge crosses
/// ([`texel_irradiance`]): 64 points, so the share of the texel in light
/// is resolved to 1/16 of its width across an edge (a 4 x 4 grid read a
/// texel whose edge fell between its rows 20% too bright).
pub const EDGE_SIDE: usize = 8;

/// Element `i`'s texel on its placed patch: its region's frame and bounds,
/// for sub-samples lifted `lift` off the surface along `n`.
struct Texel {
    origin: DVec3,
    u: DVec3,
    v: DVec3,
    /// `[s0, t0, s1, t1]` in patch parameters.
    region: [f64; 4],
    triangle: bool,
    offset: DVec3,
}

impl Texel {
    /// None for a texel without a rectangular region in its patch (a
    /// mesh's own lightmap UVs, a texel above a triangle's diagonal).
    fn of(
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        (i, n, lift): (usize, DVec3, f64),
    ) -> Option<Self> {
        let e = &atlas.elements[i];
        if !e.covers_surface() || atlas.lightmap_region(i).is_some() {
            return None;
        }
        let placed = scene.patches[e.patch as usize]
            .shape
            .transformed(&poses[e.object as usize]);
        let (o, u, v) = placed.frame();
        Some(Self {
            origin: o.as_dvec3(),
            u: u.as_dvec3(),
            v: v.as_dvec3(),
            region: e.region.map(f64::from),
            triangle: placed.is_triangle(),
            offset: n * lift,
        })
    }

    /// The centre of cell `(a, b)` of the [`EDGE_SIDE`]² grid over the
    /// region, lifted; none above a triangle's diagonal.
    fn cell(&self, a: usize, b: usize) -> Option<DVec3> {
        let [s0, t0, s1, t1] = self.region;
        let side = EDGE_SIDE as f64;
        let s = s0 + (s1 - s0) * (a as f64 + 0.5) / side;
        let t = t0 + (t1 - t0) * (b as f64 + 0.5) / side;
        (!self.triangle || t <= s).then(|| self.origin + self.u * s + self.v * t + self.offset)
    }

    /// The four corner cells (those on the surface).
    fn corners(&self) -> impl Iterator<Item = DVec3> + '_ {
        let last = EDGE_SIDE - 1;
        [(0, 0), (last, 0), (0, last), (last, last)]
            .into_iter()
            .filter_map(|(a, b)| self.cell(a, b))
    }

    /// Every cell (those on the surface).
    fn cells(&self) -> impl Iterator<Item = DVec3> + '_ {
        (0..EDGE_SIDE).flat_map(move |b| (0..EDGE_SIDE).filter_map(move |a| self.cell(a, b)))
    }

    /// How far from `x` any point of the region lies, lift included.
    fn reach(&self, x: DVec3) -> f64 {
        let [s0, t0, s1, t1] = self.region;
        [(s0, t0), (s1, t0), (s0, t1), (s1, t1)]
            .iter()
            .map(|&(s, t)| (self.origin + self.u * s + self.v * t).distance(x))
            .fold(0.0, f64::max)
            + self.offset.length()
    }
}

/// The irradiance the point, spot and directional lights (not the sky)
/// `lights` give element `i`, with `open(x, direction, distance)` saying
/// whether a shadow ray from `x` reaches its light, light by light: at
/// the element's sample `at` where the four corner sub-samples of its
/// texel ([`EDGE_SIDE`]² cells) see the light's shadow rays open as the
/// sample does (its shadow edge does not cross the texel), and otherwise
/// the mean over all its sub-samples, the texel's area average (Coombe
/// §39.3 refines where the light changes; Wallner's shadow-boundary test,
/// here as "do the corners see the light alike"). A texel half in a hard
/// shadow holds half the light instead of all or nothing, so the edge
/// reads as a ramp a texel wide rather than a staircase. Light by light,
/// so that the whole is the sum of what each light gives alone: a change
/// of one light changes the direct light by exactly that light's part
/// ([`light_change`], issue 60).
fn texel_lights(
    (scene, lights): (&Scene, &[Light]),
    (atlas, poses): (&Atlas, &[Pose]),
    (i, at, lift): (usize, (DVec3, DVec3), f64),
    (open, caster): (impl Fn(DVec3, DVec3, f64) -> bool, &Raycaster),
) -> Vec3 {
    let (x, n) = at;
    let texel = Texel::of(scene, atlas, poses, (i, n, lift));
    // Sub-samples inside geometry (under a block resting on the floor:
    // straight up they meet a face from behind) are no surface anyone
    // sees; the texel's average is over the rest (the invalid-texel rule,
    // `crate::validity`, within a texel). Found once, for the first light
    // whose edge crosses the texel.
    let mut cells: Option<Vec<DVec3>> = None;
    let (mut seen, mut probe) = (Vec::new(), Vec::new());
    let mut total = Vec3::ZERO;
    for light in lights {
        let one = std::slice::from_ref(light);
        let centre = lights_seen(one, at, |d, max| open(x, d, max), &mut seen);
        let Some(texel) = &texel else {
            total += centre;
            continue;
        };
        let edge = texel.corners().any(|p| {
            lights_seen(one, (p, n), |d, max| open(p, d, max), &mut probe);
            probe != seen
        });
        if !edge {
            total += centre;
            continue;
        }
        let cells = cells.get_or_insert_with(|| {
            texel
                .cells()
                .filter(|&p| {
                    caster
                        .closest_hit(p, n, f64::INFINITY)
                        .is_none_or(|hit| hit.front)
                })
                .collect()
        });
        if cells.is_empty() {
            total += centre;
            continue;
        }
        let sum: Vec3 = cells
            .iter()
            .map(|&p| lights_irradiance(one, (p, n), |d, max| open(p, d, max)))
            .sum();
        total += sum / cells.len() as f32;
    }
    total
}

/// [`texel_lights`] against `caster`: the point, spot and directional
/// lights' irradiance of element `i` whose sample point is `at` (off its
/// surface, `crate::raycast::sample_point`), its texel's area average
/// where a shadow edge crosses it.
pub fn texel_irradiance(
    scene: &Scene,
    caster: &Raycaster,
    (atlas, poses): (&Atlas, &[Pose]),
    i: usize,
    at: (DVec3, DVec3),
) -> Vec3 {
    if scene.lights.is_empty() {
        return Vec3::ZERO;
    }
    texel_lights(
        (scene, &scene.lights),
        (atlas, poses),
        (i, at, lift(caster)),
        (|x, d, max| !caster.occluded(x, d, max), caster),
    )
}

/// How element `i`'s direct irradiance (its sample point `at`, shadow rays
/// against `caster`) changes when the light `old` becomes `new`, nothing
/// else changing: `D_new − D_old` of that light alone, which is the change
/// of the whole because a texel's direct light is the sum of what each
/// light gives it ([`texel_lights`]). Zero where neither reaches it.
pub fn light_change(
    scene: &Scene,
    caster: &Raycaster,
    (atlas, poses): (&Atlas, &[Pose]),
    (i, at): (usize, (DVec3, DVec3)),
    (old, new): (&Light, &Light),
) -> Vec3 {
    let one = |light: &Light| {
        texel_lights(
            (scene, std::slice::from_ref(light)),
            (atlas, poses),
            (i, at, lift(caster)),
            (|x, d, max| !caster.occluded(x, d, max), caster),
        )
    };
    one(new) - one(old)
}

/// How far sub-samples are lifted off their surface: as the sample point
/// is (`crate::raycast::sample_point`).
fn lift(caster: &Raycaster) -> f64 {
    1e-5 * caster.extent()
}

/// Element `i`'s direct irradiance from the lights ([`texel_irradiance`])
/// and the sky ([`sky_irradiance_at`] at its sample point `at`).
pub fn element_direct_at(
    scene: &Scene,
    caster: &Raycaster,
    (atlas, poses): (&Atlas, &[Pose]),
    (i, at): (usize, (DVec3, DVec3)),
    sky: &CosineGrid,
) -> Vec3 {
    texel_irradiance(scene, caster, (atlas, poses), i, at)
        + sky_irradiance_at(scene, caster, at, sky)
}

/// How element `i`'s direct irradiance from the lights and the sky
/// ([`element_direct_at`], its sample point `at`) changes when the scene
/// placed as `old` becomes the scene placed as `new` (at `poses`, which
/// place element `i` alike in both), where all that moved lies in `boxes`
/// (world bounds, `(min, max)`, of the moved objects before and after):
/// `D_new − D_old`. Only elements whose shadow rays (from the sample or
/// any point of its texel) may pass through a box cast again, against
/// both; any other gets exactly zero, so a far texel is not touched by a
/// move.
pub fn irradiance_change(
    scene: &Scene,
    (old, new): (&Raycaster, &Raycaster),
    (atlas, poses): (&Atlas, &[Pose]),
    (i, at): (usize, (DVec3, DVec3)),
    (boxes, sky): (&[(DVec3, DVec3)], &CosineGrid),
) -> Vec3 {
    let (x, n) = at;
    let crosses = |p: DVec3, d: DVec3, max: f64| boxes.iter().any(|b| ray_meets_box(p, d, max, b));
    let mut change = Vec3::ZERO;
    if !scene.lights.is_empty() {
        let lift = lift(new);
        // One test per light from the sample against the boxes grown by
        // the texel's reach: every sub-sample's shadow ray to a light
        // stays within that reach of the sample's (a point light's
        // segments share their end; a sun's rays are parallel), so a miss
        // here is a miss for all of them.
        let reach = Texel::of(scene, atlas, poses, (i, n, lift)).map_or(lift, |t| t.reach(x));
        let grown: Vec<(DVec3, DVec3)> = boxes
            .iter()
            .map(|(lo, hi)| (*lo - reach, *hi + reach))
            .collect();
        let met = scene.lights.iter().any(|light| match light.kind {
            LightKind::Directional {
                direction,
                angular_radius,
            } => disc_directions(-direction.as_dvec3(), f64::from(angular_radius))
                .iter()
                .any(|&d| grown.iter().any(|b| ray_meets_box(x, d, f64::INFINITY, b))),
            _ => {
                let d = light.position.as_dvec3() - x;
                let r = d.length();
                r > 0.0 && grown.iter().any(|b| ray_meets_box(x, d / r, r + reach, b))
            }
        });
        if met {
            // A ray through no box meets the same in both: cast it
            // against `new` for both, so that each side is the element's
            // whole direct light, sub-samples chosen as they would be.
            let before = texel_lights(
                (scene, &scene.lights),
                (atlas, poses),
                (i, at, lift),
                (
                    |p, d, max| {
                        if crosses(p, d, max) {
                            !old.occluded(p, d, max)
                        } else {
                            !new.occluded(p, d, max)
                        }
                    },
                    old,
                ),
            );
            let after = texel_lights(
                (scene, &scene.lights),
                (atlas, poses),
                (i, at, lift),
                (|p, d, max| !new.occluded(p, d, max), new),
            );
            change += after - before;
        }
    }
    if let Some(lit) = &scene.sky {
        let mut sum = Vec3::ZERO;
        for d in sky.around(n) {
            if !crosses(x, d, f64::INFINITY) {
                continue;
            }
            match (
                old.occluded(x, d, f64::INFINITY),
                new.occluded(x, d, f64::INFINITY),
            ) {
                (true, false) => sum += lit.radiance(d.as_vec3()),
                (false, true) => sum -= lit.radiance(d.as_vec3()),
                _ => {}
            }
        }
        change += sum * (std::f32::consts::PI / sky.len().max(1) as f32);
    }
    change
}

/// Whether the ray `x + t d`, `0 < t < max`, meets the box `(lo, hi)`
/// (slabs).
fn ray_meets_box(x: DVec3, d: DVec3, max: f64, (lo, hi): &(DVec3, DVec3)) -> bool {
    let (mut near, mut far) = (0.0f64, max);
    for axis in 0..3 {
        let (o, v) = (x[axis], d[axis]);
        if v.abs() < 1e-300 {
            if o < lo[axis] || o > hi[axis] {
                return false;
            }
            continue;
        }
        let (a, b) = ((lo[axis] - o) / v, (hi[axis] - o) / v);
        near = near.max(a.min(b));
        far = far.min(a.max(b));
        if near > far {
            return false;
        }
    }
    true
}

/// Directions towards a disc of angular radius `radius` about the unit
/// direction `centre`: [`SUN_SIDE`]² stratified over the disc (uniform in
/// its area: radius `√u`), or `centre` alone for a disc of no size.
pub fn disc_directions(centre: DVec3, radius: f64) -> Vec<DVec3> {
    if radius <= 0.0 {
        return vec![centre];
    }
    let t1 = centre.any_orthonormal_vector();
    let t2 = centre.cross(t1);
    let side = SUN_SIDE as f64;
    let spread = radius.tan();
    (0..SUN_SIDE * SUN_SIDE)
        .map(|k| {
            let (j, i) = ((k / SUN_SIDE) as f64, (k % SUN_SIDE) as f64);
            let r = ((j + 0.5) / side).sqrt() * spread;
            let phi = std::f64::consts::TAU * (i + 0.5) / side;
            (centre + (t1 * phi.cos() + t2 * phi.sin()) * r).normalize()
        })
        .collect()
}

/// The sky's irradiance at `x` (off its surface) with unit normal `n`:
/// `π` times the mean sky radiance over `directions` (cosine-distributed
/// about `n`) that leave the scene (any face of any patch blocks). Zero
/// without a sky.
pub fn sky_irradiance_at(
    scene: &Scene,
    caster: &Raycaster,
    (x, n): (DVec3, DVec3),
    directions: &CosineGrid,
) -> Vec3 {
    let Some(sky) = &scene.sky else {
        return Vec3::ZERO;
    };
    let sum: Vec3 = directions
        .around(n)
        .filter(|&d| !caster.occluded(x, d, f64::INFINITY))
        .map(|d| sky.radiance(d.as_vec3()))
        .sum();
    sum * (std::f32::consts::PI / directions.len().max(1) as f32)
}

/// The irradiance `D + D_sky` the lights and the sky give each of
/// `elements` ([`element_direct_at`] at the element's sample point,
/// `crate::raycast::sample_point`), against the scene at `poses` without
/// the objects flagged in `absent`, in parallel; zeros for a scene without
/// lights. The GPU solvers take `ρ` times it as reflected light the
/// elements start with (the progressive solver's radiosity and unshot
/// radiosity, the gather solver's direct irradiance), while their emission
/// stays the materials'.
pub fn element_irradiance(
    scene: &Scene,
    atlas: &Atlas,
    (poses, absent): (&[Pose], &[bool]),
    elements: &[usize],
) -> Vec<Vec3> {
    if !any(scene) {
        return vec![Vec3::ZERO; elements.len()];
    }
    let caster = Raycaster::with_absent(scene, poses, absent);
    let sky = CosineGrid::new(SKY_SIDE);
    elements
        .par_iter()
        .map(|&i| {
            let at = crate::raycast::sample_point(scene, &caster, atlas, poses, i);
            element_direct_at(scene, &caster, (atlas, poses), (i, at), &sky)
        })
        .collect()
}

/// `Σ A ρ D` over the elements of `atlas`: the power the lights' direct
/// light `irradiance` ([`element_irradiance`], one per element) puts into
/// the scene as reflected light, with `areas` the elements' world areas.
/// The solvers count it with the emitted power in their convergence
/// measures.
pub fn reflected_power(atlas: &Atlas, irradiance: &[Vec3], areas: &[f32]) -> f64 {
    atlas
        .elements
        .iter()
        .zip(irradiance)
        .zip(areas)
        .map(|((e, d), a)| f64::from(*a) * f64::from((e.albedo * *d).element_sum()))
        .sum()
}

/// The power the lights' direct light `irradiance` ([`element_irradiance`],
/// one per element) delivers onto the elements of `atlas`, `Σ A D`, and
/// what they absorb of it at once, `Σ A (1 − ρ) D`, with `areas` the
/// elements' world areas (W, channels summed). Every solver reports the
/// first with the emitted power (`stats.json`): a sun's or a sky's power
/// is the part that falls on the scene.
pub fn delivered_power(atlas: &Atlas, irradiance: &[Vec3], areas: &[f32]) -> (f64, f64) {
    atlas
        .elements
        .iter()
        .zip(irradiance)
        .zip(areas)
        .map(|((e, d), a)| {
            let a = f64::from(*a);
            (
                a * f64::from(d.element_sum()),
                a * f64::from(((Vec3::ONE - e.albedo) * *d).element_sum()),
            )
        })
        .fold((0.0, 0.0), |(x, y), (p, q)| (x + p, y + q))
}

/// Whether `scene` has lights or a sky that these functions light.
pub fn any(scene: &Scene) -> bool {
    !scene.lights.is_empty() || scene.sky.is_some()
}
