//! The kd-tree of Bittner et al. §2.2 over a scene's object boxes.
//!
//! Each node splits the longest axis of its cell. Candidate planes are the
//! object-box boundaries within a window around the cell's spatial median;
//! the one that splits the fewest objects wins (ties: the one nearest the
//! median). With no candidate, the median itself splits. Objects straddling
//! the plane are referenced from both sides. Recursion stops at a leaf size
//! (not counting objects that span the cell along the axis to split, which
//! no split there could separate), a depth limit, or when a split would
//! separate nothing.
//!
//! Besides its cell, every node keeps `bounds`: the union of the boxes of the
//! objects below it, each clipped to the node's cell. It is never larger than
//! the cell, and usually much smaller (a street's empty air is not in it);
//! unlike the union of whole boxes it is not spoilt by one large object (a
//! ground plane, a floor slab) that every leaf references. Every point of an
//! object's box lies in the clipped box of some leaf that references it, so
//! a node whose bounds a test rejects holds no part of any object that test
//! would accept.
//!
//! An inner node also lists the distinct objects below it, for a traversal
//! that accepts a whole subtree: its refs repeat every object once per leaf
//! that holds it, and one ground in most leaves of a city makes the repeats
//! most of them (10k city: 19,265 refs for 10,001 objects).

use std::ops::Range;

use glam::Vec3;

use crate::geom::Aabb;
use crate::scene::Scene;

/// Build limits of a [`KdTree`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KdTreeParams {
    /// A node with this many objects or fewer becomes a leaf (objects that
    /// span the node's cell along its longest axis not counted).
    pub max_leaf_objects: usize,
    /// No node is deeper than this.
    pub max_depth: u32,
    /// Width of the candidate window around the spatial median, as a share
    /// of the cell's extent on the split axis (0.25: median ± 12.5%).
    pub median_window: f32,
}

impl Default for KdTreeParams {
    fn default() -> Self {
        KdTreeParams {
            max_leaf_objects: 4,
            max_depth: 32,
            median_window: 0.25,
        }
    }
}

/// Whether a node is a leaf or how it splits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NodeKind {
    /// A leaf: its objects are `KdTree::refs()[node.refs]`.
    Leaf,
    /// An inner node split at `axis = split`; `children[0]` is below the plane.
    Inner {
        /// 0 = x, 1 = y, 2 = z.
        axis: u8,
        /// Coordinate of the splitting plane.
        split: f32,
        /// Node indices of the lower and upper child.
        children: [u32; 2],
        /// The distinct objects below, once each, ascending: a range of
        /// `KdTree::distinct` ([`KdTree::node_objects`]). A subtree accepted
        /// whole takes them rather than its refs, in which a ground or a
        /// floor slab repeats once per leaf.
        distinct: [u32; 2],
    },
}

/// One node of the tree.
#[derive(Clone, Debug, PartialEq)]
pub struct KdNode {
    /// The region of space this node partitions (children partition it exactly).
    pub cell: Aabb,
    /// Union of the boxes of the objects referenced below, each clipped to `cell`.
    pub bounds: Aabb,
    /// Node cost (§5.3): triangles of the distinct objects below.
    pub cost: u64,
    /// Object references of every leaf below, contiguous in `KdTree::refs()`;
    /// an object straddling a split appears once per leaf that holds it.
    pub refs: Range<u32>,
    /// Leaf or split.
    pub kind: NodeKind,
}

/// A kd-tree over the objects of one scene. Node 0 is the root.
#[derive(Clone, Debug)]
pub struct KdTree {
    nodes: Vec<KdNode>,
    refs: Vec<u32>,
    /// Inner nodes' distinct objects (`NodeKind::Inner::distinct`).
    distinct: Vec<u32>,
    params: KdTreeParams,
}

