//! Direct light at a point by next-event estimation towards the emitting
//! patches, on the CPU, for the GPU solvers.
//!
//! A hemicube sees a small light as a handful of pixels, so the light it
//! gathers from it jumps by a pixel's form factor as the receiver moves:
//! the gather solver at 32² pixels was 29% off the reference on
//! cornell-small's direct light (a 0.1 m² lamp over a 5.5 m room) while
//! its surface means were right to 0.5%. Integrating the emitters instead
//! over a stratified grid of points on each emitting patch, with a shadow
//! ray to each (the point-to-area form factor `cos θ_x cos θ_y / (π r²)`
//! per sample, thesis §2.2.1, eq. 2.2.2 without the area average), removes
//! that aliasing; the hemicube then carries only the reflected light.
//! Emitters may be parallelograms or triangles (wallner §2's meshes): the
//! exact form factor takes the patch's own polygon, and the sample grid is
//! folded onto a triangle ([`grid_points`]).
//!
//! Users: the gather solver (`gpu/gather.rs`: the direct light of the
//! emission, once per solve) and cross redistribution's regathering
//! (`gpu/progressive/regather.rs`: the emitters' current radiosity near a
//! moved object). The path tracer keeps its own sampling, so that the
//! oracle shares no code with the solvers it checks.

use std::collections::HashMap;

use glam::{DVec3, Vec3};

use rayon::prelude::*;

use crate::raycast::{CosineGrid, Hit, Raycaster, WorldPatch, sample_point};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

/// Samples per emitting patch for the solvers' direct light, `GRID`².
pub const GRID: usize = 16;

/// The irradiance from the emitters' emission at each receiving point
/// `(x, n)` (world space, unit normal), against the scene at `poses`
/// ([`Emitters::irradiance`] with [`GRID`]² samples per emitting patch),
/// in parallel.
pub fn direct_light(
    scene: &Scene,
    atlas: &Atlas,
    poses: &[Pose],
    receivers: &[(DVec3, DVec3)],
) -> Vec<Vec3> {
    let caster = Raycaster::new(scene, poses);
    let emitters = Emitters::of(scene);
    receivers
        .par_iter()
        .map(|&(x, n)| {
            emitters.irradiance(&caster, atlas, x, n, GRID, |j| atlas.elements[j].emission)
        })
        .collect()
}

/// The emitting patches of a scene.
#[derive(Debug, Clone)]
pub struct Emitters {
    emits: Vec<bool>,
    patches: Vec<u32>,
}

impl Emitters {
    /// The patches whose material emits in any channel.
    pub fn of(scene: &Scene) -> Self {
        let emits: Vec<bool> = scene
            .patches
            .iter()
            .map(|p| scene.materials[p.material as usize].emission.max_element() > 0.0)
            .collect();
        let patches = (0..emits.len() as u32)
            .filter(|&p| emits[p as usize])
            .collect();
        Self { emits, patches }
    }

    /// Whether patch `p` emits.
    pub fn contains(&self, p: u32) -> bool {
        self.emits.get(p as usize).copied().unwrap_or(false)
    }

    /// Irradiance `H` at the point `x` with unit normal `n` from every
    /// emitting patch, `value(j)` being the radiosity leaving element `j`
    /// (looked up as the element of the emitting patch nearest to a
    /// sample). `caster` must hold the scene's patches at the poses `x`
    /// lives in.
    ///
    /// Per patch, the unoccluded point-to-polygon form factor `F` is exact
    /// (Lambert's contour integral over the part of the patch above `x`'s
    /// tangent plane, thesis §2.2.2; the triangle's three corners for a
    /// triangle, wallner §2's meshes), and a `grid` x `grid` stratification
    /// of the patch ([`sample_points`]), a shadow ray to a point at random
    /// in each cell, the same points for the same `x` (anything but the
    /// patch itself blocks), gives the visible,
    /// radiosity-weighted share of it: `H += F Σ_k w_k V_k value_k /
    /// Σ_k w_k` with the point-to-area kernel `w_k = a_k cos θ_x cos θ_y /
    /// r²`, `a_k` the share of the patch's area the cell stands for.
    /// Sampling the kernel alone misses most of a neighbouring wall's form
    /// factor at an edge, where
    /// it grows without bound (the furnace's edge texels lost a fifth of
    /// their direct light at 16²).
    pub fn irradiance(
        &self,
        caster: &Raycaster,
        atlas: &Atlas,
        x: DVec3,
        n: DVec3,
        grid: usize,
        value: impl Fn(usize) -> Vec3,
    ) -> Vec3 {
        let seed = receiver_seed(x);
        let mut h = Vec3::ZERO;
        for &p in &self.patches {
            let Some((wp, f)) = self.facing(caster, p, x, n) else {
                continue;
            };
            h += seen_share(caster, atlas, (p, wp, f), (x, n), (grid, seed), &value);
        }
        h
    }

