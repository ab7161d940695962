//! The DDO octree (Bernardini et al. §3.1, Fig. 5): a cube around the
//! scene's static triangles, split into eight while a node holds more than
//! [`OctreeParams::leaf_triangles`], each leaf listing the objects that
//! have a triangle in it, and each face of each node carrying its
//! occlusion masks (one per partition of [`Regions`]).
//!
//! A triangle goes to every child its box touches (closed boxes), so every
//! point of every triangle lies in a leaf that lists its object: a leaf
//! proved hidden hides everything of every object inside it.

use glam::DVec3;

use super::regions::Regions;
use super::solid::{Solid, SolidRect};
use crate::geom::Aabb;
use crate::scene::Scene;

/// How the octree is cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OctreeParams {
    /// A node with more triangles than this is split.
    pub leaf_triangles: usize,
    /// Nodes this deep are never split.
    pub max_depth: u32,
}

impl OctreeParams {
    /// The leaf sizes a user may ask for: below 16 triangles a leaf's faces
    /// add little but nodes, and the bake grows with them.
    pub const LEAF_TRIANGLES: std::ops::RangeInclusive<usize> = 16..=1_000_000;

    /// The default cut with leaves of at most `n` triangles (the paper's
    /// threshold), or why `n` is refused.
    pub fn with_leaf_triangles(n: usize) -> Result<OctreeParams, String> {
        if !Self::LEAF_TRIANGLES.contains(&n) {
            return Err(format!(
                "{n} is not a whole number from {} to {}",
                Self::LEAF_TRIANGLES.start(),
                Self::LEAF_TRIANGLES.end()
            ));
        }
        Ok(OctreeParams {
            leaf_triangles: n,
            ..OctreeParams::default()
        })
    }
}

impl Default for OctreeParams {
    fn default() -> Self {
        OctreeParams {
            leaf_triangles: 256,
            max_depth: 8,
        }
    }
}

/// One node: an axis-aligned cube.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    /// Its lowest corner, scene-local.
    pub min: DVec3,
    /// Its edge length.
    pub size: f64,
    /// The first of its eight children (child `k` holds the upper half
    /// along axis `i` when bit `i` of `k` is set); 0 for a leaf.
    pub children: u32,
    /// Its objects' range of [`Octree::objects`] (leaves only).
    pub objects: [u32; 2],
}

impl Node {
    /// Its highest corner.
    pub fn max(&self) -> DVec3 {
        self.min + DVec3::splat(self.size)
    }

    /// Whether it has no children.
    pub fn is_leaf(&self) -> bool {
        self.children == 0
    }

    /// The `f32` box that holds it (rounded outwards).
    pub fn bounds(&self) -> Aabb {
        Aabb::enclosing(self.min, self.max())
    }

    /// The centre.
    pub fn centre(&self) -> DVec3 {
        self.min + DVec3::splat(self.size * 0.5)
    }
}

/// A face of a node: `axis` and `side` (0: the face at `min[axis]`, 1: at
/// `max[axis]`), as index `2 × axis + side` of a node's masks.
pub fn face_index(axis: usize, side: usize) -> usize {
    2 * axis + side
}

/// The octree with its masks.
#[derive(Clone, Debug, PartialEq)]
pub struct Octree {
    pub(super) nodes: Vec<Node>,
    pub(super) objects: Vec<u32>,
    /// Per node, per face, the 32-region mask.
    pub(super) masks32: Vec<[u32; 6]>,
    /// Per node, per face, the 64-region mask.
    pub(super) masks64: Vec<[u64; 6]>,
    /// Rectangles inside the scene's large closed surfaces ([`super::solid`]).
    pub(super) solids: Vec<Solid>,
}

/// An octree being built: the nodes and, per leaf, its triangles (what the
/// bake's validity test searches; not kept after).
pub struct Skeleton {
    /// The nodes, root first; children of a node are consecutive.
    pub nodes: Vec<Node>,
    /// Leaf objects.
    pub objects: Vec<u32>,
    /// Per node, its range of `triangles` (leaves only).
    pub triangle_ranges: Vec<[u32; 2]>,
    /// Leaf triangles (indices into the triangle list it was built from).
    pub triangles: Vec<u32>,
}