impl KdTree {
    /// Builds the tree over every static object ([`Object::is_static`]:
    /// with a box, not movable).
    pub fn build(scene: &Scene, params: KdTreeParams) -> KdTree {
        let objects = scene.objects();
        let items: Vec<u32> = objects
            .iter()
            .filter(|o| o.is_static())
            .map(|o| o.id)
            .collect();
        let mut b = Builder {
            boxes: objects.iter().map(|o| o.bounds).collect(),
            costs: objects.iter().map(|o| o.triangle_count() as u64).collect(),
            params,
            nodes: Vec::new(),
            refs: Vec::new(),
            distinct: Vec::new(),
        };
        let cell = items
            .iter()
            .fold(Aabb::EMPTY, |acc, &i| acc.merged(&b.boxes[i as usize]));
        if !items.is_empty() {
            b.build(cell, items, 0);
        }
        // Built by pushing: keep only what is used for the scene's life.
        b.nodes.shrink_to_fit();
        b.refs.shrink_to_fit();
        b.distinct.shrink_to_fit();
        KdTree {
            nodes: b.nodes,
            refs: b.refs,
            distinct: b.distinct,
            params,
        }
    }

    /// Every node; index 0 is the root (absent for a scene with no geometry).
    pub fn nodes(&self) -> &[KdNode] {
        &self.nodes
    }

    /// The root node, `None` for a scene with no geometry.
    pub fn root(&self) -> Option<&KdNode> {
        self.nodes.first()
    }

    /// Object references of the leaves, in depth-first order.
    pub fn refs(&self) -> &[u32] {
        &self.refs
    }

    /// The object ids a node's range of references points at (with repeats).
    pub fn node_refs(&self, node: &KdNode) -> &[u32] {
        &self.refs[node.refs.start as usize..node.refs.end as usize]
    }

    /// The distinct object ids below a node, each once, ascending (a
    /// leaf's refs are so already).
    pub fn node_objects(&self, node: &KdNode) -> &[u32] {
        match node.kind {
            NodeKind::Leaf => self.node_refs(node),
            NodeKind::Inner {
                distinct: [a, b], ..
            } => &self.distinct[a as usize..b as usize],
        }
    }

    /// The limits the tree was built with.
    pub fn params(&self) -> KdTreeParams {
        self.params
    }

    /// Checks every structural invariant; tests call it after each build.
    ///
    /// Children partition their parent's cell at the split; `bounds` is the
    /// union of the boxes below clipped to the cell, `cost` their triangles;
    /// reference ranges nest; an inner node's objects are its refs' ids once
    /// each; every sample point of every object's box lies in a leaf that
    /// references the object.
    pub fn validate(&self, scene: &Scene) -> Result<(), String> {
        let objects = scene.objects();
        let Some(root) = self.root() else {
            return match objects.iter().find(|o| o.is_static()) {
                Some(o) => Err(format!("empty tree but object {} has a box", o.id)),
                None => Ok(()),
            };
        };
        for o in objects.iter().filter(|o| o.is_static()) {
            if !root.cell.contains(&o.bounds) {
                return Err(format!("root cell does not hold object {}", o.id));
            }
            self.check_covered(o.id, &o.bounds)?;
        }
        self.check_node(0, scene, 0)
    }

    /// Checks that every sample point of `b` (corners, centre, face centres)
    /// lies in the closed cell of a leaf that references `id`. Points are
    /// located by their coordinates alone (on a split plane: both sides), not
    /// by the build's distribution rule, so a wrong rule fails here.
    fn check_covered(&self, id: u32, b: &Aabb) -> Result<(), String> {
        let c = b.center();
        let mut points: Vec<Vec3> = b.corners().to_vec();
        points.push(c);
        for axis in 0..3 {
            for end in [b.min[axis], b.max[axis]] {
                let mut p = c;
                p[axis] = end;
                points.push(p);
            }
        }
        let mut leaves = Vec::new();
        for p in points {
            leaves.clear();
            self.leaves_containing(0, p, &mut leaves);
            if !leaves
                .iter()
                .any(|&l| self.node_refs(&self.nodes[l]).contains(&id))
            {
                return Err(format!(
                    "point {p} of object {id} lies in no leaf that references it (leaves {leaves:?})"
                ));
            }
        }
        Ok(())
    }

