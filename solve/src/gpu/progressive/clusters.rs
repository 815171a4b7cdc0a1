//! Shooting clusters: small triangles of one surface shot together.
//!
//! Progressive refinement shoots patches, and a mesh has a patch per
//! triangle, so the number of batches a solve takes followed the
//! tessellation rather than the surface: the 101,400-triangle box of
//! `bench meshes` needed a shot from nearly every triangle, at one
//! hemicube (all triangles drawn) per shot. The thesis cuts a large patch
//! into as many shooters as its share of the unshot power asks for
//! (§4.3.3); here the same rule runs the other way for many small
//! triangles. Triangles of one object and material whose normals stay
//! within [`MAX_ANGLE_DEG`] of their region's first triangle, joined
//! through shared corners, form a *region* (of at least
//! [`MIN_REGION_TRIANGLES`]), which shoots like one patch;
//! inside it a binary tree of median splits along the longest axis gives
//! the pieces. A batch cuts a region into as many pieces as the region's
//! power asks for (the same count a quad of that power gets), splitting
//! the piece with the most unshot power first; a piece of several
//! triangles is one shooter (`Tiling::cluster_shooter`), a single triangle
//! is tiled as before. Wallner's system clusters the same way in spirit:
//! its lightmaps are per triangle, its shooting is by atlas region (§2).
//!
//! A mesh's patches are its triangles and the quads of two triangles that
//! form a parallelogram (`scene/pairs.rs`, `Patch::mesh`); both join
//! regions, a quad as one unit of the tree. Patches of hand-written quads
//! and boxes never do. Patches that join no region are shot on their own.

use std::collections::{BinaryHeap, HashMap};

use glam::Vec3;

use crate::gpu::placement::WorldPatch;

/// Most angle between a triangle's normal and its region's first one.
pub(super) const MAX_ANGLE_DEG: f32 = 20.0;

/// Fewest triangles a region has. A surface of a few large triangles (a
/// wall cut into two) is tiled per triangle as finely as a quad is, and
/// incremental redistribution takes light back per triangle (thesis
/// Alg. 4.3 reshoots each patch as a batch tiles it): had a cluster shot
/// it, what is taken back would be discretized otherwise than what was
/// given, and the mesh box's incremental state after a move read 3.41%
/// from a from-scratch solve instead of under 2%
/// (`a_mesh_box_after_a_move_matches_a_from_scratch_solve`).
pub(super) const MIN_REGION_TRIANGLES: usize = 8;

/// A node of a region's tree: the members `order[start..end]`, and its
/// two halves unless it is one triangle.
#[derive(Debug, Clone, Copy)]
struct Node {
    start: u32,
    end: u32,
    children: Option<[u32; 2]>,
}

/// The regions of a scene's triangles and their trees.
#[derive(Debug, Clone, Default)]
pub(super) struct Clusters {
    /// Patch ids, each node's members contiguous (uploaded to the GPU as
    /// `members`: a cluster shooter names its range).
    order: Vec<u32>,
    nodes: Vec<Node>,
    /// The root node of every region of at least two triangles.
    roots: Vec<u32>,
    /// Per patch, its region (index into `roots`), or `u32::MAX`.
    region_of: Vec<u32>,
}

/// What a batch shoots of one unit: a patch on its own (tiled as before)
/// or a piece of a region (members `start..end` of the order).
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Piece {
    Patch(u32, f32),
    Members { start: u32, end: u32, power: f32 },
}

