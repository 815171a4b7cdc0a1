//! A bounding volume hierarchy over world-space patches, for shadow rays.
//!
//! Built top-down by splitting at the median centroid along the longest axis
//! of the centroid bounds; leaves hold up to [`LEAF_SIZE`] primitives. Rays
//! are tested against both faces of every primitive (an occluder blocks
//! light whichever side it is hit from).

use glam::DVec3;

const LEAF_SIZE: usize = 4;

/// A world-space patch: the parallelogram `origin + s u + t v`,
/// `s, t ∈ [0, 1]`, or its triangle half `0 <= t <= s <= 1` (corners
/// `origin`, `origin + u`, `origin + u + v`; the scene's
/// `PatchShape::Triangle`).
#[derive(Debug, Clone, Copy)]
pub struct Primitive {
    pub origin: DVec3,
    pub u: DVec3,
    pub v: DVec3,
    /// Whether only the half `t <= s` is surface.
    pub triangle: bool,
    /// Unnormalised normal `u × v`.
    n: DVec3,
    /// Dual vectors: for `d = s u + t v`, `s = d·du` and `t = d·dv`.
    du: DVec3,
    dv: DVec3,
}

impl Primitive {
    /// The parallelogram `origin + s u + t v`, `s, t ∈ [0, 1]`.
    pub fn parallelogram(origin: DVec3, u: DVec3, v: DVec3) -> Self {
        let n = u.cross(v);
        let nn = n.length_squared();
        Self {
            origin,
            u,
            v,
            triangle: false,
            n,
            du: v.cross(n) / nn,
            dv: n.cross(u) / nn,
        }
    }

    /// The triangle `origin`, `origin + u`, `origin + u + v`: the half
    /// `t <= s` of [`Self::parallelogram`].
    pub fn triangle(origin: DVec3, u: DVec3, v: DVec3) -> Self {
        Self {
            triangle: true,
            ..Self::parallelogram(origin, u, v)
        }
    }

    /// Corners counter-clockwise seen from the front (`u × v`): three for a
    /// triangle, four for a parallelogram; `corners()[..count]` are used.
    pub fn corners(&self) -> ([DVec3; 4], usize) {
        let o = self.origin;
        (
            [o, o + self.u, o + self.u + self.v, o + self.v],
            if self.triangle { 3 } else { 4 },
        )
    }

    fn bounds(&self) -> Aabb {
        let mut b = Aabb::empty();
        let (corners, count) = self.corners();
        for p in &corners[..count] {
            b.grow(*p);
        }
        b
    }

    /// Whether the ray `ro + t rd` crosses the patch (either face) at a
    /// `t` in `(t_min, t_max)`.
    fn hit(&self, ro: DVec3, rd: DVec3, t_min: f64, t_max: f64) -> bool {
        let denom = rd.dot(self.n);
        if denom.abs() < 1e-300 {
            return false;
        }
        let t = (self.origin - ro).dot(self.n) / denom;
        if !(t > t_min && t < t_max) {
            return false;
        }
        let d = ro + rd * t - self.origin;
        let s = d.dot(self.du);
        let w = d.dot(self.dv);
        (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&w) && (!self.triangle || w <= s)
    }
}

#[derive(Debug, Clone, Copy)]
struct Aabb {
    min: DVec3,
    max: DVec3,
}

impl Aabb {
    fn empty() -> Self {
        Self {
            min: DVec3::splat(f64::INFINITY),
            max: DVec3::splat(f64::NEG_INFINITY),
        }
    }
    fn grow(&mut self, p: DVec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    fn union(&mut self, o: &Aabb) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }
    /// Slab test against the segment `ro + t rd`, `t ∈ [0, t_max]`.
    fn hit(&self, ro: DVec3, inv: DVec3, t_max: f64) -> bool {
        let t0 = (self.min - ro) * inv;
        let t1 = (self.max - ro) * inv;
        let lo = t0.min(t1).max_element().max(0.0);
        let hi = t0.max(t1).min_element().min(t_max);
        // A tiny tolerance keeps flat boxes (a single quad) hittable.
        lo <= hi + 1e-9
    }
}

#[derive(Debug, Clone, Copy)]
enum Node {
    Leaf {
        bounds: Aabb,
        first: u32,
        count: u32,
    },
    Inner {
        bounds: Aabb,
        left: u32,
        right: u32,
    },
}

/// The hierarchy. Primitive ids are the indices of the slice it was built
/// from (patch ids).
#[derive(Debug, Clone)]
pub struct Bvh {
    prims: Vec<Primitive>,
    /// Primitive ids in leaf order.
    order: Vec<u32>,
    nodes: Vec<Node>,
}

impl Bvh {
    pub fn new(prims: Vec<Primitive>) -> Self {
        let mut order: Vec<u32> = (0..prims.len() as u32).collect();
        let mut nodes = Vec::new();
        if !prims.is_empty() {
            let n = order.len();
            build(&prims, &mut order, 0, n, &mut nodes);
        }
        Self {
            prims,
            order,
            nodes,
        }
    }