impl Skeleton {
    /// The octree over `boxes` (one per triangle, scene-local) whose
    /// triangles belong to `owner`; `None` when there are none.
    pub fn build(boxes: &[(DVec3, DVec3)], owner: &[u32], params: OctreeParams) -> Option<Skeleton> {
        let (lo, hi) = boxes.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), (a, b)| (lo.min(*a), hi.max(*b)),
        );
        if boxes.is_empty() || !lo.is_finite() || !hi.is_finite() {
            return None;
        }
        // A cube, a hair larger than the box so that rounding in `max()`
        // cannot leave a triangle's corner outside.
        let extent = (hi - lo).max_element();
        let size = extent * (1.0 + 1e-9) + extent.max(lo.abs().max_element()) * 1e-12 + 1e-30;
        let mut s = Skeleton {
            nodes: vec![Node {
                min: lo,
                size,
                children: 0,
                objects: [0, 0],
            }],
            objects: Vec::new(),
            triangle_ranges: vec![[0, 0]],
            triangles: Vec::new(),
        };
        let all: Vec<u32> = (0..boxes.len() as u32).collect();
        s.split(0, all, 0, boxes, owner, params);
        Some(s)
    }

    fn split(
        &mut self,
        at: usize,
        tris: Vec<u32>,
        depth: u32,
        boxes: &[(DVec3, DVec3)],
        owner: &[u32],
        params: OctreeParams,
    ) {
        let node = self.nodes[at];
        if tris.len() <= params.leaf_triangles || depth >= params.max_depth {
            let start = self.triangles.len() as u32;
            self.triangles.extend_from_slice(&tris);
            self.triangle_ranges[at] = [start, self.triangles.len() as u32];
            let mut ids: Vec<u32> = tris.iter().map(|&t| owner[t as usize]).collect();
            ids.sort_unstable();
            ids.dedup();
            let start = self.objects.len() as u32;
            self.objects.extend(ids);
            self.nodes[at].objects = [start, self.objects.len() as u32];
            return;
        }
        let half = node.size * 0.5;
        let first = self.nodes.len();
        self.nodes[at].children = first as u32;
        let mut lists: [Vec<u32>; 8] = Default::default();
        for (k, list) in lists.iter_mut().enumerate() {
            let offset = DVec3::new(
                (k & 1) as f64 * half,
                ((k >> 1) & 1) as f64 * half,
                ((k >> 2) & 1) as f64 * half,
            );
            let min = node.min + offset;
            self.nodes.push(Node {
                min,
                size: half,
                children: 0,
                objects: [0, 0],
            });
            self.triangle_ranges.push([0, 0]);
            let max = min + DVec3::splat(half);
            *list = tris
                .iter()
                .copied()
                .filter(|&t| {
                    let (a, b) = boxes[t as usize];
                    a.cmple(max).all() && b.cmpge(min).all()
                })
                .collect();
        }
        drop(tris);
        for (k, list) in lists.into_iter().enumerate() {
            self.split(first + k, list, depth + 1, boxes, owner, params);
        }
    }

    /// The triangles of leaf `node`.
    pub fn leaf_triangles(&self, node: usize) -> &[u32] {
        let [a, b] = self.triangle_ranges[node];
        &self.triangles[a as usize..b as usize]
    }

    /// Calls `visit` with every leaf whose cube, grown by `grow`, `segment`
    /// may meet; `stack` is the walk's (kept by the caller, so that the
    /// bake's millions of walks allocate nothing).
    pub fn leaves_along(
        &self,
        segment: &Segment,
        grow: f64,
        stack: &mut Vec<u32>,
        mut visit: impl FnMut(usize),
    ) {
        let g = DVec3::splat(grow);
        // Start at the smallest node whose cube holds the segment's box
        // grown by twice `grow`: no cube outside it, grown by `grow`, can
        // reach the segment, and the levels above cost a bake most of its
        // box tests.
        let (lo, hi) = (segment.lo() - g * 2.0, segment.hi() + g * 2.0);
        let mut start = 0u32;
        loop {
            let node = &self.nodes[start as usize];
            if node.is_leaf() {
                break;
            }
            let mid = node.centre();
            let mut k = 0;
            let mut inside = true;
            for axis in 0..3 {
                if lo[axis] > mid[axis] {
                    k |= 1 << axis;
                } else if hi[axis] >= mid[axis] {
                    inside = false;
                }
            }
            if !inside {
                break;
            }
            start = node.children + k;
        }
        stack.clear();
        let root = &self.nodes[start as usize];
        if segment.meets_box(root.min - g, root.max() + g) {
            stack.push(start);
        }
        // Every node on the stack meets the segment. The eight children's
        // slabs are two a side along each axis: taken from the lowest and
        // highest child (whose bounds are every child's, bit for bit),
        // they decide each child as `meets_box` on its own box would.
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n as usize];
            if node.is_leaf() {
                visit(n as usize);
                continue;
            }
            let (low, high) = (
                &self.nodes[node.children as usize],
                &self.nodes[node.children as usize + 7],
            );
            let (lo, hi) = ([low.min - g, high.min - g], [low.max() + g, high.max() + g]);
            let mut slabs = [[None; 2]; 3];
            for (axis, halves) in slabs.iter_mut().enumerate() {
                for (side, slab) in halves.iter_mut().enumerate() {
                    *slab = segment.slab(axis, lo[side][axis], hi[side][axis]);
                }
            }
            for k in 0..8u32 {
                let child = (0..3).map(|axis| slabs[axis][(k >> axis & 1) as usize]);
                if Segment::within(child).is_some_and(Segment::meets) {
                    stack.push(node.children + k);
                }
            }
        }
    }

    /// The finished octree with the masks found for each node.
    pub fn finish(self, masks: Vec<([u32; 6], [u64; 6])>, solids: Vec<Solid>) -> Octree {
        let (masks32, masks64) = masks.into_iter().unzip();
        Octree {
            nodes: self.nodes,
            objects: self.objects,
            masks32,
            masks64,
            solids,
        }
    }
}