impl Clusters {
    /// Regions of `patches` (placed at the solver's first poses; a region
    /// moves rigidly with its object): `objects` and `materials` per patch,
    /// and which patches are part of a mesh (`Patch::mesh`: its triangles
    /// and the pairs of them that share a chart); only those join regions.
    pub(super) fn build(
        patches: &[WorldPatch],
        objects: &[u32],
        materials: &[u32],
        mesh: &[bool],
    ) -> Self {
        let n = patches.len();
        let mut clusters = Self {
            region_of: vec![u32::MAX; n],
            ..Self::default()
        };
        let triangles: Vec<u32> = (0..n as u32)
            .filter(|&p| mesh.get(p as usize).copied().unwrap_or(false))
            .collect();
        if triangles.len() < 2 {
            return clusters;
        }
        // Corners shared by triangles, up to a hair of the scene's size.
        let extent = super::placement::extent(patches);
        let quantum = (extent * 1e-5).max(f32::MIN_POSITIVE);
        let key = |p: Vec3| {
            let q = (p / quantum).round();
            (q.x as i64, q.y as i64, q.z as i64)
        };
        let mut at_corner: HashMap<(i64, i64, i64), Vec<u32>> = HashMap::new();
        for &t in &triangles {
            for c in patches[t as usize].corners() {
                at_corner.entry(key(c)).or_default().push(t);
            }
        }
        let cos_max = MAX_ANGLE_DEG.to_radians().cos();
        let mut assigned = vec![false; n];
        let mut stack = Vec::new();
        for &seed in &triangles {
            if assigned[seed as usize] {
                continue;
            }
            assigned[seed as usize] = true;
            let s = seed as usize;
            let normal = patches[s].normal;
            let mut region = vec![seed];
            stack.push(seed);
            while let Some(t) = stack.pop() {
                for c in patches[t as usize].corners() {
                    let Some(next) = at_corner.get(&key(c)) else {
                        continue;
                    };
                    for &m in next {
                        let mu = m as usize;
                        if assigned[mu]
                            || objects[mu] != objects[s]
                            || materials[mu] != materials[s]
                            || patches[mu].normal.dot(normal) < cos_max
                        {
                            continue;
                        }
                        assigned[mu] = true;
                        region.push(m);
                        stack.push(m);
                    }
                }
            }
            if region.len() < MIN_REGION_TRIANGLES {
                continue;
            }
            let r = clusters.roots.len() as u32;
            for &m in &region {
                clusters.region_of[m as usize] = r;
            }
            let start = clusters.order.len() as u32;
            let mut units = quads(&region, patches, &key);
            let root = clusters.split(&mut units, start);
            clusters.roots.push(root);
        }
        clusters
    }

    /// Appends `units` to the order as one node, halved along the longest
    /// axis of their centres until single units, a quad's unit then into
    /// its two triangles; returns the node. `start` is where they begin in
    /// the order.
    fn split(&mut self, members: &mut [(Unit2, Vec3)], start: u32) -> u32 {
        let end = start + members.iter().map(|(u, _)| unit_size(u)).sum::<u32>();
        let id = self.nodes.len() as u32;
        self.nodes.push(Node {
            start,
            end,
            children: None,
        });
        if members.len() == 1 {
            let [a, b] = members[0].0;
            if b == u32::MAX {
                self.order.push(a);
            } else {
                let halves = [a, b].map(|t| {
                    let at = self.order.len() as u32;
                    self.order.push(t);
                    self.nodes.push(Node {
                        start: at,
                        end: at + 1,
                        children: None,
                    });
                    self.nodes.len() as u32 - 1
                });
                self.nodes[id as usize].children = Some(halves);
            }
            return id;
        }
        let (lo, hi) = members.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), (_, c)| (lo.min(*c), hi.max(*c)),
        );
        let size = hi - lo;
        let axis = if size.x >= size.y && size.x >= size.z {
            0
        } else if size.y >= size.z {
            1
        } else {
            2
        };
        let mid = members.len() / 2;
        members.select_nth_unstable_by(mid, |a, b| {
            a.1[axis].total_cmp(&b.1[axis]).then(a.0[0].cmp(&b.0[0]))
        });
        let (left, right) = members.split_at_mut(mid);
        let left_size: u32 = left.iter().map(|(u, _)| unit_size(u)).sum();
        let a = self.split(left, start);
        let b = self.split(right, start + left_size);
        self.nodes[id as usize].children = Some([a, b]);
        id
    }

    /// Whether any region exists.
    pub(super) fn is_empty(&self) -> bool {
        self.roots.is_empty()
    }

    /// Patch ids in tree order (the GPU's `members`).
    pub(super) fn order(&self) -> &[u32] {
        &self.order
    }

    /// Members `start..end` of the order.
    pub(super) fn members(&self, start: u32, end: u32) -> &[u32] {
        &self.order[start as usize..end as usize]
    }

    /// The units a batch chooses from, with their unshot power: every
    /// region (the sum of its triangles' powers) and every patch in no
    /// region. `powers` holds one value per patch.
    pub(super) fn units(&self, powers: &[f32]) -> Vec<(Unit, f32)> {
        let mut region_power = vec![0.0f64; self.roots.len()];
        let mut units = Vec::new();
        for (p, &w) in powers.iter().enumerate() {
            match self.region_of.get(p) {
                Some(&r) if r != u32::MAX => region_power[r as usize] += f64::from(w),
                _ => units.push((Unit::Patch(p as u32), w)),
            }
        }
        units.extend(
            region_power
                .iter()
                .enumerate()
                .map(|(r, &w)| (Unit::Region(r as u32), w as f32)),
        );
        units
    }

    /// Region `r` cut into at most `wanted` pieces, always halving the
    /// piece with the most unshot power (`powers` per patch) that is more
    /// than one triangle. Pieces holding no power are left out.
    pub(super) fn cut(&self, r: u32, wanted: usize, powers: &[f32]) -> Vec<Piece> {
        let power = |node: &Node| -> f64 {
            self.order[node.start as usize..node.end as usize]
                .iter()
                .map(|&p| f64::from(powers.get(p as usize).copied().unwrap_or(0.0)))
                .sum()
        };
        #[derive(PartialEq)]
        struct Open(f64, u32);
        impl Eq for Open {}
        impl PartialOrd for Open {
            fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
                Some(self.cmp(other))
            }
        }
        impl Ord for Open {
            fn cmp(&self, other: &Self) -> std::cmp::Ordering {
                self.0.total_cmp(&other.0).then(other.1.cmp(&self.1))
            }
        }
        let root = self.roots[r as usize];
        let mut open = BinaryHeap::new();
        let mut done = Vec::new();
        open.push(Open(power(&self.nodes[root as usize]), root));
        while let Some(Open(w, id)) = open.pop() {
            let node = self.nodes[id as usize];
            match node.children {
                Some([a, b]) if open.len() + done.len() + 1 < wanted.max(1) => {
                    for c in [a, b] {
                        open.push(Open(power(&self.nodes[c as usize]), c));
                    }
                }
                _ => done.push((id, w)),
            }
        }
        done.sort_by_key(|&(id, _)| self.nodes[id as usize].start);
        done.into_iter()
            .filter(|&(_, w)| w > 0.0)
            .map(|(id, w)| {
                let node = self.nodes[id as usize];
                if node.end - node.start == 1 {
                    Piece::Patch(self.order[node.start as usize], w as f32)
                } else {
                    Piece::Members {
                        start: node.start,
                        end: node.end,
                        power: w as f32,
                    }
                }
            })
            .collect()
    }
}