    /// [`Emitters::irradiance`] with about `budget` shadow rays in all
    /// instead of `grid`² per emitting patch: each patch gets a share of
    /// the budget in proportion to what it would give unoccluded (its
    /// form factor times its emission), as a square grid of at most
    /// `grid`² and at least one point. A level lit by 32 lamps would
    /// otherwise cast 32 x 256 shadow rays per texel for lamps most of
    /// which it barely sees; each patch's visible share is still
    /// estimated without bias (exact form factor, stratified points), only
    /// with more noise where it matters less.
    pub fn irradiance_within(
        &self,
        caster: &Raycaster,
        atlas: &Atlas,
        (x, n): (DVec3, DVec3),
        (grid, budget): (usize, usize),
        value: impl Fn(usize) -> Vec3,
    ) -> Vec3 {
        let seed = receiver_seed(x);
        let facing: Vec<(u32, &WorldPatch, f64, f64)> = self
            .patches
            .iter()
            .filter_map(|&p| {
                let (wp, f) = self.facing(caster, p, x, n)?;
                let power = f64::from(self.emission(atlas, p).element_sum()) * f;
                Some((p, wp, f, power))
            })
            .collect();
        let total: f64 = facing.iter().map(|e| e.3).sum();
        let mut h = Vec3::ZERO;
        for (p, wp, f, power) in facing {
            let share = if total > 0.0 { power / total } else { 1.0 };
            let side = ((share * budget as f64).sqrt().round() as usize).clamp(1, grid.max(1));
            h += seen_share(caster, atlas, (p, wp, f), (x, n), (side, seed), &value);
        }
        h
    }

    /// Patch `p` placed as `caster` holds it and its unoccluded form factor
    /// from `(x, n)`, if it has area and faces the point.
    fn facing<'c>(
        &self,
        caster: &'c Raycaster,
        p: u32,
        x: DVec3,
        n: DVec3,
    ) -> Option<(&'c WorldPatch, f64)> {
        let wp = caster.patches().get(p as usize)?;
        if wp.area.is_nan() || wp.area <= 0.0 {
            // An absent object's patch (`Raycaster::with_absent`).
            return None;
        }
        let f = form_factor(x, n, wp.corners());
        (f > 0.0).then_some((wp, f))
    }

    /// The emission of the first element of patch `p` (its material's).
    fn emission(&self, atlas: &Atlas, p: u32) -> Vec3 {
        atlas
            .elements
            .get(atlas.elements_of(p).start)
            .map_or(Vec3::ZERO, |e| e.emission)
    }
}

/// The same points for the same receiver, whatever ran before.
fn receiver_seed(x: DVec3) -> u64 {
    x.x.to_bits() ^ x.y.to_bits().rotate_left(21) ^ x.z.to_bits().rotate_left(42)
}

/// What emitting patch `p` (placed as `wp`, unoccluded form factor `f`
/// from `(x, n)`) gives the point: `F Σ_k w_k V_k value_k / Σ_k w_k` over
/// a `grid` x `grid` stratification of the patch seeded with `seed` (see
/// [`Emitters::irradiance`]).
fn seen_share(
    caster: &Raycaster,
    atlas: &Atlas,
    (p, wp, f): (u32, &WorldPatch, f64),
    (x, n): (DVec3, DVec3),
    (grid, seed): (usize, u64),
    value: &impl Fn(usize) -> Vec3,
) -> Vec3 {
    let (mut seen, mut total) = (Vec3::ZERO, 0.0f64);
    for (y, share) in sample_points(wp, grid, Some(seed)) {
        let to = y - x;
        let r2 = to.length_squared();
        if r2 <= 0.0 {
            continue;
        }
        let r = r2.sqrt();
        let dir = to / r;
        let (cos_x, cos_y) = (n.dot(dir), -wp.normal.dot(dir));
        if cos_x <= 0.0 || cos_y <= 0.0 {
            continue;
        }
        let w = share * cos_x * cos_y / r2;
        total += w;
        if caster.occluded_except(x, dir, r * (1.0 - 1e-6), p) {
            continue;
        }
        if let Some(j) = element_at(caster, atlas, p, y) {
            seen += value(j) * w as f32;
        }
    }
    if total > 0.0 {
        seen * (f / total) as f32
    } else {
        Vec3::ZERO
    }
}

/// The form factor from a differential area at `x` with unit normal `n` to
/// the planar polygon `corners`, ignoring occlusion: Lambert's formula
/// `F = (1 / 2π) Σ_k γ_k (n · ĉ_k)` over the edges of the polygon clipped
/// to `x`'s upper half-space, `γ_k` the angle an edge subtends at `x` and
/// `ĉ_k` the unit normal of the plane through `x` and the edge (thesis
/// §2.2.2). Zero for a polygon behind `x`; either winding.
pub fn form_factor(x: DVec3, n: DVec3, corners: &[DVec3]) -> f64 {
    // Sutherland-Hodgman against the plane n · (y - x) = 0, as directions
    // from `x`.
    let mut clipped: Vec<DVec3> = Vec::with_capacity(corners.len() + 1);
    for (k, &a) in corners.iter().enumerate() {
        let b = corners[(k + 1) % corners.len()];
        let (da, db) = (a - x, b - x);
        let (ha, hb) = (n.dot(da), n.dot(db));
        if ha >= 0.0 {
            clipped.push(da);
        }
        if (ha >= 0.0) != (hb >= 0.0) {
            let t = ha / (ha - hb);
            clipped.push(da + (db - da) * t);
        }
    }
    if clipped.len() < 3 {
        return 0.0;
    }
    let mut sum = 0.0;
    for (k, &a) in clipped.iter().enumerate() {
        let b = clipped[(k + 1) % clipped.len()];
        let (a, b) = (a.normalize_or_zero(), b.normalize_or_zero());
        let c = a.cross(b);
        let len = c.length();
        if len <= 1e-15 {
            continue;
        }
        let gamma = a.dot(b).clamp(-1.0, 1.0).acos();
        sum += gamma * n.dot(c / len);
    }
    (sum / std::f64::consts::TAU).abs()
}