    fn leaves_containing(&self, node: usize, p: Vec3, out: &mut Vec<usize>) {
        match self.nodes[node].kind {
            NodeKind::Leaf => out.push(node),
            NodeKind::Inner {
                axis,
                split,
                children,
                ..
            } => {
                let v = p[axis as usize];
                if v <= split {
                    self.leaves_containing(children[0] as usize, p, out);
                }
                if v >= split {
                    self.leaves_containing(children[1] as usize, p, out);
                }
            }
        }
    }

    fn check_node(&self, i: usize, scene: &Scene, depth: u32) -> Result<(), String> {
        let n = &self.nodes[i];
        let refs = self.node_refs(n);
        let mut distinct: Vec<u32> = refs.to_vec();
        distinct.sort_unstable();
        distinct.dedup();
        if self.node_objects(n) != distinct {
            return Err(format!(
                "node {i}: its objects are not its refs' ids once each, ascending"
            ));
        }
        let bounds = distinct.iter().fold(Aabb::EMPTY, |a, &o| {
            a.merged(&scene.objects()[o as usize].bounds.clipped(&n.cell))
        });
        if bounds != n.bounds {
            return Err(format!(
                "node {i}: bounds {:?} != union of its clipped objects {bounds:?}",
                n.bounds
            ));
        }
        let cost: u64 = distinct
            .iter()
            .map(|&o| scene.objects()[o as usize].triangle_count() as u64)
            .sum();
        if cost != n.cost {
            return Err(format!("node {i}: cost {} != {cost}", n.cost));
        }
        if depth > self.params.max_depth {
            return Err(format!("node {i} is deeper than {}", self.params.max_depth));
        }
        match n.kind {
            NodeKind::Leaf => Ok(()),
            NodeKind::Inner {
                axis,
                split,
                children,
                ..
            } => {
                let a = axis as usize;
                let (l, h) = (
                    &self.nodes[children[0] as usize],
                    &self.nodes[children[1] as usize],
                );
                let mut lc = n.cell;
                lc.max[a] = split;
                let mut hc = n.cell;
                hc.min[a] = split;
                if l.cell != lc || h.cell != hc {
                    return Err(format!(
                        "node {i}: children do not partition the cell at {split} on axis {a}"
                    ));
                }
                if !(n.cell.min[a] < split && split < n.cell.max[a]) {
                    return Err(format!("node {i}: split {split} is not inside the cell"));
                }
                if l.refs.start != n.refs.start
                    || l.refs.end != h.refs.start
                    || h.refs.end != n.refs.end
                {
                    return Err(format!(
                        "node {i}: children's reference ranges do not tile the parent's"
                    ));
                }
                self.check_node(children[0] as usize, scene, depth + 1)?;
                self.check_node(children[1] as usize, scene, depth + 1)
            }
        }
    }
}

/// An object whose box starts below the plane belongs to the lower child.
fn goes_low(lo: f32, split: f32) -> bool {
    lo < split
}

/// An object whose box ends above the plane belongs to the upper child; so
/// does a box lying flat on the plane, so that it is held somewhere.
fn goes_high(hi: f32, lo: f32, split: f32) -> bool {
    hi > split || (hi == split && lo == split)
}

struct Builder {
    boxes: Vec<Aabb>,
    costs: Vec<u64>,
    params: KdTreeParams,
    nodes: Vec<KdNode>,
    refs: Vec<u32>,
    distinct: Vec<u32>,
}

