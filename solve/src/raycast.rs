//! Closest-hit ray casting over a scene's world-space patches.
//!
//! [`Raycaster`] places every patch of a [`Scene`] at given poses and
//! answers two questions about a ray `origin + t dir`, `t > 0`, in f64:
//! which patch does it hit first ([`Raycaster::closest_hit`]: patch id,
//! distance, point, and whether the front face — the side `u × v` points
//! to — was hit), and does anything block it before a distance
//! ([`Raycaster::occluded`], for shadow rays; either face blocks).
//!
//! The acceleration structure is a bounding volume hierarchy built top-down
//! along the longest axis of the primitives' centroid bounds, split where
//! the surface area heuristic (the summed areas of the two children's
//! boxes, each times its primitive count: what a random ray expects to
//! test) is least among [`SAH_BINS`] bins of centroids; leaves hold up to
//! [`LEAF_SIZE`] patches. A level's triangles range from a wall to a
//! screw, and a median split put them in boxes that many rays enter: with
//! the surface area heuristic `lightwire bake --solver rays` took 11 s on
//! the garage level instead of 17, and 150 s on pandora instead of 197
//! (BENCHMARKS.md, section 9).
//! Traversal visits the nearer child first and skips every box that starts
//! beyond the closest hit found so far. Its users are the path tracer
//! ([`crate::pathtrace`]) and the contact test of [`crate::validity`]; the
//! reference solver keeps its own shadow-ray hierarchy (`reference/bvh.rs`)
//! so that the two oracles share no code.
//!
//! A patch is a parallelogram ([`PatchShape::Quad`]) or the triangle half
//! `t <= s` of one ([`PatchShape::Triangle`]); a new shape adds an arm to
//! [`WorldPatch::new`] and a test in [`WorldPatch::intersect`].

use glam::DVec3;

use lightwire_scene::atlas::Atlas;
use lightwire_scene::{PatchShape, Pose, Scene};

/// Most patches in one leaf of the hierarchy.
pub const LEAF_SIZE: usize = 4;

/// Bins of centroids a split considers (binned surface area heuristic).
pub const SAH_BINS: usize = 16;

/// Depth below which splits take the median instead of the surface area
/// heuristic's choice.
const SAH_DEPTH: usize = 40;

/// A patch placed in the world: the parallelogram `origin + s u + t v`,
/// `s, t ∈ [0, 1]`, or, for a triangle, its half `0 <= t <= s <= 1`
/// (corners `origin`, `origin + u`, `origin + u + v`, as
/// [`PatchShape::Triangle`]); it faces `u × v`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldPatch {
    pub origin: DVec3,
    pub u: DVec3,
    pub v: DVec3,
    /// Unit normal of the front face, `normalize(u × v)`.
    pub normal: DVec3,
    /// Area in m² (half the parallelogram's for a triangle).
    pub area: f64,
    /// Whether only the half `t <= s` is surface.
    triangle: bool,
    /// `origin`, `origin + u`, `origin + u + v`, `origin + v`; a triangle
    /// has the first three.
    corners: [DVec3; 4],
    /// Unnormalised `u × v` and the dual vectors of `u` and `v` in the
    /// patch's plane: for `d = s u + t v`, `s = d·du` and `t = d·dv`.
    n: DVec3,
    du: DVec3,
    dv: DVec3,
}

impl WorldPatch {
    /// The patch `shape` (object-local) moved by `pose`.
    pub fn new(shape: &PatchShape, pose: &Pose) -> Self {
        let placed = shape.transformed(pose);
        let (origin, u, v) = placed.frame();
        let (origin, u, v) = (origin.as_dvec3(), u.as_dvec3(), v.as_dvec3());
        if placed.is_triangle() {
            Self::triangle(origin, u, v)
        } else {
            Self::parallelogram(origin, u, v)
        }
    }

    /// A world-space parallelogram. `u` and `v` must not be parallel (a
    /// validated scene guarantees it).
    pub fn parallelogram(origin: DVec3, u: DVec3, v: DVec3) -> Self {
        let n = u.cross(v);
        let nn = n.length_squared();
        Self {
            origin,
            u,
            v,
            normal: n / nn.sqrt(),
            area: nn.sqrt(),
            triangle: false,
            corners: [origin, origin + u, origin + u + v, origin + v],
            n,
            du: v.cross(n) / nn,
            dv: n.cross(u) / nn,
        }
    }

    /// The world-space triangle `origin`, `origin + u`, `origin + u + v`:
    /// the half `t <= s` of [`Self::parallelogram`].
    pub fn triangle(origin: DVec3, u: DVec3, v: DVec3) -> Self {
        let whole = Self::parallelogram(origin, u, v);
        Self {
            area: 0.5 * whole.area,
            triangle: true,
            ..whole
        }
    }

    /// Whether the patch is a triangle (only `t <= s` is surface).
    pub fn is_triangle(&self) -> bool {
        self.triangle
    }

    /// The point at patch parameters `(s, t)`.
    pub fn at(&self, s: f64, t: f64) -> DVec3 {
        self.origin + self.u * s + self.v * t
    }