/// The points of a `grid` x `grid` stratification of the patch `wp` with the
/// share of its area each stands for (the shares sum to 1).
///
/// A parallelogram's are its cell centres, `1 / grid²` each. A triangle's
/// (the half `t <= s` of its frame) fold the square's grid onto the
/// triangle by mirroring the cells above the diagonal onto those below,
/// which keeps the sampling uniform over the triangle's area: a cell below
/// the diagonal stands for itself and its mirror image (`2 / grid²`, at
/// its centre), a cell on the diagonal for its lower half twice (`1 /
/// grid²`, at that half's centroid, inside the triangle).
pub fn grid_points(wp: &WorldPatch, grid: usize) -> impl Iterator<Item = (DVec3, f64)> + '_ {
    sample_points(wp, grid, None)
}

/// [`grid_points`], each point placed at random within its cell (within
/// the cell's lower half on a triangle's diagonal) by a generator seeded
/// with `seed`, or at the cell's centre without one. A fixed point per
/// cell aliases with a regular occluder in front of an emitter (the
/// garage's panel behind a grille: 8² cell centres saw 100% of it from
/// the floor where the path tracer saw 81%, and the direct light of its
/// floor read 27% high); a point at random in each cell keeps the
/// stratification and has no bias.
pub fn sample_points(
    wp: &WorldPatch,
    grid: usize,
    seed: Option<u64>,
) -> impl Iterator<Item = (DVec3, f64)> + '_ {
    let g = grid as f64;
    let cell = 1.0 / (g * g);
    let triangle = wp.is_triangle();
    let mut rng = seed.map(fastrand::Rng::with_seed);
    let mut offset = move || match rng.as_mut() {
        Some(r) => (r.f64(), r.f64()),
        None => (0.5, 0.5),
    };
    (0..grid)
        .flat_map(move |a| {
            let rows = if triangle { a + 1 } else { grid };
            (0..rows).map(move |b| (a, b))
        })
        .map(move |(a, b)| {
            let (a, b) = (a as f64, b as f64);
            let (u, v) = offset();
            if !triangle {
                (wp.at((a + u) / g, (b + v) / g), cell)
            } else if b < a {
                (wp.at((a + u) / g, (b + v) / g), 2.0 * cell)
            } else if seed.is_none() {
                (wp.at((a + 2.0 / 3.0) / g, (a + 1.0 / 3.0) / g), cell)
            } else {
                // Uniform over the cell's half below the diagonal: a point
                // above it is mirrored onto it.
                let (u, v) = if v > u { (v, u) } else { (u, v) };
                (wp.at((a + u) / g, (a + v) / g), cell)
            }
        })
}

/// The element of `patch` nearest to the world point `x` on it (`caster`
/// holds the patches placed as `x` is): the texel whose sample is nearest
/// in patch parameters, after clamping `x` onto the patch. On a triangle a
/// point beyond the diagonal is moved onto it, so the texel found has
/// `b <= a` and stands for surface.
pub fn element_at(caster: &Raycaster, atlas: &Atlas, patch: u32, x: DVec3) -> Option<usize> {
    let wp = caster.patches().get(patch as usize)?;
    if wp.area.is_nan() || wp.area <= 0.0 {
        // An absent object's patch (`Raycaster::with_absent`).
        return None;
    }
    let (s, t) = wp.param(x);
    let (mut s, mut t) = (s.clamp(0.0, 1.0), t.clamp(0.0, 1.0));
    if wp.is_triangle() && t > s {
        let m = 0.5 * (s + t);
        (s, t) = (m, m);
    }
    // Rounding is monotonic, so `t <= s` gives row <= column on a
    // triangle's own chart.
    let e = atlas.element_of(patch, wp.is_triangle(), glam::Vec2::new(s as f32, t as f32))?;
    (atlas.elements.get(e)?.patch == patch).then_some(e)
}

/// How [`gather`] reads the radiosity where a ray lands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lookup {
    /// The element whose sample is nearest to the hit point.
    Nearest,
    /// Bilinear between the samples around it, as a client samples the
    /// lightmap ([`Atlas::sample`]), on parallelogram patches (a
    /// triangle's chart reads its nearest element): for values whose
    /// invalid texels are filled (`Validity::dilate`). Near a contact a
    /// hemisphere sees much of one texel of the surface it touches, and
    /// the nearest sample changes from one receiver to the next: the
    /// contact row of a moved box read light and dark in turn.
    Bilinear,
}

