//! The 2D quadtree of Downs et al. §3.3 over the ground plane (x, z).
//!
//! An object is stored in the cells of the deepest level whose side exceeds
//! the largest side of its footprint, so it straddles at most 2 × 2 of them
//! (the paper's "as many as four cells") and a small object on a big cell's
//! boundary is not lifted to the big cell. Every cell keeps the union of the
//! boxes of the objects in it and below it (`bounds`): its `max.y` is the
//! paper's "maximum height of any object within it or any of its
//! descendants", and the whole box lets a sweep test the cell as one frame.
//!
//! A cell that at most [`BUCKET`] objects reach is not split: it keeps them
//! all. An object then sits in the first unsplit cell above each of its (at
//! most four) own cells, so still in 1 to 4 cells, each wider than its
//! footprint and overlapping it. Why: a sweep pays for a cell it opens with
//! a frustum test, a frame, a queue push and a pop, and for an object with
//! a frame and a horizon test; in a city whose buildings each fill a cell
//! of ~10 m, the deep levels held one or two objects a cell, so their
//! cells cost more than the object tests they could spare. Horizon on the
//! street walks, 60 frames (`cull_profile` under callgrind): 44.8M → 34.3M
//! instructions on the 10k city, 24.0M → 15.8M on the 1k city, with the
//! same mean PVS (a box not hidden when its cell opens is tested again
//! against every mask nearer than it, whichever cell held it).

use crate::geom::Aabb;
use crate::scene::Scene;

/// No cell is deeper than this (a side 2¹⁶ times smaller than the scene's).
pub const MAX_DEPTH: u32 = 16;

/// A cell reached by at most this many objects keeps them all rather than
/// handing them to children (module docs; 8 and 24–32 took 4–7% more
/// instructions than 16 on the 10k city, 13% and 2% more on the 1k city).
pub const BUCKET: usize = 16;

/// One cell.
#[derive(Clone, Debug, PartialEq)]
pub struct QuadCell {
    /// Depth: 0 for the root.
    pub level: u32,
    /// Smallest (x, z) corner of the square cell.
    pub origin: [f32; 2],
    /// Side of the square.
    pub side: f32,
    /// Union of the boxes of the objects in this cell and below it.
    pub bounds: Aabb,
    /// Children (0 for none: the root is never a child).
    pub children: [u32; 4],
    objects: std::ops::Range<u32>,
}

/// A quadtree over a scene's object footprints.
#[derive(Clone, Debug, Default)]
pub struct QuadTree {
    cells: Vec<QuadCell>,
    refs: Vec<u32>,
}

/// Where an object goes: its level and the cells of that level it touches.
struct Placement {
    object: u32,
    level: u32,
    cells: [u32; 4], // ix0, iz0, ix1, iz1
}

impl QuadTree {
    /// Builds the tree over every object of `scene` that has a box.
    pub fn build(scene: &Scene) -> QuadTree {
        let b = scene.bounds();
        if b.is_empty() {
            return QuadTree::default();
        }
        let origin = [b.min.x, b.min.z];
        // Grown a little so the far boundary lies strictly inside the root.
        let side = b.extent().x.max(b.extent().z).max(f32::MIN_POSITIVE) * (1.0 + 1e-6);
        let placements: Vec<Placement> = scene
            .objects()
            .iter()
            .filter(|o| o.is_static())
            .map(|o| {
                let e = o.bounds.extent();
                let largest = e.x.max(e.z);
                let mut level = 0;
                while level < MAX_DEPTH && side / (1u32 << (level + 1)) as f32 > largest {
                    level += 1;
                }
                let cell = side / (1u32 << level) as f32;
                let last = (1u32 << level) - 1;
                let index = |v: f32, o: f32| (((v - o) / cell).floor().max(0.0) as u32).min(last);
                Placement {
                    object: o.id,
                    level,
                    cells: [
                        index(o.bounds.min.x, origin[0]),
                        index(o.bounds.min.z, origin[1]),
                        index(o.bounds.max.x, origin[0]),
                        index(o.bounds.max.z, origin[1]),
                    ],
                }
            })
            .collect();
        let mut tree = QuadTree::default();
        let all: Vec<usize> = (0..placements.len()).collect();
        tree.build_cell(scene, &placements, all, 0, [0, 0], origin, side);
        tree
    }

    /// Builds the cell `(level, ix, iz)` from the placements reaching it
    /// (all kept here when at most [`BUCKET`] do); returns its index.
    #[allow(clippy::too_many_arguments)]
    fn build_cell(
        &mut self,
        scene: &Scene,
        placements: &[Placement],
        here: Vec<usize>,
        level: u32,
        index: [u32; 2],
        origin: [f32; 2],
        root_side: f32,
    ) -> u32 {
        let me = self.cells.len() as u32;
        let side = root_side / (1u32 << level) as f32;
        self.cells.push(QuadCell {
            level,
            origin: [
                origin[0] + index[0] as f32 * side,
                origin[1] + index[1] as f32 * side,
            ],
            side,
            bounds: Aabb::EMPTY,
            children: [0; 4],
            objects: 0..0,
        });
        let start = self.refs.len() as u32;
        let mut below: [Vec<usize>; 4] = Default::default();
        let unsplit = here.len() <= BUCKET;
        for p in here {
            let pl = &placements[p];
            let shift = pl.level - level;
            if shift == 0 || unsplit {
                self.refs.push(pl.object);
                continue;
            }
            // The children (one level down) that hold one of its cells.
            let (x0, z0) = (pl.cells[0] >> (shift - 1), pl.cells[1] >> (shift - 1));
            let (x1, z1) = (pl.cells[2] >> (shift - 1), pl.cells[3] >> (shift - 1));
            for (q, list) in below.iter_mut().enumerate() {
                let (cx, cz) = (
                    2 * index[0] + (q as u32 & 1),
                    2 * index[1] + (q as u32 >> 1),
                );
                if (x0..=x1).contains(&cx) && (z0..=z1).contains(&cz) {
                    list.push(p);
                }
            }
        }
        let end = self.refs.len() as u32;
        let mut bounds = Aabb::EMPTY;
        for &o in &self.refs[start as usize..end as usize] {
            bounds.merge(&scene.objects()[o as usize].bounds);
        }
        let mut children = [0u32; 4];
        for (q, list) in below.into_iter().enumerate() {
            if list.is_empty() {
                continue;
            }
            let child_index = [
                2 * index[0] + (q as u32 & 1),
                2 * index[1] + (q as u32 >> 1),
            ];
            let c = self.build_cell(
                scene,
                placements,
                list,
                level + 1,
                child_index,
                origin,
                root_side,
            );
            bounds.merge(&self.cells[c as usize].bounds);
            children[q] = c;
        }
        let cell = &mut self.cells[me as usize];
        cell.objects = start..end;
        cell.bounds = bounds;
        cell.children = children;
        me
    }

