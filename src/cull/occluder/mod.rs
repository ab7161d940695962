//! Occluders: large convex planar polygons, found once per scene, and the
//! ones picked for a view (Bittner et al. §2.1 and §3; Coorg–Teller).
//!
//! **Identification** ([`Occluders::find`]): a file that flags objects with
//! `extras.occluder` (walls, floors, facades; `pvsd gen` does) has its
//! flagged objects used and no others; a file without flags has every
//! object's geometry searched. Within one object, coplanar triangles that
//! share an edge exactly are merged while the union stays convex, into
//! maximal convex polygons; those above an area threshold are occluders.
//! See-through triangles never occlude. Because merged polygons are unions of
//! the object's own triangles, an occluder covers only what the object does.
//!
//! **Selection** ([`Occluders::select`]): the area-angle metric
//! `A (N · D̂) / |D|²` (the paper's `-A (N · V) / |D|²` with `V` the direction
//! to the occluder instead of the view direction: a corridor's side walls
//! face across the view and hide the most), over the occluders referenced
//! by kd leaves within `λ` of the eye, the `k` best.

mod extract;

use glam::DVec3;

use super::occlusion::tolerance::EDGE_ON_TOLERANCE;
use crate::geom::{Aabb, ConvexPolygon, Plane};
use crate::scene::Scene;
use crate::spatial::{KdTree, NodeKind};

/// One occluder polygon, scene-local.
#[derive(Clone, Debug)]
pub struct Occluder {
    /// The polygon (convex, no collinear vertices).
    pub polygon: ConvexPolygon,
    /// Its plane.
    pub plane: Plane,
    /// Its area.
    pub area: f64,
    /// The mean of its corners.
    pub centroid: DVec3,
    /// Its bounding box.
    pub bounds: Aabb,
}

/// A scene's occluders and, per kd leaf, the occluders that reach into it.
#[derive(Clone, Debug)]
pub struct Occluders {
    list: Vec<Occluder>,
    /// Per kd node index: for leaves, the occluders whose box meets its cell.
    by_leaf: Vec<Vec<u32>>,
}

impl Occluders {
    /// Finds a scene's occluders (see the module docs); `None` when it has none.
    pub fn find(scene: &Scene, tree: &KdTree) -> Option<Occluders> {
        let list = extract::occluder_polygons(scene);
        if list.is_empty() {
            return None;
        }
        let mut by_leaf = vec![Vec::new(); tree.nodes().len()];
        for (i, o) in list.iter().enumerate() {
            let mut stack = vec![0usize];
            while let Some(n) = stack.pop() {
                let node = &tree.nodes()[n];
                if !node.cell.intersects(&o.bounds) {
                    continue;
                }
                match node.kind {
                    NodeKind::Leaf => by_leaf[n].push(i as u32),
                    NodeKind::Inner { children, .. } => stack.extend(children.map(|c| c as usize)),
                }
            }
        }
        Some(Occluders { list, by_leaf })
    }

    /// Every occluder.
    pub fn all(&self) -> &[Occluder] {
        &self.list
    }

    /// The occluders reaching into kd node `leaf` (empty for inner nodes).
    pub fn in_leaf(&self, leaf: usize) -> &[u32] {
        &self.by_leaf[leaf]
    }

    /// The `k` occluders with the best area-angle seen from `eye` among
    /// `candidates` (no repeats), best first. Occluders seen edge-on, with
    /// the eye within `eps` of their plane, are skipped: they hide nothing.
    pub fn select(&self, eye: DVec3, candidates: &[u32], k: usize, out: &mut Vec<u32>) {
        let mut scored: Vec<(f64, u32)> = Vec::with_capacity(candidates.len());
        for &i in candidates {
            let o = &self.list[i as usize];
            let d = o.centroid - eye;
            let dist2 = d.length_squared();
            let facing = o.plane.signed_distance(eye).abs();
            if dist2 <= 0.0 || facing <= EDGE_ON_TOLERANCE * (1.0 + dist2.sqrt()) {
                continue;
            }
            let cos = (o.plane.normal.dot(d) / dist2.sqrt()).abs();
            scored.push((o.area * cos / dist2, i));
        }
        let better = |a: &(f64, u32), b: &(f64, u32)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
        if scored.len() > k {
            scored.select_nth_unstable_by(k, better);
            scored.truncate(k);
        }
        scored.sort_unstable_by(better);
        out.clear();
        out.extend(scored.into_iter().map(|s| s.1));
    }
}