/// `B = E + ρ H` of each element of `elements`, `H` the radiosity it sees
/// over its hemisphere in `radiosity` (one RGBA value per element), against
/// the scene at `poses` without the objects flagged in `absent`: emitters
/// by next-event estimation (`grid`² samples
/// per emitting patch, a shadow ray each, [`Emitters::irradiance`]),
/// everything else by `side`² stratified cosine-distributed rays (Malley's
/// method, [`CosineGrid`]), each reading `radiosity` where it hits as
/// `lookup` says; a back face gives nothing. Users: the tests that check
/// what cross projection blocks against rays; cross redistribution's
/// regathering calls [`gather_cached`].
#[allow(clippy::too_many_arguments)]
pub fn gather(
    scene: &Scene,
    atlas: &Atlas,
    (poses, absent): (&[Pose], &[bool]),
    radiosity: &[[f32; 4]],
    elements: &[usize],
    side: usize,
    grid: usize,
    lookup: Lookup,
) -> Vec<Vec3> {
    let mut none = StaticHits::new(side, 0);
    gather_cached(
        scene,
        atlas,
        (poses, absent),
        radiosity,
        elements,
        grid,
        lookup,
        &mut none,
    )
}

/// [`gather`] with the cache's `side`² cosine rays ([`StaticHits::new`])
/// and their hits on the static world taken from (and added to) `cache`:
/// only the dynamic objects are ray cast again. The hits are the same as
/// casting against everything.
#[allow(clippy::too_many_arguments)]
pub fn gather_cached(
    scene: &Scene,
    atlas: &Atlas,
    (poses, absent): (&[Pose], &[bool]),
    radiosity: &[[f32; 4]],
    elements: &[usize],
    grid: usize,
    lookup: Lookup,
    cache: &mut StaticHits,
) -> Vec<Vec3> {
    let caster = Raycaster::with_absent(scene, poses, absent);
    let emitters = Emitters::of(scene);
    let value = |j: usize| {
        let b = radiosity[j];
        Vec3::new(b[0], b[1], b[2])
    };
    let seen = |patch: u32, x: DVec3| -> Option<Vec3> {
        let weights = lookup_weights(&caster, atlas, patch, x, lookup)?;
        Some(weights.iter().map(|&(j, w)| value(j) * w).sum())
    };
    let samples: Vec<(DVec3, DVec3)> = elements
        .iter()
        .map(|&i| sample_point(scene, &caster, atlas, poses, i))
        .collect();
    let rays = cache.prepare(scene, (poses, absent), elements, &samples);
    elements
        .par_iter()
        .zip(&samples)
        .map(|(&i, &(x, n))| {
            let e = &atlas.elements[i];
            let mut h = Vec3::ZERO;
            let directions = rays.directions.around(n);
            for (hit, d) in rays.hits(&caster, i, x, n).zip(directions) {
                let Some(hit) = hit else {
                    // Left the scene: the sky, if it has one, as the
                    // radiosity π L of a surface of its radiance.
                    if let Some(sky) = &scene.sky {
                        h += sky.radiance(d.as_vec3()) * std::f32::consts::PI;
                    }
                    continue;
                };
                // Emitters are sampled on their own below.
                if !hit.front || emitters.contains(hit.patch) {
                    continue;
                }
                if let Some(b) = seen(hit.patch, hit.point) {
                    h += b;
                }
            }
            h /= rays.count() as f32;
            h += emitters.irradiance(&caster, atlas, x, n, grid, value);
            h += crate::lights::texel_irradiance(scene, &caster, (atlas, poses), i, (x, n));
            e.emission + e.albedo * h
        })
        .collect()
}

/// The elements whose radiosity a ray hitting `patch` at the world point
/// `x` reads as `lookup` says, with their weights (summing to 1; the
/// nearest element's alone has weight 1 and three of weight 0). `caster`
/// holds the patches placed as `x` is. None for a patch of no area (an
/// absent object's) or a point with no element.
pub(crate) fn lookup_weights(
    caster: &Raycaster,
    atlas: &Atlas,
    patch: u32,
    x: DVec3,
    lookup: Lookup,
) -> Option<[(usize, f32); 4]> {
    let wp = caster.patches().get(patch as usize)?;
    let chart = atlas.charts.get(patch as usize)?;
    // A chart on a mesh's own lightmap holds texels beyond its patch
    // (`atlas/uv.rs`): nearest there, as on a triangle's chart.
    if lookup == Lookup::Bilinear
        && !wp.is_triangle()
        && !atlas.on_lightmap_uvs(patch)
        && chart.w >= 2
        && chart.h >= 2
    {
        if wp.area.is_nan() || wp.area <= 0.0 {
            return None;
        }
        let (s, t) = wp.param(x);
        return Some(atlas.sample_weights(patch, [s as f32, t as f32]));
    }
    let e = element_at(caster, atlas, patch, x)?;
    Some([(e, 1.0), (e, 0.0), (e, 0.0), (e, 0.0)])
}

/// An element's kept rays: the sample point and normal they leave from,
/// and per direction the static patch hit and its distance.
type KeptRays = (DVec3, DVec3, Box<[(u32, f64)]>);

/// A kept ray's patch when it hits nothing of the static world.
const NO_HIT: u32 = u32::MAX;