/// A region's triangles as the tree splits them: a pair that forms a
/// quad, or one triangle (`[t, u32::MAX]`).
type Unit2 = [u32; 2];

/// Triangles in a unit.
fn unit_size(unit: &Unit2) -> u32 {
    if unit[1] == u32::MAX { 1 } else { 2 }
}

/// The triangles of `region` paired into quads where two share an edge
/// that is the longest of both (a quad cut along its diagonal, as
/// exporters triangulate quads), each unit with its area-weighted centre:
/// the tree then never separates a quad's halves until it reaches them,
/// so a piece of a tessellated grid covers the rectangle its shooter
/// stands in for. `key` names a corner.
fn quads<K: std::hash::Hash + Ord>(
    region: &[u32],
    patches: &[WorldPatch],
    key: &impl Fn(Vec3) -> K,
) -> Vec<(Unit2, Vec3)> {
    // The longest edge of each triangle, by its corners' keys.
    let mut by_edge: HashMap<(K, K), Vec<u32>> = HashMap::new();
    let longest = |t: u32| {
        let c = patches[t as usize].corners();
        (0..3)
            .max_by(|&i, &j| {
                let len = |i: usize| (c[(i + 1) % 3] - c[i]).length_squared();
                len(i).total_cmp(&len(j))
            })
            .map(|i| (c[i], c[(i + 1) % 3]))
            .unwrap_or((c[0], c[1]))
    };
    for &t in region.iter().filter(|&&t| patches[t as usize].triangle) {
        let (a, b) = longest(t);
        // Both triangles name the edge alike: the lesser corner first.
        let (a, b) = (key(a), key(b));
        let edge = if a <= b { (a, b) } else { (b, a) };
        by_edge.entry(edge).or_default().push(t);
    }
    let mut partner: HashMap<u32, u32> = HashMap::new();
    for ts in by_edge.values() {
        if let [a, b] = ts[..] {
            partner.insert(a, b);
            partner.insert(b, a);
        }
    }
    let area = |t: u32| {
        let p = &patches[t as usize];
        p.u.cross(p.v).length() * if p.triangle { 0.5 } else { 1.0 }
    };
    let mut units = Vec::with_capacity(region.len());
    for &t in region {
        match partner.get(&t) {
            Some(&m) if m < t => {}
            Some(&m) => {
                let (wa, wb) = (area(t), area(m));
                let centre = (patches[t as usize].centre() * wa
                    + patches[m as usize].centre() * wb)
                    / (wa + wb).max(f32::MIN_POSITIVE);
                units.push(([t, m], centre));
            }
            None => units.push(([t, u32::MAX], patches[t as usize].centre())),
        }
    }
    units
}