impl Builder {
    fn build(&mut self, cell: Aabb, items: Vec<u32>, depth: u32) -> u32 {
        let index = self.nodes.len() as u32;
        let bounds = items.iter().fold(Aabb::EMPTY, |a, &o| {
            a.merged(&self.boxes[o as usize].clipped(&cell))
        });
        let cost = items.iter().map(|&o| self.costs[o as usize]).sum();
        let start = self.refs.len() as u32;
        self.nodes.push(KdNode {
            cell,
            bounds,
            cost,
            refs: start..start,
            kind: NodeKind::Leaf,
        });
        // Objects spanning the cell along the axis a split would cut go to
        // both sides of any split: they do not count towards the leaf size,
        // or one floor slab in every cell would split the tree to its depth.
        let axis = cell.longest_axis();
        let local = items
            .iter()
            .filter(|&&o| {
                let b = &self.boxes[o as usize];
                !(b.min[axis] <= cell.min[axis] && b.max[axis] >= cell.max[axis])
            })
            .count();
        let split = (local > self.params.max_leaf_objects && depth < self.params.max_depth)
            .then(|| self.choose_split(&cell, &items))
            .flatten();
        match split {
            Some((axis, split, low, high)) => {
                let (mut lc, mut hc) = (cell, cell);
                lc.max[axis] = split;
                hc.min[axis] = split;
                let l = self.build(lc, low, depth + 1);
                let h = self.build(hc, high, depth + 1);
                let first = self.distinct.len() as u32;
                self.distinct.extend_from_slice(&items);
                self.nodes[index as usize].kind = NodeKind::Inner {
                    axis: axis as u8,
                    split,
                    children: [l, h],
                    distinct: [first, self.distinct.len() as u32],
                };
            }
            None => self.refs.extend_from_slice(&items),
        }
        self.nodes[index as usize].refs = start..self.refs.len() as u32;
        index
    }

    /// `(axis, plane, lower objects, upper objects)`, or `None` when no plane
    /// separates anything (a leaf is better than two copies of the same set).
    fn choose_split(&self, cell: &Aabb, items: &[u32]) -> Option<(usize, f32, Vec<u32>, Vec<u32>)> {
        let axis = cell.longest_axis();
        let (cmin, cmax) = (cell.min[axis], cell.max[axis]);
        if cmax.partial_cmp(&cmin) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let median = cmin + (cmax - cmin) * 0.5;
        let half = (cmax - cmin) * self.params.median_window * 0.5;
        let (wlo, whi) = (median - half, median + half);
        let mut los: Vec<f32> = items
            .iter()
            .map(|&o| self.boxes[o as usize].min[axis])
            .collect();
        let mut his: Vec<f32> = items
            .iter()
            .map(|&o| self.boxes[o as usize].max[axis])
            .collect();
        los.sort_unstable_by(f32::total_cmp);
        his.sort_unstable_by(f32::total_cmp);
        // Objects split by plane p (lo < p < hi) = #(lo < p) − #(hi ≤ p) + #(lo = hi = p);
        // the last term (boxes lying flat on p) is left out: it only makes
        // such planes look slightly better, and the count is a heuristic.
        let split_count = |p: f32| {
            los.partition_point(|&v| v < p)
                .saturating_sub(his.partition_point(|&v| v <= p))
        };
        let mut best: Option<(usize, f32, f32)> = None; // (split objects, distance to median, plane)
        for &p in los.iter().chain(his.iter()) {
            if p < wlo || p > whi || p <= cmin || p >= cmax {
                continue;
            }
            let key = (split_count(p), (p - median).abs());
            if best.is_none_or(|(c, dist, _)| key.0 < c || (key.0 == c && key.1 < dist)) {
                best = Some((key.0, key.1, p));
            }
        }
        let plane = best.map_or(median, |(_, _, p)| p);
        if !(cmin < plane && plane < cmax) {
            return None;
        }
        let (mut low, mut high) = (Vec::new(), Vec::new());
        for &o in items {
            let b = &self.boxes[o as usize];
            if goes_low(b.min[axis], plane) {
                low.push(o);
            }
            if goes_high(b.max[axis], b.min[axis], plane) {
                high.push(o);
            }
        }
        if low.len() == items.len() && high.len() == items.len() {
            return None;
        }
        Some((axis, plane, low, high))
    }
}