    /// Whether any primitive other than those in `skip` blocks the open
    /// segment from `a` to `b`.
    pub fn occluded(&self, a: DVec3, b: DVec3, skip: [u32; 2]) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let rd = b - a;
        let inv = rd.recip();
        // Ignore hits within a relative hair of either end point.
        let (t_min, t_max) = (1e-9, 1.0 - 1e-9);
        let mut stack = [0u32; 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            match self.nodes[stack[top] as usize] {
                Node::Leaf {
                    bounds,
                    first,
                    count,
                } => {
                    if !bounds.hit(a, inv, 1.0) {
                        continue;
                    }
                    for &p in &self.order[first as usize..(first + count) as usize] {
                        if p != skip[0]
                            && p != skip[1]
                            && self.prims[p as usize].hit(a, rd, t_min, t_max)
                        {
                            return true;
                        }
                    }
                }
                Node::Inner {
                    bounds,
                    left,
                    right,
                } => {
                    if bounds.hit(a, inv, 1.0) && top + 2 <= stack.len() {
                        stack[top] = left;
                        stack[top + 1] = right;
                        top += 2;
                    }
                }
            }
        }
        false
    }
}

fn build(
    prims: &[Primitive],
    order: &mut [u32],
    first: usize,
    end: usize,
    nodes: &mut Vec<Node>,
) -> u32 {
    let slice = &mut order[first..end];
    let mut bounds = Aabb::empty();
    let mut centroids = Aabb::empty();
    for &p in slice.iter() {
        let b = prims[p as usize].bounds();
        bounds.union(&b);
        centroids.grow((b.min + b.max) * 0.5);
    }
    let index = nodes.len() as u32;
    if slice.len() <= LEAF_SIZE {
        nodes.push(Node::Leaf {
            bounds,
            first: first as u32,
            count: slice.len() as u32,
        });
        return index;
    }
    let extent = centroids.max - centroids.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let key = |p: &u32| {
        let b = prims[*p as usize].bounds();
        (b.min + b.max)[axis]
    };
    slice.sort_by(|a, b| key(a).total_cmp(&key(b)));
    let mid = first + slice.len() / 2;
    nodes.push(Node::Leaf {
        bounds,
        first: 0,
        count: 0,
    }); // placeholder
    let left = build(prims, order, first, mid, nodes);
    let right = build(prims, order, mid, end, nodes);
    nodes[index as usize] = Node::Inner {
        bounds,
        left,
        right,
    };
    index
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(z: f64) -> Primitive {
        Primitive::parallelogram(
            DVec3::new(-1.0, -1.0, z),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
        )
    }

    #[test]
    fn a_square_between_two_points_blocks_the_segment() {
        let bvh = Bvh::new(vec![square(0.0)]);
        assert!(bvh.occluded(
            DVec3::new(0.0, 0.0, -1.0),
            DVec3::new(0.0, 0.0, 1.0),
            [u32::MAX; 2]
        ));
        // Passing beside the square is not blocked.
        assert!(!bvh.occluded(
            DVec3::new(1.5, 0.0, -1.0),
            DVec3::new(1.5, 0.0, 1.0),
            [u32::MAX; 2]
        ));
        // A skipped primitive never blocks.
        assert!(!bvh.occluded(
            DVec3::new(0.0, 0.0, -1.0),
            DVec3::new(0.0, 0.0, 1.0),
            [0, u32::MAX]
        ));
    }

    /// A triangle blocks only segments through its half `t <= s` of the
    /// square (here `y <= x`), its diagonal included.
    #[test]
    fn a_triangle_blocks_only_its_half_of_the_square() {
        let bvh = Bvh::new(vec![Primitive::triangle(
            DVec3::new(-1.0, -1.0, 0.0),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
        )]);
        let through = |x: f64, y: f64| {
            bvh.occluded(DVec3::new(x, y, -1.0), DVec3::new(x, y, 1.0), [u32::MAX; 2])
        };
        for (x, y) in [
            (0.5, -0.5),
            (0.9, 0.8),
            (-0.9, -0.95),
            (0.3, 0.3),
            (0.99, -0.99),
        ] {
            assert!(through(x, y), "({x}, {y}) is on the triangle");
        }
        for (x, y) in [(-0.5, 0.5), (0.8, 0.9), (-0.95, -0.9), (-0.99, 0.99)] {
            assert!(!through(x, y), "({x}, {y}) is off the triangle");
        }
    }

    #[test]
    fn many_primitives_agree_with_brute_force() {
        // A stack of squares at various heights and offsets.
        let prims: Vec<Primitive> = (0..40)
            .map(|i| {
                let f = i as f64;
                let (o, u, v) = (
                    DVec3::new((f * 0.37).sin() * 3.0, (f * 0.91).cos() * 3.0, f * 0.25),
                    DVec3::new(0.8, 0.1, 0.0),
                    DVec3::new(0.0, 0.7, 0.2),
                );
                // Every third one a triangle: its bounds hold three corners.
                if i % 3 == 2 {
                    Primitive::triangle(o, u, v)
                } else {
                    Primitive::parallelogram(o, u, v)
                }
            })
            .collect();
        let bvh = Bvh::new(prims.clone());
        for k in 0..200 {
            let f = k as f64;
            let a = DVec3::new((f * 1.3).sin() * 4.0, (f * 0.7).cos() * 4.0, -1.0);
            let b = DVec3::new((f * 0.3).cos() * 4.0, (f * 1.9).sin() * 4.0, 11.0);
            let brute = prims.iter().any(|p| p.hit(a, b - a, 1e-9, 1.0 - 1e-9));
            assert_eq!(bvh.occluded(a, b, [u32::MAX; 2]), brute, "segment {k}");
        }
    }
}