/// What a batch picks first: a patch in no region, or a region.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum Unit {
    Patch(u32),
    Region(u32),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `k x k` grid of unit cells in the plane z = 0, two triangles
    /// each, plus a triangle standing up at its side.
    fn grid(k: u32) -> Vec<WorldPatch> {
        let mut patches = Vec::new();
        let tri = |o: Vec3, u: Vec3, v: Vec3| WorldPatch {
            origin: o,
            u,
            v,
            normal: u.cross(v).normalize(),
            first: 0,
            w: 2,
            h: 2,
            triangle: true,
            lightmap: None,
        };
        for j in 0..k {
            for i in 0..k {
                let o = Vec3::new(i as f32, j as f32, 0.0);
                // (0,0) (1,0) (1,1) and (0,0) (1,1) (0,1).
                patches.push(tri(o, Vec3::X, Vec3::Y));
                patches.push(tri(o, Vec3::new(1.0, 1.0, 0.0), Vec3::new(-1.0, 0.0, 0.0)));
            }
        }
        patches.push(tri(Vec3::ZERO, Vec3::X, Vec3::Z));
        patches
    }

    #[test]
    fn a_planar_grid_is_one_region_and_a_wall_beside_it_another() {
        let patches = grid(4);
        let n = patches.len();
        let clusters = Clusters::build(&patches, &vec![0; n], &vec![0; n], &vec![true; n]);
        // 32 floor triangles in one region; the standing triangle shares
        // corners with the floor but faces another way: on its own.
        assert_eq!(clusters.roots.len(), 1);
        assert!(clusters.region_of[..n - 1].iter().all(|&r| r == 0));
        assert_eq!(clusters.region_of[n - 1], u32::MAX);
        let mut order = clusters.order().to_vec();
        order.sort_unstable();
        assert_eq!(order, (0..n as u32 - 1).collect::<Vec<_>>());
    }

    #[test]
    fn a_quad_s_two_triangles_stay_together_until_its_piece_is_split() {
        let patches = grid(4);
        let n = patches.len();
        let clusters = Clusters::build(&patches, &vec![0; n], &vec![0; n], &vec![true; n]);
        let powers = vec![1.0; n];
        // 16 pieces of 32 triangles: every piece is one cell's two halves.
        for piece in clusters.cut(0, 16, &powers) {
            let Piece::Members { start, end, .. } = piece else {
                panic!("a single triangle: {piece:?}");
            };
            let mut members = clusters.members(start, end).to_vec();
            members.sort_unstable();
            assert_eq!(members.len(), 2);
            assert_eq!(members[0] / 2, members[1] / 2, "{members:?}");
        }
    }

    #[test]
    fn other_materials_and_objects_make_other_regions() {
        let patches = grid(4);
        let n = patches.len();
        // The first row of cells (8 triangles) in another material.
        let mut materials = vec![0; n];
        materials[..8].fill(1);
        let clusters = Clusters::build(&patches, &vec![0; n], &materials, &vec![true; n]);
        assert_eq!(clusters.roots.len(), 2);
        assert_ne!(clusters.region_of[0], clusters.region_of[8]);
        let mut objects = vec![0; n];
        objects[2] = 1;
        let clusters = Clusters::build(&patches, &objects, &vec![0; n], &vec![true; n]);
        assert_eq!(clusters.region_of[2], u32::MAX);
        assert_ne!(clusters.region_of[3], u32::MAX);
    }

    #[test]
    fn a_surface_of_few_triangles_is_no_region() {
        let patches = grid(1);
        let n = patches.len();
        let clusters = Clusters::build(&patches, &vec![0; n], &vec![0; n], &vec![true; n]);
        assert!(clusters.is_empty());
        assert!(clusters.region_of.iter().all(|&r| r == u32::MAX));
    }

    #[test]
    fn a_region_is_cut_where_the_power_is() {
        let patches = grid(4);
        let n = patches.len();
        let clusters = Clusters::build(&patches, &vec![0; n], &vec![0; n], &vec![true; n]);
        // All the power on triangle 0: cutting into three pieces halves
        // towards it, and pieces without power are left out.
        let mut powers = vec![0.0; n];
        powers[0] = 1.0;
        let pieces = clusters.cut(0, 3, &powers);
        assert_eq!(pieces.len(), 1);
        let held = |p: &Piece| match *p {
            Piece::Patch(id, _) => vec![id],
            Piece::Members { start, end, .. } => clusters.members(start, end).to_vec(),
        };
        assert!(held(&pieces[0]).contains(&0));
        assert!(held(&pieces[0]).len() <= 8, "{:?}", held(&pieces[0]));
        // Uniform power: as many pieces as asked, together every triangle once.
        let powers = vec![1.0; n];
        for wanted in [1, 2, 5, 32, 100] {
            let pieces = clusters.cut(0, wanted, &powers);
            assert_eq!(pieces.len(), wanted.min(n - 1));
            let mut all: Vec<u32> = pieces.iter().flat_map(held).collect();
            all.sort_unstable();
            assert_eq!(all, (0..n as u32 - 1).collect::<Vec<_>>());
        }
    }
}