impl Octree {
    /// The nodes, root first.
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// The objects of leaf `node`.
    pub fn objects_of(&self, node: &Node) -> &[u32] {
        &self.objects[node.objects[0] as usize..node.objects[1] as usize]
    }

    /// Node `n`'s mask for face `face` ([`face_index`]) with `regions`, widened to 64 bits.
    pub fn mask(&self, n: usize, face: usize, regions: Regions) -> u64 {
        match regions {
            Regions::R32 => self.masks32[n][face] as u64,
            Regions::R64 => self.masks64[n][face],
        }
    }

    /// How many faces are valid from at least one region of `regions`.
    pub fn valid_faces(&self, regions: Regions) -> usize {
        (0..self.nodes.len())
            .flat_map(|n| (0..6).map(move |f| (n, f)))
            .filter(|&(n, f)| self.mask(n, f, regions) != 0)
            .count()
    }

    /// The bytes of the bake payload (`proto/bake-format.md`, kind `ddo`).
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(&(self.nodes.len() as u32).to_le_bytes());
        out.extend_from_slice(&(self.objects.len() as u32).to_le_bytes());
        for (i, n) in self.nodes.iter().enumerate() {
            for v in n.min.to_array() {
                out.extend_from_slice(&v.to_le_bytes());
            }
            out.extend_from_slice(&n.size.to_le_bytes());
            out.extend_from_slice(&n.children.to_le_bytes());
            out.extend_from_slice(&n.objects[0].to_le_bytes());
            out.extend_from_slice(&n.objects[1].to_le_bytes());
            for m in self.masks32[i] {
                out.extend_from_slice(&m.to_le_bytes());
            }
            for m in self.masks64[i] {
                out.extend_from_slice(&m.to_le_bytes());
            }
        }
        for o in &self.objects {
            out.extend_from_slice(&o.to_le_bytes());
        }
        out.extend_from_slice(&(self.solids.len() as u32).to_le_bytes());
        for solid in &self.solids {
            for v in solid.lo.to_array().into_iter().chain(solid.hi.to_array()) {
                out.extend_from_slice(&v.to_le_bytes());
            }
            out.extend_from_slice(&solid.object.unwrap_or(u32::MAX).to_le_bytes());
            out.push(u8::from(solid.large));
            out.extend_from_slice(&(solid.rects.len() as u32).to_le_bytes());
            for r in &solid.rects {
                let values = r.corners.iter().chain([&r.normal]).flat_map(|p| p.to_array());
                for v in values.chain([r.d]) {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        out
    }

    /// The solid occluders ([`super::solid`]).
    pub fn solids(&self) -> &[Solid] {
        &self.solids
    }

    /// The octree of a payload, checked against `scene` (every object id
    /// exists, every child and object range lies inside the arrays).
    pub fn decode(bytes: &[u8], scene: &Scene) -> Result<Octree, String> {
        let mut r = Reader { bytes, at: 0 };
        let nodes = r.u32()? as usize;
        let objects = r.u32()? as usize;
        if nodes == 0 || bytes.len() < 8 + nodes * NODE_BYTES + objects * 4 + 4 {
            return Err("the ddo payload's length disagrees with its counts".into());
        }
        let mut tree = Octree {
            nodes: Vec::with_capacity(nodes),
            objects: Vec::with_capacity(objects),
            masks32: Vec::with_capacity(nodes),
            masks64: Vec::with_capacity(nodes),
            solids: Vec::new(),
        };
        for _ in 0..nodes {
            let min = DVec3::new(r.f64()?, r.f64()?, r.f64()?);
            let size = r.f64()?;
            let node = Node {
                min,
                size,
                children: r.u32()?,
                objects: [r.u32()?, r.u32()?],
            };
            let children_fit = node.children == 0
                || (node.children as usize > tree.nodes.len() && node.children as usize + 8 <= nodes);
            let objects_fit = node.objects[0] <= node.objects[1] && node.objects[1] as usize <= objects;
            if !(min.is_finite() && size.is_finite() && size > 0.0 && children_fit && objects_fit) {
                return Err(format!("ddo node {} is malformed", tree.nodes.len()));
            }
            tree.nodes.push(node);
            let mut m32 = [0u32; 6];
            for m in &mut m32 {
                *m = r.u32()?;
            }
            let mut m64 = [0u64; 6];
            for m in &mut m64 {
                *m = r.u64()?;
            }
            tree.masks32.push(m32);
            tree.masks64.push(m64);
        }
        for _ in 0..objects {
            let id = r.u32()?;
            if id as usize >= scene.objects().len() {
                return Err(format!("the ddo payload names object {id}, which the scene has not"));
            }
            tree.objects.push(id);
        }
        let solids = r.u32()?;
        for _ in 0..solids {
            let lo = DVec3::new(r.f64()?, r.f64()?, r.f64()?);
            let hi = DVec3::new(r.f64()?, r.f64()?, r.f64()?);
            let object = Some(r.u32()?).filter(|&o| o != u32::MAX);
            if object.is_some_and(|o| o as usize >= scene.objects().len()) {
                return Err(format!("ddo solid {} names an object the scene has not", tree.solids.len()));
            }
            let large = match r.take::<1>()? {
                [0] => false,
                [1] => true,
                _ => return Err(format!("ddo solid {} is malformed", tree.solids.len())),
            };
            let count = r.u32()? as usize;
            // Each rectangle takes 128 bytes: a count the rest cannot hold
            // is refused before anything is reserved for it.
            if count > (bytes.len() - r.at) / 128 || !(lo.is_finite() && hi.is_finite() && lo.cmple(hi).all()) {
                return Err(format!("ddo solid {} is malformed", tree.solids.len()));
            }
            let mut rects = Vec::with_capacity(count);
            for _ in 0..count {
                let mut point = || -> Result<DVec3, String> { Ok(DVec3::new(r.f64()?, r.f64()?, r.f64()?)) };
                let corners = [point()?, point()?, point()?, point()?];
                let normal = point()?;
                let d = r.f64()?;
                if !(corners.iter().all(|c| c.is_finite()) && normal.is_finite() && d.is_finite()) {
                    return Err(format!("a rectangle of ddo solid {} is malformed", tree.solids.len()));
                }
                rects.push(SolidRect { corners, normal, d });
            }
            tree.solids.push(Solid {
                lo,
                hi,
                object,
                large,
                rects,
            });
        }
        if r.at != bytes.len() {
            return Err("the ddo payload's length disagrees with its counts".into());
        }
        Ok(tree)
    }
}

/// Bytes of one node in the payload.
const NODE_BYTES: usize = 8 * 4 + 4 * 3 + 4 * 6 + 8 * 6;

/// A segment `p q` set up for many box tests (the bake tests each of its
/// segments against hundreds of boxes): the reciprocal of its direction is
/// taken once.
#[derive(Clone, Copy, Debug)]
pub struct Segment {
    p: DVec3,
    q: DVec3,
    /// `1 / (q − p)` per axis; infinite where the segment is flat along it.
    inv: DVec3,
}

impl Segment {
    /// The segment from `p` to `q`.
    pub fn new(p: DVec3, q: DVec3) -> Segment {
        Segment {
            p,
            q,
            inv: (q - p).recip(),
        }
    }

    /// The lowest corner of its box.
    pub fn lo(&self) -> DVec3 {
        self.p.min(self.q)
    }

    /// The highest corner of its box.
    pub fn hi(&self) -> DVec3 {
        self.p.max(self.q)
    }

    /// Whether it may meet the box `[lo, hi]` (slab clipping; a caller that
    /// must not miss a meeting grows the box by a margin far above the
    /// rounding here: a product by the reciprocal is within two roundings
    /// of the quotient, and the `1e-9` slack on the segment's parameter is
    /// seven orders above that).
    pub fn meets_box(&self, lo: DVec3, hi: DVec3) -> bool {
        Segment::within((0..3).map(|k| self.slab(k, lo[k], hi[k]))).is_some_and(Segment::meets)
    }

    /// The parameters `[t₀, t₁]` of the segment (`[0, 1]`) narrowed to
    /// each slab in turn, or `None` when a slab misses the line.
    fn within(slabs: impl Iterator<Item = Option<[f64; 2]>>) -> Option<[f64; 2]> {
        let mut t = [0.0f64, 1.0f64];
        for s in slabs {
            let s = s?;
            t = [t[0].max(s[0]), t[1].min(s[1])];
        }
        Some(t)
    }

    /// The parameters `[t₀, t₁]` of its line between the planes `lo` and
    /// `hi` along `axis` (unbounded when it runs parallel to them), or
    /// `None` when it runs parallel outside them.
    fn slab(&self, axis: usize, lo: f64, hi: f64) -> Option<[f64; 2]> {
        let (p, inv) = (self.p[axis], self.inv[axis]);
        if inv.is_infinite() {
            // Written as a test for outside, so that a NaN counts as inside.
            return (!(p < lo || p > hi)).then_some([f64::NEG_INFINITY, f64::INFINITY]);
        }
        let (a, b) = ((lo - p) * inv, (hi - p) * inv);
        Some([a.min(b), a.max(b)])
    }

    /// Whether the parameters `t` left by the slabs are a piece of the
    /// segment, with the slack the callers rely on.
    fn meets(t: [f64; 2]) -> bool {
        t[0] <= t[1] + 1e-9
    }
}

/// Little-endian reads from a payload.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let b = self
            .bytes
            .get(self.at..self.at + N)
            .ok_or("the ddo payload ends early")?;
        self.at += N;
        Ok(b.try_into().expect("N bytes"))
    }