    /// Patch parameters `(s, t)` of the point of the patch's plane nearest
    /// to `x` (not clamped to the patch).
    pub fn param(&self, x: DVec3) -> (f64, f64) {
        let d = x - self.origin;
        (d.dot(self.du), d.dot(self.dv))
    }

    /// Whether patch parameters `(s, t)` lie on the patch, edges included.
    pub fn contains(&self, s: f64, t: f64) -> bool {
        let square = (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&t);
        square && (!self.triangle || t <= s)
    }

    /// The centroid of the patch: `(1/2, 1/2)` of a parallelogram,
    /// `(2/3, 1/3)` of a triangle.
    pub fn centre(&self) -> DVec3 {
        if self.triangle {
            self.at(2.0 / 3.0, 1.0 / 3.0)
        } else {
            self.at(0.5, 0.5)
        }
    }

    /// Corners counter-clockwise seen from the front: `origin`,
    /// `origin + u`, `origin + u + v` and, for a parallelogram,
    /// `origin + v` (the polygon of a point-to-polygon form factor).
    pub fn corners(&self) -> &[DVec3] {
        &self.corners[..if self.triangle { 3 } else { 4 }]
    }

    fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for &c in self.corners() {
            b.grow(c);
        }
        b
    }

    /// Ray parameter `t ∈ (0, t_max)` at which `origin + t dir` crosses the
    /// patch, if it does. Rays in (or parallel to) the patch's plane miss.
    #[inline]
    pub fn intersect(&self, origin: DVec3, dir: DVec3, t_max: f64) -> Option<f64> {
        let denom = dir.dot(self.n);
        if denom == 0.0 || !denom.is_finite() {
            return None;
        }
        let t = (self.origin - origin).dot(self.n) / denom;
        if !(t > 0.0 && t < t_max) {
            return None;
        }
        let (s, w) = self.param(origin + dir * t);
        self.contains(s, w).then_some(t)
    }
}

/// Where a ray first meets a patch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Patch id: an index into [`Scene::patches`] (or into the slice given
    /// to [`Raycaster::from_patches`]).
    pub patch: u32,
    /// Distance from the ray origin along the unit direction (m).
    pub distance: f64,
    /// The hit point.
    pub point: DVec3,
    /// Whether the ray arrived on the front face (the side `u × v` points
    /// to), i.e. `dir · normal < 0`.
    pub front: bool,
}