/// The closest hits of the cosine rays of gathering elements against the
/// static world (object 0, which never moves), kept between gathers: the
/// texels next to a moving object gather after every move, and only the
/// rays that meet a dynamic object change. Holds at most `capacity`
/// elements' rays (`side`² hits each, 16 bytes a hit, [`NO_HIT`] for a ray
/// that leaves the scene); when a gather needs more it starts over, so
/// memory stays bounded whatever the moves.
#[derive(Debug)]
pub struct StaticHits {
    directions: CosineGrid,
    capacity: usize,
    /// The static world's patches (the dynamic objects' absent) and the
    /// world pose they were placed with.
    world: Option<(Pose, Raycaster)>,
    /// Per element: the sample point and normal the hits are of, and per
    /// direction the static patch hit and its distance.
    entries: HashMap<usize, KeptRays>,
}

impl StaticHits {
    /// An empty cache of `side`² rays per element for at most `capacity`
    /// elements (0: nothing is kept; every ray is cast against everything).
    pub fn new(side: usize, capacity: usize) -> Self {
        Self {
            directions: CosineGrid::new(side),
            capacity,
            world: None,
            entries: HashMap::new(),
        }
    }

    /// Elements whose hits are kept.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no element's hits are kept.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Fills the hits of `elements` (sampled at `samples`) that are missing
    /// or of another point, and returns the rays to cast for them at
    /// `poses` without the objects flagged in `absent`.
    fn prepare<'a>(
        &'a mut self,
        scene: &Scene,
        (poses, absent): (&[Pose], &[bool]),
        elements: &[usize],
        samples: &[(DVec3, DVec3)],
    ) -> Rays<'a> {
        let keep = self.capacity > 0 && elements.len() <= self.capacity;
        if !keep {
            return Rays {
                directions: &self.directions,
                kept: None,
            };
        }
        let world_pose = poses[0];
        if self.world.as_ref().is_none_or(|(p, _)| *p != world_pose) {
            let dynamic: Vec<bool> = scene.objects.iter().map(|o| o.dynamic).collect();
            self.world = Some((world_pose, Raycaster::with_absent(scene, poses, &dynamic)));
            self.entries.clear();
        }
        let missing: Vec<(usize, DVec3, DVec3)> = elements
            .iter()
            .zip(samples)
            .filter(|&(i, &(x, n))| {
                self.entries
                    .get(i)
                    .is_none_or(|(kx, kn, _)| *kx != x || *kn != n)
            })
            .map(|(&i, &(x, n))| (i, x, n))
            .collect();
        if self.entries.len() + missing.len() > self.capacity {
            self.entries.clear();
        }
        if let Some((_, world)) = &self.world {
            let directions = &self.directions;
            let found: Vec<_> = missing
                .par_iter()
                .map(|&(i, x, n)| {
                    let hits = directions
                        .around(n)
                        .map(|d| {
                            world
                                .closest_hit(x, d, f64::INFINITY)
                                .map_or((NO_HIT, f64::INFINITY), |h| (h.patch, h.distance))
                        })
                        .collect();
                    (i, (x, n, hits))
                })
                .collect();
            self.entries.extend(found);
        }
        // The present dynamic objects alone, ids mapped back to the
        // scene's.
        let (patches, ids): (Vec<WorldPatch>, Vec<u32>) = scene
            .patches
            .iter()
            .enumerate()
            .filter(|(_, p)| {
                let o = p.object as usize;
                scene.objects[o].dynamic && !absent.get(o).copied().unwrap_or(false)
            })
            .map(|(id, p)| {
                (
                    WorldPatch::new(&p.shape, &poses[p.object as usize]),
                    id as u32,
                )
            })
            .unzip();
        Rays {
            directions: &self.directions,
            kept: self.world.as_ref().map(|(_, world)| Kept {
                entries: &self.entries,
                world,
                dynamic: Raycaster::from_patches(patches),
                ids,
            }),
        }
    }
}

/// The cosine rays of one gather ([`StaticHits::prepare`]).
struct Rays<'a> {
    directions: &'a CosineGrid,
    /// The kept static hits; none: every ray is cast against everything.
    kept: Option<Kept<'a>>,
}

/// Kept static hits and what completes them.
struct Kept<'a> {
    entries: &'a HashMap<usize, KeptRays>,
    /// The static world they were cast against.
    world: &'a Raycaster,
    /// The present dynamic objects' patches, and their ids in the scene.
    dynamic: Raycaster,
    ids: Vec<u32>,
}

impl Rays<'_> {
    fn count(&self) -> usize {
        self.directions.len()
    }

    /// The closest hit of each cosine ray of element `i` at `x` (normal
    /// `n`): the nearer of its kept static hit and a present dynamic
    /// object's, or, with nothing kept for it, what `everything` (the
    /// scene as the gather sees it) gives.
    fn hits<'b>(
        &'b self,
        everything: &'b Raycaster,
        i: usize,
        x: DVec3,
        n: DVec3,
    ) -> impl Iterator<Item = Option<Hit>> + 'b {
        let kept = self
            .kept
            .as_ref()
            .and_then(|k| Some((k, &k.entries.get(&i)?.2)));
        self.directions.around(n).enumerate().map(move |(r, d)| {
            let Some((k, hits)) = kept else {
                return everything.closest_hit(x, d, f64::INFINITY);
            };
            let (patch, t) = hits[r];
            if let Some(hit) = k.dynamic.closest_hit(x, d, t) {
                let patch = k.ids[hit.patch as usize];
                return Some(Hit { patch, ..hit });
            }
            (patch != NO_HIT).then(|| k.world.hit(patch, x, d, t))
        })
    }
}