    fn u32(&mut self) -> Result<u32, String> {
        self.take().map(u32::from_le_bytes)
    }

    fn u64(&mut self) -> Result<u64, String> {
        self.take().map(u64::from_le_bytes)
    }

    fn f64(&mut self) -> Result<f64, String> {
        self.take().map(f64::from_le_bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneBuilder;

    #[test]
    fn a_payload_decodes_to_the_octree_it_encodes_and_a_damaged_one_is_refused() {
        let mut b = SceneBuilder::new("t");
        b.begin_object("a", None);
        super::super::tests::grid_box(&mut b, DVec3::splat(-1.0), DVec3::splat(1.0), 6, None);
        b.begin_object("b", None);
        super::super::tests::grid_box(&mut b, DVec3::splat(-0.2), DVec3::splat(0.2), 2, None);
        let scene = b.finish();
        let params = OctreeParams {
            leaf_triangles: 16,
            max_depth: 4,
        };
        let tree = super::super::bake(&scene, params).expect("a bake");
        let bytes = tree.encode();
        assert_eq!(Octree::decode(&bytes, &scene), Ok(tree.clone()));
        assert!(Octree::decode(&bytes[..bytes.len() - 1], &scene).is_err(), "short");
        // Both boxes are closed: their insides hold solid occluders.
        assert!(!tree.solids().is_empty());
        // An object id the scene has not.
        let mut bad = bytes.clone();
        let last = 8 + tree.nodes.len() * NODE_BYTES + tree.objects.len() * 4 - 4;
        bad[last..last + 4].copy_from_slice(&99u32.to_le_bytes());
        assert!(Octree::decode(&bad, &scene).unwrap_err().contains("object 99"));
        // A rectangle's corner that is not a number.
        let mut bad = bytes.clone();
        let corner = bytes.len() - 16 * 8;
        bad[corner..corner + 8].copy_from_slice(&f64::NAN.to_le_bytes());
        assert!(Octree::decode(&bad, &scene).unwrap_err().contains("rectangle"));
        // Bytes left over.
        let mut long = bytes.clone();
        long.push(0);
        assert!(Octree::decode(&long, &scene).is_err(), "long");
        // A child index past the nodes.
        let mut bad = bytes.clone();
        bad[8 + 32..8 + 36].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(Octree::decode(&bad, &scene).unwrap_err().contains("node 0"));
    }

    #[test]
    fn a_segment_meets_the_boxes_it_crosses_or_touches_and_no_other() {
        let s = Segment::new(DVec3::ZERO, DVec3::new(1.0, 1.0, 0.0));
        assert!(s.meets_box(DVec3::new(0.4, 0.4, -0.1), DVec3::splat(0.6)));
        assert!(s.meets_box(DVec3::new(1.0, 1.0, -1.0), DVec3::splat(2.0)));
        assert!(!s.meets_box(DVec3::new(0.6, 0.0, -1.0), DVec3::new(1.0, 0.3, 1.0)));
        // Flat along z: only boxes spanning its z.
        assert!(!s.meets_box(DVec3::new(0.0, 0.0, 0.1), DVec3::splat(1.0)));
        // A point segment.
        let p = Segment::new(DVec3::ONE, DVec3::ONE);
        assert!(p.meets_box(DVec3::ZERO, DVec3::ONE));
        assert!(!p.meets_box(DVec3::ZERO, DVec3::splat(0.999)));
    }

    #[test]
    fn the_walk_along_a_segment_finds_the_same_leaves_from_its_start_node() {
        // A grid of small triangles, split deep, and segments of every
        // length: the leaves found are those whose grown cube the segment
        // meets, by brute force over all leaves.
        let mut boxes = Vec::new();
        for i in 0..16 {
            for j in 0..16 {
                for k in 0..4 {
                    let lo = DVec3::new(i as f64, j as f64, 4.0 * k as f64) * 0.25;
                    boxes.push((lo, lo + DVec3::splat(0.1)));
                }
            }
        }
        let owner = vec![0; boxes.len()];
        let params = OctreeParams {
            leaf_triangles: 2,
            max_depth: 8,
        };
        let tree = Skeleton::build(&boxes, &owner, params).unwrap();
        let mut stack = Vec::new();
        let grow = 1e-3;
        for (p, q) in [
            (DVec3::new(0.1, 0.1, 0.1), DVec3::new(0.12, 0.1, 0.1)),
            (DVec3::new(0.3, 2.0, 1.0), DVec3::new(3.0, 0.5, 2.0)),
            (DVec3::new(-1.0, 1.9, 0.5), DVec3::new(1.9, 1.9, 0.5)),
            (DVec3::new(2.0, 2.0, 2.0), DVec3::new(2.0, 2.0, 2.0)),
        ] {
            let segment = Segment::new(p, q);
            let mut found = Vec::new();
            tree.leaves_along(&segment, grow, &mut stack, |n| found.push(n));
            found.sort_unstable();
            let g = DVec3::splat(grow);
            let all: Vec<usize> = (0..tree.nodes.len())
                .filter(|&n| tree.nodes[n].is_leaf())
                .filter(|&n| segment.meets_box(tree.nodes[n].min - g, tree.nodes[n].max() + g))
                .collect();
            assert_eq!(found, all, "{p} {q}");
        }
    }
}
