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

pub(crate) use extract::{PLANARITY_ULPS, object_polygons};

use glam::{DVec3, Vec3};

use super::occlusion::tolerance::EDGE_ON_TOLERANCE;
use crate::geom::{Aabb, ConvexPolygon, Plane};
use crate::scene::{BakeCache, Scene};
use crate::spatial::{KdTree, NodeKind};

/// One occluder polygon, scene-local.
#[derive(Clone, Debug, PartialEq)]
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

impl Occluder {
    /// An occluder from its polygon, plane and area.
    fn new(polygon: ConvexPolygon, plane: Plane, area: f64) -> Occluder {
        let bounds = Aabb::from_points(polygon.vertices.iter().map(|v| v.as_vec3()));
        // Grow by the f32 rounding of the corners so the box holds the polygon.
        let slack =
            Vec3::splat(bounds.max.abs().max(bounds.min.abs()).max_element() * f32::EPSILON * 2.0);
        Occluder {
            centroid: polygon.centroid(),
            bounds: Aabb::new(bounds.min - slack, bounds.max + slack),
            polygon,
            plane,
            area,
        }
    }
}

/// The bake of a scene's occluder polygons: their corners, `f64`, in order
/// (`u32` count of polygons; per polygon a `u32` count of corners and
/// three `f64` each, little-endian). Plane, area and box are derived again
/// the way extraction derives them.
fn encode(list: &Vec<Occluder>) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&(list.len() as u32).to_le_bytes());
    for o in list {
        out.extend_from_slice(&(o.polygon.vertices.len() as u32).to_le_bytes());
        for v in &o.polygon.vertices {
            for c in v.to_array() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    out
}

fn decode(bytes: &[u8]) -> Result<Vec<Occluder>, String> {
    let mut at = 0usize;
    let u32_at = |at: &mut usize| -> Result<u32, String> {
        let b = bytes.get(*at..*at + 4).ok_or("occluders: truncated")?;
        *at += 4;
        Ok(u32::from_le_bytes(b.try_into().expect("4 bytes")))
    };
    let count = u32_at(&mut at)?;
    let mut list = Vec::with_capacity(count.min(1 << 20) as usize);
    for _ in 0..count {
        let corners = u32_at(&mut at)? as usize;
        let need = corners * 24;
        let raw = bytes.get(at..at + need).ok_or("occluders: truncated")?;
        at += need;
        let f = |i: usize| f64::from_le_bytes(raw[i * 8..i * 8 + 8].try_into().expect("8 bytes"));
        let polygon = ConvexPolygon::new(
            (0..corners)
                .map(|k| DVec3::new(f(3 * k), f(3 * k + 1), f(3 * k + 2)))
                .collect(),
        );
        let plane = polygon
            .plane()
            .ok_or("occluders: a polygon without a plane")?;
        let area = polygon.area();
        list.push(Occluder::new(polygon, plane, area));
    }
    if at != bytes.len() {
        return Err("occluders: bytes left over".into());
    }
    Ok(list)
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
        Occluders::with_list(extract::occluder_polygons(scene), tree)
    }

    /// [`Occluders::find`], the polygons read from `cache` when an earlier
    /// run baked them for this scene file (extraction is most of a large
    /// scene's preparation), and baked there when not.
    pub fn find_baked(scene: &Scene, tree: &KdTree, cache: &BakeCache) -> Option<Occluders> {
        let (list, _) = cache.load_or_build(
            scene,
            "occluders",
            extract::BAKE_PARAMS,
            || extract::occluder_polygons(scene),
            encode,
            decode,
        );
        Occluders::with_list(list, tree)
    }

    fn with_list(list: Vec<Occluder>, tree: &KdTree) -> Option<Occluders> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::generate::{OfficeOptions, office};
    use crate::scene::{Baked, load_slice};

    /// A baked occluder list is the extracted one, bit for bit: its corners
    /// travel exactly and every derived field is derived the same way.
    #[test]
    fn baked_occluders_are_the_extracted_ones() {
        let doc = office(&OfficeOptions::default());
        let path = std::path::Path::new("office.glb");
        let scene = load_slice("office", &doc.to_glb(), None, path).unwrap();
        let tree = KdTree::build(&scene, Default::default());
        let found = Occluders::find(&scene, &tree).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let cache = BakeCache::new(dir.path());
        let built = Occluders::find_baked(&scene, &tree, &cache).unwrap();
        let loaded = Occluders::find_baked(&scene, &tree, &cache).unwrap();
        assert_eq!(found.all(), built.all());
        assert_eq!(found.all(), loaded.all());
        assert_eq!(found.by_leaf, loaded.by_leaf);
        let (_, how) = cache.load_or_build(
            &scene,
            "occluders",
            extract::BAKE_PARAMS,
            Vec::new,
            encode,
            decode,
        );
        assert_eq!(how, Baked::Loaded);
        assert!(decode(&encode(found.all().to_vec().as_ref())[..7]).is_err());
    }
}