/// Which of `elements` stand at a contact: another surface lies within
/// half a texel of the sample point in the direction of the patch edge
/// nearest to it (a box's row on the floor it rests on, a face pushed
/// against a wall), against the scene at `poses` without the objects
/// flagged in `absent`. One ray each, from the nudged sample point
/// outwards in the patch's plane; only samples on a patch's boundary can
/// reach another surface that close. The light of such a texel changes
/// within the texel (the floor beside a box darkens towards it), so a
/// value gathered for a larger tile misreads it
/// (`gpu/progressive/redistribute.rs` gathers these per texel).
pub fn at_contact(
    scene: &Scene,
    atlas: &Atlas,
    (poses, absent): (&[Pose], &[bool]),
    elements: &[usize],
) -> Vec<usize> {
    let caster = Raycaster::with_absent(scene, poses, absent);
    elements
        .par_iter()
        .copied()
        .filter(|&i| {
            let e = &atlas.elements[i];
            let (x, n) = sample_point(scene, &caster, atlas, poses, i);
            let pose = &poses[e.object as usize];
            let centre = scene.patches[e.patch as usize]
                .shape
                .transformed(pose)
                .centre()
                .as_dvec3();
            let outward = x - centre;
            let outward = (outward - n * outward.dot(n)).normalize_or_zero();
            let reach = 0.5 / f64::from(scene.patches[e.patch as usize].texel_density);
            outward != DVec3::ZERO && caster.occluded(x, outward, reach)
        })
        .collect()
}