    /// Every cell; the root is cell 0 (none for an empty scene).
    pub fn cells(&self) -> &[QuadCell] {
        &self.cells
    }

    /// The objects stored in `cell` itself (not below it).
    pub fn objects(&self, cell: &QuadCell) -> &[u32] {
        &self.refs[cell.objects.start as usize..cell.objects.end as usize]
    }

    /// Checks the invariants the sweep relies on: every object with a box is
    /// stored in 1 to 4 cells whose side exceeds its footprint and whose
    /// square it overlaps, and every cell's bounds hold every box below it.
    pub fn validate(&self, scene: &Scene) -> Result<(), String> {
        let mut count = vec![0u32; scene.objects().len()];
        let mut stack: Vec<(u32, Vec<u32>)> = Vec::new();
        if !self.cells.is_empty() {
            stack.push((0, Vec::new()));
        }
        while let Some((c, ancestors)) = stack.pop() {
            let cell = &self.cells[c as usize];
            for &o in self.objects(cell) {
                let ob = &scene.objects()[o as usize].bounds;
                count[o as usize] += 1;
                let e = ob.extent();
                if cell.side <= e.x.max(e.z) && cell.level > 0 {
                    return Err(format!(
                        "object {o} in cell {c} of side {} too small",
                        cell.side
                    ));
                }
                let inside = |a: &Aabb| a.contains(ob);
                if !inside(&cell.bounds)
                    || !ancestors
                        .iter()
                        .all(|&a| inside(&self.cells[a as usize].bounds))
                {
                    return Err(format!(
                        "object {o}'s box is not inside cell {c}'s bounds or an ancestor's"
                    ));
                }
                let [x, z] = cell.origin;
                let overlaps = ob.max.x >= x
                    && ob.min.x <= x + cell.side
                    && ob.max.z >= z
                    && ob.min.z <= z + cell.side;
                if !overlaps && cell.level > 0 {
                    return Err(format!("object {o} does not overlap cell {c}"));
                }
            }
            for &k in cell.children.iter().filter(|&&k| k != 0) {
                let mut a = ancestors.clone();
                a.push(c);
                stack.push((k, a));
            }
        }
        for o in scene.objects() {
            let n = count[o.id as usize];
            if o.is_static() && !(1..=4).contains(&n) {
                return Err(format!("object {} is stored in {n} cells", o.id));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::scene::SceneBuilder;
    use crate::scene::generate::MeshBuilder;

    /// `n` unit cubes in a row along x, 10 apart: each would sit in a cell
    /// of about 1.2 m at its own level.
    fn row(n: usize) -> Scene {
        let mut b = SceneBuilder::new("row");
        for i in 0..n {
            let x = 10.0 * i as f32;
            let mut m = MeshBuilder::new();
            m.cuboid(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0), true);
            b.begin_object(format!("c{i}"), None);
            b.add_triangles(
                m.build(false)
                    .triangles()
                    .map(|t| t.map(|v| v.as_dvec3()))
                    .collect::<Vec<_>>(),
                false,
            );
        }
        b.finish()
    }

    /// The distinct objects stored in `cell` and below it.
    fn reaching(t: &QuadTree, cell: &QuadCell) -> usize {
        let mut ids: Vec<u32> = Vec::new();
        let mut stack = vec![cell];
        while let Some(c) = stack.pop() {
            ids.extend(t.objects(c));
            stack.extend(
                c.children
                    .iter()
                    .filter(|&&k| k != 0)
                    .map(|&k| &t.cells()[k as usize]),
            );
        }
        ids.sort_unstable();
        ids.dedup();
        ids.len()
    }

    #[test]
    fn a_cell_few_objects_reach_keeps_them_and_one_more_splits_it() {
        let few = row(BUCKET);
        let t = QuadTree::build(&few);
        t.validate(&few).unwrap();
        assert_eq!(t.cells().len(), 1);
        assert_eq!(t.objects(&t.cells()[0]).len(), BUCKET);

        let many = row(BUCKET + 1);
        let t = QuadTree::build(&many);
        t.validate(&many).unwrap();
        assert!(t.objects(&t.cells()[0]).is_empty());
        for c in t.cells() {
            let split = c.children.iter().any(|&k| k != 0);
            assert_eq!(split, reaching(&t, c) > BUCKET, "cell {c:?}");
            // Kept above their own level (a side of ~1.2 m), not at it.
            assert!(t.objects(c).is_empty() || c.side > 8.0, "cell {c:?}");
        }
    }
}