#[derive(Debug, Clone, Copy)]
struct Aabb {
    min: DVec3,
    max: DVec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: DVec3::splat(f64::INFINITY),
        max: DVec3::splat(f64::NEG_INFINITY),
    };

    fn grow(&mut self, p: DVec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    fn centre(&self) -> DVec3 {
        (self.min + self.max) * 0.5
    }

    /// Surface area (0 for an empty box).
    fn area(&self) -> f64 {
        let d = (self.max - self.min).max(DVec3::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }

    /// Entry distance of the ray `origin + t dir` (with `inv = 1 / dir`)
    /// into the box, if it enters before `t_max`. A small tolerance keeps
    /// flat boxes (a single axis-aligned quad) hittable; NaNs from
    /// `0 * inf` on an axis-parallel ray through a slab face count as
    /// inside, so nothing is culled wrongly.
    #[inline]
    fn entry(&self, origin: DVec3, inv: DVec3, t_max: f64) -> Option<f64> {
        let t0 = (self.min - origin) * inv;
        let t1 = (self.max - origin) * inv;
        let near = t0.min(t1);
        let far = t0.max(t1);
        let lo = near.x.max(near.y).max(near.z).max(0.0);
        let hi = far.x.min(far.y).min(far.z).min(t_max);
        let slack = 1e-9 * (1.0 + lo.abs());
        (lo <= hi + slack).then_some(lo)
    }
}

#[derive(Debug, Clone, Copy)]
struct Node {
    bounds: Aabb,
    /// Leaf: first index into `order`; inner: unused.
    first: u32,
    /// Leaf: number of patches (> 0); inner: 0.
    count: u32,
    /// Inner: index of the right child (the left is `self index + 1`).
    right: u32,
}

/// Closest-hit and occlusion queries over world-space patches.
#[derive(Debug, Clone)]
pub struct Raycaster {
    patches: Vec<WorldPatch>,
    /// Patch ids in leaf order.
    order: Vec<u32>,
    /// Depth-first: an inner node's left child follows it directly.
    nodes: Vec<Node>,
}

impl Raycaster {
    /// Places every patch of `scene` at `poses` (one per object, indexed
    /// like [`Scene::objects`], e.g. [`Scene::initial_poses`]). Patch ids
    /// are indices into `scene.patches`.
    pub fn new(scene: &Scene, poses: &[Pose]) -> Self {
        Self::from_patches(
            scene
                .patches
                .iter()
                .map(|p| WorldPatch::new(&p.shape, &poses[p.object as usize]))
                .collect(),
        )
    }

    /// Like [`Raycaster::new`], with the patches of the objects flagged in
    /// `absent` (a moving object taken out of the simulation, cross
    /// redistribution) shrunk to a point that no ray hits; patch ids stay
    /// indices into `scene.patches`.
    pub fn with_absent(scene: &Scene, poses: &[Pose], absent: &[bool]) -> Self {
        Self::from_patches(
            scene
                .patches
                .iter()
                .map(|p| {
                    let pose = &poses[p.object as usize];
                    let placed = WorldPatch::new(&p.shape, pose);
                    if absent.get(p.object as usize).copied().unwrap_or(false) {
                        WorldPatch::parallelogram(placed.origin, DVec3::ZERO, DVec3::ZERO)
                    } else {
                        placed
                    }
                })
                .collect(),
        )
    }

    /// A hierarchy over the given patches; ids are their indices.
    pub fn from_patches(patches: Vec<WorldPatch>) -> Self {
        let bounds: Vec<Aabb> = patches.iter().map(WorldPatch::bounds).collect();
        let mut order: Vec<u32> = (0..patches.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * patches.len().max(1));
        if !patches.is_empty() {
            build(&bounds, &mut order, (0, 0), &mut nodes);
        }
        Self {
            patches,
            order,
            nodes,
        }
    }

    /// The placed patches, indexed by patch id.
    pub fn patches(&self) -> &[WorldPatch] {
        &self.patches
    }

    /// The diagonal of the scene's bounds, for scale-relative offsets.
    /// The root node's bounds are the union of every patch's (min and max
    /// are exact, so the same to the bit as a loop over the patches), so
    /// this costs nothing per sample point.
    pub fn extent(&self) -> f64 {
        self.nodes
            .first()
            .map_or(0.0, |root| (root.bounds.max - root.bounds.min).length())
            .max(1e-9)
    }

    /// The first patch the ray `origin + t dir`, `0 < t < t_max`, hits.
    /// `dir` must be a unit vector (distances are ray parameters).
    pub fn closest_hit(&self, origin: DVec3, dir: DVec3, t_max: f64) -> Option<Hit> {
        let mut best: Option<(u32, f64)> = None;
        let mut limit = t_max;
        self.traverse(origin, dir, &mut limit, |id, t| {
            best = Some((id, t));
            false
        });
        best.map(|(patch, t)| self.hit(patch, origin, dir, t))
    }

    /// Whether any patch, either face, lies on the ray `origin + t dir`
    /// for `0 < t < t_max`: a shadow ray. `dir` must be a unit vector.
    pub fn occluded(&self, origin: DVec3, dir: DVec3, t_max: f64) -> bool {
        let mut blocked = false;
        let mut limit = t_max;
        self.traverse(origin, dir, &mut limit, |_, _| {
            blocked = true;
            true
        });
        blocked
    }

    /// Whether any patch but `except`, either face, lies on the ray
    /// `origin + t dir` for `0 < t < t_max`: a shadow ray towards a point
    /// of patch `except` (an emitter), which stops at the first blocker
    /// instead of looking for the closest hit. `dir` must be a unit
    /// vector.
    pub fn occluded_except(&self, origin: DVec3, dir: DVec3, t_max: f64, except: u32) -> bool {
        let mut blocked = false;
        let mut limit = t_max;
        self.traverse(origin, dir, &mut limit, |id, _| {
            blocked = id != except;
            blocked
        });
        blocked
    }

    /// [`Self::closest_hit`] by testing every patch: what the hierarchy
    /// must agree with (tests, and a check for new shapes).
    pub fn closest_hit_brute_force(&self, origin: DVec3, dir: DVec3, t_max: f64) -> Option<Hit> {
        let mut best: Option<(u32, f64)> = None;
        let mut limit = t_max;
        for (id, p) in self.patches.iter().enumerate() {
            if let Some(t) = p.intersect(origin, dir, limit) {
                best = Some((id as u32, t));
                limit = t;
            }
        }
        best.map(|(patch, t)| self.hit(patch, origin, dir, t))
    }

    /// The hit of the ray `origin + t dir` on `patch` at distance `t` (a
    /// hit found before, of a ray with that origin and direction).
    pub fn hit(&self, patch: u32, origin: DVec3, dir: DVec3, t: f64) -> Hit {
        Hit {
            patch,
            distance: t,
            point: origin + dir * t,
            front: dir.dot(self.patches[patch as usize].normal) < 0.0,
        }
    }

    /// Visits the hits closer than `limit`, nearer boxes first, shrinking
    /// `limit` to each hit found; `on_hit` returns true to stop.
    fn traverse(
        &self,
        origin: DVec3,
        dir: DVec3,
        limit: &mut f64,
        mut on_hit: impl FnMut(u32, f64) -> bool,
    ) {
        if self.nodes.is_empty() || !origin.is_finite() || !dir.is_finite() {
            return;
        }
        let inv = dir.recip();
        // A median split bounds the depth by log2(patches) + 1; the
        // surface area heuristic's is rarely much deeper, and a deeper
        // tree still traverses correctly (`visit_all`).
        let mut stack = [0u32; 64];
        let mut top = 0usize;
        let mut current = 0u32;
        loop {
            let node = &self.nodes[current as usize];
            if node.count > 0 {
                if self.visit_leaf(node, origin, dir, limit, &mut on_hit) {
                    return;
                }
            } else {
                let (left, right) = (current + 1, node.right);
                let tl = self.nodes[left as usize].bounds.entry(origin, inv, *limit);
                let tr = self.nodes[right as usize].bounds.entry(origin, inv, *limit);
                match (tl, tr) {
                    (Some(a), Some(b)) => {
                        let (near, far) = if a <= b { (left, right) } else { (right, left) };
                        if top < stack.len() {
                            stack[top] = far;
                            top += 1;
                            current = near;
                            continue;
                        }
                        // Deeper than the stack: stay correct.
                        self.visit_all(far, origin, dir, limit, &mut on_hit);
                        current = near;
                        continue;
                    }
                    (Some(_), None) => {
                        current = left;
                        continue;
                    }
                    (None, Some(_)) => {
                        current = right;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next box that still starts before the closest hit.
            loop {
                if top == 0 {
                    return;
                }
                top -= 1;
                let candidate = stack[top];
                if self.nodes[candidate as usize]
                    .bounds
                    .entry(origin, inv, *limit)
                    .is_some()
                {
                    current = candidate;
                    break;
                }
            }
        }
    }

    /// Tests the patches of leaf `node`, shortening `limit` to every hit;
    /// true when `on_hit` asks to stop.
    fn visit_leaf(
        &self,
        node: &Node,
        origin: DVec3,
        dir: DVec3,
        limit: &mut f64,
        on_hit: &mut impl FnMut(u32, f64) -> bool,
    ) -> bool {
        let first = node.first as usize;
        for &id in &self.order[first..first + node.count as usize] {
            if let Some(t) = self.patches[id as usize].intersect(origin, dir, *limit) {
                *limit = t;
                if on_hit(id, t) {
                    return true;
                }
            }
        }
        false
    }

    /// Tests every patch under `node` (the stack-overflow fallback).
    fn visit_all(
        &self,
        node: u32,
        origin: DVec3,
        dir: DVec3,
        limit: &mut f64,
        on_hit: &mut impl FnMut(u32, f64) -> bool,
    ) {
        let n = &self.nodes[node as usize];
        if n.count > 0 {
            self.visit_leaf(n, origin, dir, limit, on_hit);
        } else {
            self.visit_all(node + 1, origin, dir, limit, on_hit);
            self.visit_all(n.right, origin, dir, limit, on_hit);
        }
    }
}

/// Builds the subtree over `order[first..first + ids.len()]` depth-first
/// into `nodes`; returns its index.
fn build(
    bounds: &[Aabb],
    ids: &mut [u32],
    (first, depth): (usize, usize),
    nodes: &mut Vec<Node>,
) -> u32 {
    let index = nodes.len() as u32;
    let total = ids
        .iter()
        .fold(Aabb::EMPTY, |b, &i| b.union(&bounds[i as usize]));
    if ids.len() <= LEAF_SIZE {
        nodes.push(Node {
            bounds: total,
            first: first as u32,
            count: ids.len() as u32,
            right: 0,
        });
        return index;
    }
    let mid = split(bounds, ids, depth);
    nodes.push(Node {
        bounds: total,
        first: 0,
        count: 0,
        right: 0,
    });
    let (left, right) = ids.split_at_mut(mid);
    build(bounds, left, (first, depth + 1), nodes);
    let r = build(bounds, right, (first + mid, depth + 1), nodes);
    nodes[index as usize].right = r;
    index
}

/// Orders `ids` so that the first `mid` go left, and returns `mid`: the
/// cheapest split by the surface area heuristic among [`SAH_BINS`] bins
/// of the centroids along their longest axis, or the median when the
/// centroids coincide, every bin boundary leaves one side empty, or the
/// node is deeper than [`SAH_DEPTH`] (a split by area may cut off one
/// primitive at a time; the median halves, so the tree stays shallow
/// and its build's recursion bounded).
fn split(bounds: &[Aabb], ids: &mut [u32], depth: usize) -> usize {
    let mut centroids = Aabb::EMPTY;
    for &i in ids.iter() {
        centroids.grow(bounds[i as usize].centre());
    }
    let extent = centroids.max - centroids.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let median = |ids: &mut [u32]| {
        let mid = ids.len() / 2;
        ids.select_nth_unstable_by(mid, |&a, &b| {
            bounds[a as usize].centre()[axis].total_cmp(&bounds[b as usize].centre()[axis])
        });
        mid
    };
    if extent[axis].partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || depth >= SAH_DEPTH {
        return median(ids);
    }
    let (lo, scale) = (centroids.min[axis], SAH_BINS as f64 / extent[axis]);
    let bin = |i: u32| -> usize {
        let c = bounds[i as usize].centre()[axis];
        (((c - lo) * scale) as usize).min(SAH_BINS - 1)
    };
    let mut boxes = [Aabb::EMPTY; SAH_BINS];
    let mut counts = [0usize; SAH_BINS];
    for &i in ids.iter() {
        let b = bin(i);
        boxes[b] = boxes[b].union(&bounds[i as usize]);
        counts[b] += 1;
    }
    // Cost of splitting after bin k: left area x count + right area x
    // count (the parent's area divides both, so it is left out).
    let mut right_area = [0.0f64; SAH_BINS];
    let (mut acc, mut n) = (Aabb::EMPTY, 0usize);
    for k in (1..SAH_BINS).rev() {
        acc = acc.union(&boxes[k]);
        n += counts[k];
        right_area[k] = if n > 0 { acc.area() * n as f64 } else { 0.0 };
    }
    let (mut best, mut best_cost) = (None, f64::INFINITY);
    let (mut acc, mut n) = (Aabb::EMPTY, 0usize);
    for k in 0..SAH_BINS - 1 {
        acc = acc.union(&boxes[k]);
        n += counts[k];
        if n == 0 || n == ids.len() {
            continue;
        }
        let cost = acc.area() * n as f64 + right_area[k + 1];
        if cost < best_cost {
            (best, best_cost) = (Some(k), cost);
        }
    }
    let Some(best) = best else {
        return median(ids);
    };
    // Partition: bins up to `best` first.
    let (mut i, mut j) = (0, ids.len());
    while i < j {
        if bin(ids[i]) <= best {
            i += 1;
        } else {
            j -= 1;
            ids.swap(i, j);
        }
    }
    i
}

/// `side`² cosine-distributed directions over the hemisphere of a unit
/// normal, stratified: cell `(j, k)` of a uniform grid on the unit disk
/// lifted to the hemisphere (Malley's method), kept in a tangent frame,
/// `(x, y, z)` with `z` along the normal, and computed once: placing them
/// around a normal ([`CosineGrid::around`]) costs three multiply-adds each
/// instead of a square root, a sine and a cosine (a quarter of cross
/// redistribution's regathering).
#[derive(Debug, Clone)]
pub struct CosineGrid {
    local: Vec<DVec3>,
}

impl CosineGrid {
    /// The `side` x `side` grid.
    pub fn new(side: usize) -> Self {
        let cells = (0..side).flat_map(|j| (0..side).map(move |k| (j, k)));
        let local = cells
            .map(|(j, k)| {
                let (u1, u2) = (
                    (j as f64 + 0.5) / side as f64,
                    (k as f64 + 0.5) / side as f64,
                );
                let r = u1.sqrt();
                let phi = std::f64::consts::TAU * u2;
                DVec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt())
            })
            .collect();
        Self { local }
    }

    /// How many directions: `side`².
    pub fn len(&self) -> usize {
        self.local.len()
    }

    /// Whether the grid has no directions (`side` 0).
    pub fn is_empty(&self) -> bool {
        self.local.is_empty()
    }

    /// The directions around the unit normal `n` with the grid shifted by
    /// `shift` (each in [0, 1)) on the unit square before it is lifted (a
    /// Cranley-Patterson rotation): still one direction per cell of a
    /// `side` x `side` grid of the square, so still stratified, but a
    /// different set for every shift. Receivers that each take their own
    /// shift see a bright small source through different directions, so
    /// their shared error is noise, not the streaks one fixed set of
    /// directions draws across a surface. Computed on the fly (a square
    /// root, a sine and a cosine per direction).
    pub fn around_shifted(&self, n: DVec3, shift: (f64, f64)) -> impl Iterator<Item = DVec3> {
        let side = (self.local.len() as f64).sqrt().round().max(1.0) as usize;
        let t1 = n.any_orthonormal_vector();
        let t2 = n.cross(t1);
        (0..side * side).map(move |c| {
            let (j, k) = (c / side, c % side);
            let u1 = ((j as f64 + 0.5) / side as f64 + shift.0).fract();
            let u2 = ((k as f64 + 0.5) / side as f64 + shift.1).fract();
            let r = u1.sqrt();
            let phi = std::f64::consts::TAU * u2;
            t1 * (r * phi.cos()) + t2 * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()
        })
    }

    /// The directions around the unit normal `n`, cell by cell.
    pub fn around(&self, n: DVec3) -> impl Iterator<Item = DVec3> + '_ {
        let t1 = n.any_orthonormal_vector();
        let t2 = n.cross(t1);
        self.local
            .iter()
            .map(move |l| t1 * l.x + t2 * l.y + n * l.z)
    }
}

/// The sample point of element `i` placed by its object's pose, a hair
/// above its surface (so that rays leave it) and as far towards its
/// patch's centre, and its world normal. Edge samples lie on the patch's
/// boundary; where another surface meets it there (a wall's bottom row on
/// the floor's plane, a box's contact row), a ray leaving the point on
/// that surface's plane would pass it and see nothing: the wall's bottom
/// row read about half of what the solvers give it. Nudged inwards, the
/// point sees the meeting surface from just beside it, the limit the
/// texel stands for (the reference solver, the path tracer and
/// `validity.rs` place their samples the same way).
pub(crate) fn sample_point(
    scene: &Scene,
    caster: &Raycaster,
    atlas: &Atlas,
    poses: &[Pose],
    i: usize,
) -> (DVec3, DVec3) {
    let e = &atlas.elements[i];
    let pose = &poses[e.object as usize];
    let n = pose.transform_normal(e.normal).as_dvec3();
    let x = pose.transform_point(e.position).as_dvec3();
    let centre = scene.patches[e.patch as usize]
        .shape
        .transformed(pose)
        .centre()
        .as_dvec3();
    let inward = (centre - x).normalize_or_zero();
    (x + (n + inward) * (1e-5 * caster.extent()), n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A deterministic soup of `n` random parallelograms and triangles in a
    /// 10 m cube, a few large and many small, in every orientation.
    fn soup(n: usize, seed: u64) -> Vec<WorldPatch> {
        let mut rng = fastrand::Rng::with_seed(seed);
        let mut v3 = |scale: f64| {
            DVec3::new(
                rng.f64() * 2.0 - 1.0,
                rng.f64() * 2.0 - 1.0,
                rng.f64() * 2.0 - 1.0,
            ) * scale
        };
        (0..n)
            .map(|k| {
                let size = if k % 10 == 0 { 4.0 } else { 0.8 };
                let origin = v3(5.0);
                let (mut u, mut v) = (v3(size), v3(size));
                while u.cross(v).length() < 1e-3 {
                    (u, v) = (v3(size), v3(size));
                }
                // Every fifth one axis-aligned (flat bounding boxes).
                if k % 5 == 1 {
                    u = DVec3::new(u.x, 0.0, 0.0) + DVec3::X * 0.1;
                    v = DVec3::new(0.0, 0.0, v.z) + DVec3::Z * 0.1;
                }
                // Every third one a triangle (half of its parallelogram).
                if k % 3 == 2 {
                    WorldPatch::triangle(origin, u, v)
                } else {
                    WorldPatch::parallelogram(origin, u, v)
                }
            })
            .collect()
    }

    fn unit(rng: &mut fastrand::Rng) -> DVec3 {
        loop {
            let d = DVec3::new(
                rng.f64() * 2.0 - 1.0,
                rng.f64() * 2.0 - 1.0,
                rng.f64() * 2.0 - 1.0,
            );
            let l = d.length();
            if l > 1e-3 && l <= 1.0 {
                return d / l;
            }
        }
    }

    fn same(a: Option<Hit>, b: Option<Hit>) -> bool {
        match (a, b) {
            (None, None) => true,
            (Some(a), Some(b)) => {
                // Equal distances (a ray through a shared edge) may name
                // either patch.
                (a.patch == b.patch && a.front == b.front || a.distance == b.distance)
                    && (a.distance - b.distance).abs() <= 1e-12 * (1.0 + a.distance)
            }
            _ => false,
        }
    }

    #[test]
    fn bvh_closest_hit_equals_brute_force_on_5000_random_rays() {
        let rc = Raycaster::from_patches(soup(300, 7));
        let mut rng = fastrand::Rng::with_seed(11);
        let (mut hits, mut fronts) = (0, 0);
        for k in 0..5000 {
            let origin = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 14.0 - 7.0;
            let dir = unit(&mut rng);
            let t_max = if k % 4 == 0 {
                rng.f64() * 5.0
            } else {
                f64::INFINITY
            };
            let (a, b) = (
                rc.closest_hit(origin, dir, t_max),
                rc.closest_hit_brute_force(origin, dir, t_max),
            );
            assert!(
                same(a, b),
                "ray {k} from {origin} along {dir}: {a:?} vs {b:?}"
            );
            assert_eq!(rc.occluded(origin, dir, t_max), b.is_some(), "ray {k}");
            // A shadow ray towards a patch: blocked by any other, whether
            // or not the excepted one comes first.
            let except = (k % 300) as u32;
            let others = (0..300u32).filter(|&id| id != except).any(|id| {
                rc.patches()[id as usize]
                    .intersect(origin, dir, t_max)
                    .is_some()
            });
            assert_eq!(
                rc.occluded_except(origin, dir, t_max, except),
                others,
                "ray {k} except {except}"
            );
            if let Some(h) = b {
                hits += 1;
                fronts += usize::from(h.front);
                assert!(h.distance > 0.0 && h.distance < t_max);
                assert!((h.point - (origin + dir * h.distance)).length() < 1e-9);
            }
        }
        // The test means something only if rays both hit and miss, from
        // both sides.
        assert!(hits > 1000 && hits < 4900, "{hits} hits");
        assert!(
            fronts > hits / 4 && fronts < hits * 3 / 4,
            "{fronts} of {hits}"
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any soup, any ray: the hierarchy finds what brute force finds.
        #[test]
        fn bvh_matches_brute_force(seed in any::<u64>(), n in 1usize..120,
                                   ox in -6.0f64..6.0, oy in -6.0f64..6.0, oz in -6.0f64..6.0,
                                   dx in -1.0f64..1.0, dy in -1.0f64..1.0, dz in -1.0f64..1.0) {
            let d = DVec3::new(dx, dy, dz);
            prop_assume!(d.length() > 1e-3);
            let dir = d.normalize();
            let rc = Raycaster::from_patches(soup(n, seed));
            let origin = DVec3::new(ox, oy, oz);
            let (a, b) = (
                rc.closest_hit(origin, dir, f64::INFINITY),
                rc.closest_hit_brute_force(origin, dir, f64::INFINITY),
            );
            prop_assert!(same(a, b), "{:?} vs {:?}", a, b);
        }
    }

    /// The floor `y = 0` facing up (`u = +z`, `v = +x`, `u × v = +y`).
    fn floor() -> Raycaster {
        Raycaster::from_patches(vec![WorldPatch::parallelogram(
            DVec3::ZERO,
            DVec3::Z,
            DVec3::X,
        )])
    }

    #[test]
    fn front_and_back_faces() {
        let rc = floor();
        assert_eq!(rc.patches()[0].normal, DVec3::Y);
        let down = rc
            .closest_hit(DVec3::new(0.5, 2.0, 0.5), -DVec3::Y, f64::INFINITY)
            .expect("hits from above");
        assert!(down.front);
        assert_eq!(down.patch, 0);
        assert!((down.distance - 2.0).abs() < 1e-12);
        assert!((down.point - DVec3::new(0.5, 0.0, 0.5)).length() < 1e-12);
        let up = rc
            .closest_hit(DVec3::new(0.25, -1.0, 0.75), DVec3::Y, f64::INFINITY)
            .expect("hits from below");
        assert!(!up.front);
        assert!((up.distance - 1.0).abs() < 1e-12);
    }

    #[test]
    fn misses() {
        let rc = floor();
        let o = DVec3::new(0.5, 1.0, 0.5);
        // Away from the plane, parallel to it, beside it, beyond t_max.
        assert_eq!(rc.closest_hit(o, DVec3::Y, f64::INFINITY), None);
        assert_eq!(rc.closest_hit(o, DVec3::X, f64::INFINITY), None);
        assert_eq!(
            rc.closest_hit(DVec3::new(1.5, 1.0, 0.5), -DVec3::Y, f64::INFINITY),
            None
        );
        assert_eq!(rc.closest_hit(o, -DVec3::Y, 0.999), None);
        assert!(!rc.occluded(o, -DVec3::Y, 0.999));
        assert!(rc.occluded(o, -DVec3::Y, 1.001));
        // A ray starting on the surface does not hit it (t > 0 strictly).
        assert_eq!(
            rc.closest_hit(DVec3::new(0.5, 0.0, 0.5), DVec3::Y, f64::INFINITY),
            None
        );
        // Non-finite input misses instead of panicking.
        assert_eq!(rc.closest_hit(DVec3::NAN, DVec3::Y, f64::INFINITY), None);
        assert_eq!(
            Raycaster::from_patches(Vec::new()).closest_hit(o, DVec3::Y, 1.0),
            None
        );
    }

    /// A triangle is the half `t <= s` of its frame: rays through that
    /// half hit it (its edges included), rays through the other half of the
    /// parallelogram miss; its bounds, centre, area and corners are the
    /// triangle's. The triangle `(0,0,0)`, `(0,0,1)`, `(1,0,1)` on the floor
    /// (`u = +z`, `v = +x`, facing up) covers the points with `x <= z`.
    #[test]
    fn a_triangle_is_hit_only_on_its_half_of_the_parallelogram() {
        let tri = WorldPatch::triangle(DVec3::ZERO, DVec3::Z, DVec3::X);
        let quad = WorldPatch::parallelogram(DVec3::ZERO, DVec3::Z, DVec3::X);
        let rc = Raycaster::from_patches(vec![tri]);
        let down = |x: f64, z: f64| rc.closest_hit(DVec3::new(x, 1.0, z), -DVec3::Y, 2.0);
        let mut rng = fastrand::Rng::with_seed(5);
        let (mut inside, mut outside) = (0, 0);
        for _ in 0..2000 {
            let (x, z) = (rng.f64(), rng.f64());
            if (x - z).abs() < 1e-9 {
                continue;
            }
            let hit = down(x, z);
            // The same ray always hits the whole parallelogram.
            assert!(
                quad.intersect(DVec3::new(x, 1.0, z), -DVec3::Y, 2.0)
                    .is_some()
            );
            if x < z {
                inside += 1;
                let h = hit.unwrap_or_else(|| panic!("({x}, {z}) is on the triangle"));
                assert!(h.front && (h.distance - 1.0).abs() < 1e-12);
            } else {
                outside += 1;
                assert_eq!(hit, None, "({x}, {z}) is off the triangle");
            }
        }
        assert!(inside > 800 && outside > 800);
        // Its edges, the diagonal included, belong to it.
        for (x, z) in [(0.5, 0.5), (0.0, 0.3), (0.3, 1.0), (0.0, 0.0), (1.0, 1.0)] {
            assert!(down(x, z).is_some(), "edge point ({x}, {z})");
        }
        assert!(down(0.5 + 1e-9, 0.5).is_none());
        // From below: a back-face hit on the same half only.
        let up = rc.closest_hit(DVec3::new(0.2, -1.0, 0.7), DVec3::Y, 2.0);
        assert!(up.is_some_and(|h| !h.front));
        assert!(
            rc.closest_hit(DVec3::new(0.7, -1.0, 0.2), DVec3::Y, 2.0)
                .is_none()
        );
        assert!((tri.area - 0.5).abs() < 1e-15 && (quad.area - 1.0).abs() < 1e-15);
        assert!((tri.centre() - DVec3::new(1.0 / 3.0, 0.0, 2.0 / 3.0)).length() < 1e-15);
        assert_eq!(tri.corners().len(), 3);
        assert_eq!(quad.corners().len(), 4);
        assert!(tri.contains(0.7, 0.7) && !tri.contains(0.3, 0.7));
        // Bounds from the three corners: a triangle whose parallelogram's
        // fourth corner, (-1, 0, 1), lies outside its box has the extent
        // of its own corners (the parallelogram's would be √5).
        let slim = WorldPatch::triangle(DVec3::ZERO, DVec3::X, DVec3::new(-1.0, 0.0, 1.0));
        let rc = Raycaster::from_patches(vec![slim]);
        assert!((rc.extent() - 2f64.sqrt()).abs() < 1e-12, "{}", rc.extent());
    }

    /// A scene's mesh surface is placed as triangles: a quad scene and its
    /// triangulation hit the same points with the same distances, and the
    /// triangle hit names the half the point is on.
    #[test]
    fn a_triangulated_scene_is_hit_where_its_quads_are() {
        let scene = Scene::parse(
            r#"{
              "name": "tri", "lightmap": { "texel_density": 2 },
              "materials": [ { "name": "light", "albedo": [0, 0, 0], "emission": [1, 1, 1] } ],
              "surfaces": [
                { "name": "floor", "material": "light",
                  "quad": { "origin": [0, 0, 0], "u": [0, 0, 2], "v": [1, 0, 0] } }
              ]
            }"#,
            "raycast test",
        )
        .expect("scene");
        let tri = scene.triangulated();
        let poses = scene.initial_poses();
        let (quads, triangles) = (Raycaster::new(&scene, &poses), Raycaster::new(&tri, &poses));
        assert!(triangles.patches().iter().all(WorldPatch::is_triangle));
        let mut rng = fastrand::Rng::with_seed(9);
        for _ in 0..500 {
            let o = DVec3::new(rng.f64() * 1.4 - 0.2, 1.0, rng.f64() * 2.4 - 0.2);
            let (a, b) = (
                quads.closest_hit(o, -DVec3::Y, 5.0),
                triangles.closest_hit(o, -DVec3::Y, 5.0),
            );
            assert_eq!(a.is_some(), b.is_some(), "{o}");
            if let (Some(a), Some(b)) = (a, b) {
                assert!((a.distance - b.distance).abs() < 1e-9);
                // Quad (s, t) = (z / 2, x); its first triangle has t <= s.
                let (s, t) = (o.z / 2.0, o.x);
                if (s - t).abs() > 1e-6 {
                    assert_eq!(b.patch, u32::from(t > s), "{o}");
                }
            }
        }
    }

    /// The nearer of two stacked patches wins, and a scene with a dynamic
    /// object places it at the given pose.
    #[test]
    fn nearest_of_stacked_patches_and_poses() {
        let scene = Scene::parse(
            r#"{
              "name": "stack", "lightmap": { "texel_density": 2 },
              "materials": [ { "name": "light", "albedo": [0, 0, 0], "emission": [1, 1, 1] } ],
              "objects": [ { "name": "lid", "pose": { "translation": [0, 3, 0] } } ],
              "surfaces": [
                { "name": "floor", "material": "light",
                  "quad": { "origin": [0, 0, 0], "u": [0, 0, 1], "v": [1, 0, 0] } },
                { "name": "lid", "material": "light", "object": "lid",
                  "quad": { "origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 0, 1] } }
              ]
            }"#,
            "raycast test",
        )
        .expect("scene");
        let rc = Raycaster::new(&scene, &scene.initial_poses());
        let h = rc
            .closest_hit(DVec3::new(0.5, 1.0, 0.5), DVec3::Y, f64::INFINITY)
            .expect("lid above");
        assert_eq!((h.patch, h.front), (1, true));
        assert!((h.distance - 2.0).abs() < 1e-6);
        let h = rc
            .closest_hit(DVec3::new(0.5, 5.0, 0.5), -DVec3::Y, f64::INFINITY)
            .expect("lid below");
        assert_eq!((h.patch, h.front), (1, false));
        let moved = Pose {
            translation: glam::Vec3::new(0.0, 4.0, 0.0),
            ..Pose::IDENTITY
        };
        let rc = Raycaster::new(&scene, &[Pose::IDENTITY, moved]);
        let h = rc
            .closest_hit(DVec3::new(0.5, 1.0, 0.5), DVec3::Y, f64::INFINITY)
            .expect("lid above");
        assert!((h.distance - 3.0).abs() < 1e-6);
        // An absent lid is hit by nothing; the floor keeps its id.
        let rc = Raycaster::with_absent(&scene, &scene.initial_poses(), &[false, true]);
        assert_eq!(
            rc.closest_hit(DVec3::new(0.5, 1.0, 0.5), DVec3::Y, f64::INFINITY),
            None
        );
        let h = rc
            .closest_hit(DVec3::new(0.5, 5.0, 0.5), -DVec3::Y, f64::INFINITY)
            .expect("floor below");
        assert_eq!((h.patch, h.front), (0, true));
        assert_eq!(rc.patches().len(), 2);
    }
}