/// The irradiance from the emitters' emission at the sample points of
/// `elements` ([`Emitters::irradiance`], `grid`² samples per emitting
/// patch), and from the lights and the sky (`crate::lights::element_direct_at`),
/// against the scene at `poses` without the objects flagged in
/// `absent`, in parallel: the direct light of cross redistribution's
/// moving texels, each its own, where a tile's hemicube would give them
/// one value for all (`gpu/progressive/redistribute.rs`).
pub fn element_direct_light(
    scene: &Scene,
    atlas: &Atlas,
    (poses, absent): (&[Pose], &[bool]),
    elements: &[usize],
    grid: usize,
) -> Vec<Vec3> {
    let caster = Raycaster::with_absent(scene, poses, absent);
    let emitters = Emitters::of(scene);
    let sky = CosineGrid::new(crate::lights::SKY_SIDE);
    let lit = crate::lights::any(scene);
    elements
        .par_iter()
        .map(|&i| {
            let (x, n) = sample_point(scene, &caster, atlas, poses, i);
            let e = emitters.irradiance(&caster, atlas, x, n, grid, |j| atlas.elements[j].emission);
            if lit {
                e + crate::lights::element_direct_at(
                    scene,
                    &caster,
                    (atlas, poses),
                    (i, (x, n)),
                    &sky,
                )
            } else {
                e
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A room's floor, a lamp and a dynamic crate that moves about.
    const CRATE: &str = r#"{
      "name": "crate", "lightmap": { "texel_density": 6 },
      "materials": [
        { "name": "white", "albedo": [0.5, 0.5, 0.5] },
        { "name": "red", "albedo": [0.6, 0.1, 0.1] },
        { "name": "light", "albedo": [0, 0, 0], "emission": [10, 10, 10] }
      ],
      "objects": [{ "name": "crate", "pose": { "translation": [1.0, 0.25, 1.0] } }],
      "surfaces": [
        { "name": "floor", "material": "white",
          "quad": { "origin": [0, 0, 0], "u": [0, 0, 2], "v": [2, 0, 0] } },
        { "name": "wall", "material": "red",
          "quad": { "origin": [0, 0, 0], "u": [2, 0, 0], "v": [0, 2, 0] } },
        { "name": "light", "material": "light",
          "quad": { "origin": [0.5, 2, 0.5], "u": [1, 0, 0], "v": [0, 0, 1] } },
        { "name": "crate", "material": "white", "object": "crate",
          "box": { "center": [0, 0, 0], "size": [0.5, 0.5, 0.5] } }
      ]
    }"#;

    /// A lamp behind a grille of eight slats that cover 40% of it, set
    /// so that every cell centre of an 8 x 8 grid falls in a gap: sampled
    /// at the centres it looks unobstructed (the garage's panel read 27%
    /// too bright on its floor so), sampled at a point at random in each
    /// cell it shows the 60% that is open, at every receiver on average.
    #[test]
    fn a_grille_in_front_of_a_lamp_shows_what_it_covers() {
        let mut surfaces = vec![
            r#"{ "name": "floor", "material": "white",
                "quad": { "origin": [0, 0, 0], "u": [0, 0, 2], "v": [2, 0, 0] } }"#
                .to_string(),
            r#"{ "name": "light", "material": "light",
                "quad": { "origin": [0.5, 2, 0.5], "u": [1, 0, 0], "v": [0, 0, 1] } }"#
                .to_string(),
        ];
        for k in 0..8 {
            let x = 0.5 + k as f64 / 8.0;
            surfaces.push(format!(
                r#"{{ "name": "slat{k}", "material": "white",
                    "quad": {{ "origin": [{x}, 1.999, 0.5], "u": [0.05, 0, 0], "v": [0, 0, 1] }} }}"#
            ));
        }
        let json = format!(
            r#"{{ "name": "grille", "lightmap": {{ "texel_density": 4 }},
              "materials": [
                {{ "name": "white", "albedo": [0.5, 0.5, 0.5] }},
                {{ "name": "light", "albedo": [0, 0, 0], "emission": [10, 10, 10] }}
              ],
              "surfaces": [{}] }}"#,
            surfaces.join(",")
        );
        let scene = Scene::parse(&json, "grille").expect("scene");
        let atlas = Atlas::build(&scene).expect("atlas");
        let poses = scene.initial_poses();
        let caster = Raycaster::new(&scene, &poses);
        let emitters = Emitters::of(&scene);
        let light = scene
            .patches
            .iter()
            .position(|p| p.name == "light")
            .expect("light") as u32;
        let lamp = &caster.patches()[light as usize];
        let n = DVec3::Y;
        let (mut centres, mut jittered, mut irradiance) = (0.0, 0.0, 0.0);
        let receivers: Vec<DVec3> = (0..5)
            .flat_map(|i| (0..5).map(move |j| (i, j)))
            .map(|(i, j)| DVec3::new(0.6 + 0.2 * i as f64, 1e-4, 0.6 + 0.2 * j as f64))
            .collect();
        for &x in &receivers {
            let open = |seed: Option<u64>| {
                let (mut seen, mut all) = (0.0, 0.0);
                for (y, share) in sample_points(lamp, 8, seed) {
                    let to = y - x;
                    let w = share * n.dot(to.normalize()) / to.length_squared();
                    all += w;
                    let hit = caster.closest_hit(x, to.normalize(), to.length() * (1.0 - 1e-6));
                    if hit.is_none_or(|h| h.patch == light) {
                        seen += w;
                    }
                }
                seen / all
            };
            centres += open(None) / receivers.len() as f64;
            jittered +=
                open(Some(x.x.to_bits() ^ x.z.to_bits().rotate_left(7))) / receivers.len() as f64;
            let h = emitters.irradiance(&caster, &atlas, x, n, 8, |j| atlas.elements[j].emission);
            let exact = form_factor(x, n, lamp.corners()) * 10.0;
            irradiance += f64::from(h.x) / exact / receivers.len() as f64;
        }
        assert!(centres > 0.99, "cell centres see {centres:.3} of the lamp");
        assert!(
            (jittered - 0.6).abs() < 0.03,
            "points at random see {jittered:.3}"
        );
        assert!(
            (irradiance - 0.6).abs() < 0.03,
            "irradiance {irradiance:.3} of unobstructed"
        );
    }

    /// Kept static hits change nothing: after every move (the crate
    /// placed, moved, taken out, put back), the cached gather gives each
    /// element exactly what casting every ray against everything gives, for
    /// the texels a move keeps, those it adds, and with a cache too small
    /// for them (which starts over).
    #[test]
    fn gathering_with_kept_static_hits_gives_what_casting_everything_gives() {
        let scene = Scene::parse(CRATE, "crate").expect("scene");
        let atlas = Atlas::build(&scene).expect("atlas");
        let radiosity: Vec<[f32; 4]> = (0..atlas.elements.len())
            .map(|i| {
                let e = &atlas.elements[i];
                [e.emission.x + 0.1 + (i % 7) as f32 * 0.05, 0.3, 0.2, 0.0]
            })
            .collect();
        let floor: Vec<usize> = (0..atlas.elements.len())
            .filter(|&i| atlas.elements[i].patch == 0)
            .collect();
        let mut poses = scene.initial_poses();
        let mut cache = StaticHits::new(6, 1000);
        // Room for one move's texels but not two: it starts over.
        let mut tight = StaticHits::new(6, floor.len() / 2 + 2);
        // Too small for one move's: every ray is cast against everything.
        let mut small = StaticHits::new(6, floor.len() / 3);
        let moves = [
            ([1.0, 0.25, 1.0], false),
            ([1.2, 0.25, 0.9], false),
            ([1.2, 0.25, 0.9], true),
            ([0.6, 0.25, 1.3], false),
        ];
        let mut hit_crate = false;
        for (step, (at, gone)) in moves.into_iter().enumerate() {
            poses[1].translation = Vec3::from(at);
            let absent = [false, gone];
            // A different part of the floor each time, overlapping the last.
            let elements: Vec<usize> = floor
                .iter()
                .copied()
                .skip(step * floor.len() / 8)
                .take(floor.len() / 2)
                .collect();
            let expected = gather(
                &scene,
                &atlas,
                (&poses, &absent),
                &radiosity,
                &elements,
                6,
                4,
                Lookup::Bilinear,
            );
            for cache in [&mut cache, &mut tight, &mut small] {
                let got = gather_cached(
                    &scene,
                    &atlas,
                    (&poses, &absent),
                    &radiosity,
                    &elements,
                    4,
                    Lookup::Bilinear,
                    cache,
                );
                assert_eq!(got, expected, "move {step}");
            }
            assert!(cache.len() >= elements.len(), "move {step}: kept");
            assert!(tight.len() <= floor.len() / 2 + 2, "move {step}: bounded");
            assert!(small.is_empty(), "move {step}: nothing kept");
            // The crate must matter, or the test shows nothing: without
            // it the floor gathers otherwise.
            let without = gather(
                &scene,
                &atlas,
                (&poses, &[false, true]),
                &radiosity,
                &elements,
                6,
                4,
                Lookup::Bilinear,
            );
            hit_crate |= !gone && without != expected;
        }
        assert!(hit_crate, "the crate shadows none of the gathering texels");
    }

    /// Two directly opposed parallel unit squares one unit apart: the form
    /// factor from the centre of one to the other is four times the closed
    /// form for a point under a corner of an `a` x `b` rectangle at height
    /// `c`, `(1/2π) (A/√(1+A²) atan(B/√(1+A²)) + B/√(1+B²) atan(A/√(1+B²)))`
    /// with `A = a/c = B = 1/2`: about 0.2394.
    #[test]
    fn form_factor_of_an_opposed_square_matches_the_closed_form() {
        let corners = [
            DVec3::new(-0.5, -0.5, 1.0),
            DVec3::new(0.5, -0.5, 1.0),
            DVec3::new(0.5, 0.5, 1.0),
            DVec3::new(-0.5, 0.5, 1.0),
        ];
        let (a, c) = (0.5f64, 1.0f64);
        let k = a / (a * a + c * c).sqrt();
        let expected =
            4.0 / (2.0 * std::f64::consts::PI) * k * (a / (a * a + c * c).sqrt()).atan() * 2.0;
        let got = form_factor(DVec3::ZERO, DVec3::Z, &corners);
        assert!((got - expected).abs() < 1e-9, "{got} vs {expected}");
        let reversed: Vec<DVec3> = corners.iter().rev().copied().collect();
        assert!((form_factor(DVec3::ZERO, DVec3::Z, &reversed) - got).abs() < 1e-12);
    }

    /// The folded grid on a triangle is a midpoint rule over it: every point
    /// on the triangle, shares summing to 1, and the weighted mean of the
    /// points its centroid (exact for linear functions); a grid over the
    /// whole parallelogram would put it at the parallelogram's centre.
    #[test]
    fn the_grid_on_a_triangle_is_uniform_over_the_triangle() {
        let (o, u, v) = (
            DVec3::new(0.3, 1.0, -0.2),
            DVec3::new(1.5, 0.2, 0.0),
            DVec3::new(-0.4, 0.1, 0.9),
        );
        let tri = WorldPatch::triangle(o, u, v);
        for grid in [1, 2, 5, 16] {
            let points: Vec<(DVec3, f64)> = grid_points(&tri, grid).collect();
            assert_eq!(points.len(), grid * (grid + 1) / 2);
            let total: f64 = points.iter().map(|p| p.1).sum();
            assert!((total - 1.0).abs() < 1e-12, "{grid}: {total}");
            let mean: DVec3 = points.iter().map(|(y, w)| *y * *w).sum();
            assert!((mean - tri.centre()).length() < 1e-12, "{grid}: {mean}");
            for (y, _) in &points {
                let (s, t) = tri.param(*y);
                assert!(tri.contains(s, t) && t < s, "{grid}: ({s}, {t}) off");
            }
        }
        let quad = WorldPatch::parallelogram(o, u, v);
        let mean: DVec3 = grid_points(&quad, 4).map(|(y, w)| y * w).sum();
        assert!((mean - quad.centre()).length() < 1e-12);
    }

    /// A floor point a millimetre from a wall that extends far in every
    /// direction above it sees half of the hemisphere's form factor in it;
    /// a polygon wholly behind the point gives zero, and one half behind is
    /// clipped to its upper half.
    #[test]
    fn form_factor_clips_to_the_upper_half_space() {
        let big = 1e4;
        let wall = [
            DVec3::new(0.0, -big, 0.0),
            DVec3::new(0.0, big, 0.0),
            DVec3::new(0.0, big, big),
            DVec3::new(0.0, -big, big),
        ];
        let x = DVec3::new(1e-3, 0.0, 0.0);
        let got = form_factor(x, DVec3::Z, &wall);
        assert!((got - 0.5).abs() < 1e-3, "{got}");
        let below: Vec<DVec3> = wall.iter().map(|c| DVec3::new(c.x, c.y, -c.z)).collect();
        let behind = form_factor(x, DVec3::Z, &below);
        assert!(behind.abs() < 1e-9, "{behind}");
        let through: Vec<DVec3> = wall
            .iter()
            .map(|c| DVec3::new(c.x, c.y, c.z - big / 2.0))
            .collect();
        let half = form_factor(x, DVec3::Z, &through);
        assert!((half - 0.5).abs() < 1e-3, "{half}");
    }
}
