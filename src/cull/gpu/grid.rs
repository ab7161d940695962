//! The scene as a regular grid organized as an octree-like hierarchy (Tai &
//! Hsu §3.1), with the eye-siding numbers of §3.3.
//!
//! Voxels are cubes a few typical objects wide. Each object belongs to
//! exactly one voxel, the one holding the minimum corner of its box (the
//! paper's *overlapping voxels*: a voxel reaches as far past its cell as its
//! objects do), so finding an object's voxel is a subtraction, a division
//! and a floor. The hierarchy halves the grid's index range on every axis
//! that is still more than one voxel long, so a node has up to eight
//! children, and a voxel is a leaf. A node's box is the union of its
//! objects' boxes (tighter than the overlapping voxel, and what a query
//! must cover); empty nodes are left out.

use glam::{DVec3, Vec3};

use crate::geom::Aabb;
use crate::scene::Scene;

/// Voxels are this many typical (median) objects wide.
const OBJECTS_PER_VOXEL: f32 = 2.0;

/// Most voxels along an axis (the paper's walkthrough used 32³).
const MAX_VOXELS: u32 = 32;

/// One node of the hierarchy.
#[derive(Clone, Debug)]
pub struct Node {
    /// Depth below the root (the root is 0).
    pub depth: u32,
    /// The union of the boxes of the objects below it.
    pub bounds: Aabb,
    /// Child nodes (none for a voxel).
    pub children: Vec<u32>,
    /// The objects of a voxel (none for an inner node).
    pub objects: Vec<u32>,
    /// Where it splits each axis, scene-local (`NaN` for an axis it does
    /// not split): the planes eye-siding numbers are counted against.
    pub split: [f32; 3],
    /// The first voxel index of its range on each axis.
    lo: [u32; 3],
    /// One past the last voxel index of its range on each axis.
    hi: [u32; 3],
    /// Its parent (the root's is itself).
    parent: u32,
}

/// The grid and its hierarchy.
#[derive(Clone, Debug)]
pub struct Grid {
    min: Vec3,
    voxel: f32,
    dims: [u32; 3],
    nodes: Vec<Node>,
    /// Per voxel (x fastest, then y, then z): the deepest node whose range
    /// holds it — where a movable object in that voxel is kept.
    owner: Vec<u32>,
}

impl Grid {
    /// The grid over `scene`'s static objects (those with an empty box show
    /// no pixel; movable ones are culled where they are now, as dynamic
    /// occludees).
    pub fn build(scene: &Scene) -> Grid {
        let bounds = scene.bounds();
        let mut sizes: Vec<f32> = scene
            .objects()
            .iter()
            .filter(|o| o.is_static())
            .map(|o| o.bounds.extent().max_element())
            .collect();
        if bounds.is_empty() || sizes.is_empty() {
            return Grid {
                min: Vec3::ZERO,
                voxel: 1.0,
                dims: [1; 3],
                nodes: Vec::new(),
                owner: Vec::new(),
            };
        }
        let mid = sizes.len() / 2;
        let (_, median, _) = sizes.select_nth_unstable_by(mid, f32::total_cmp);
        let extent = bounds.extent();
        let voxel = (*median * OBJECTS_PER_VOXEL)
            .max(extent.max_element() / MAX_VOXELS as f32)
            .max(f32::MIN_POSITIVE);
        let dims = [0, 1, 2].map(|a| ((extent[a] / voxel).ceil() as u32).clamp(1, MAX_VOXELS));
        let mut grid = Grid {
            min: bounds.min,
            voxel,
            dims,
            nodes: Vec::new(),
            owner: Vec::new(),
        };
        let mut items: Vec<([u32; 3], u32)> = scene
            .objects()
            .iter()
            .filter(|o| o.is_static())
            .map(|o| (grid.voxel_of(&o.bounds), o.id))
            .collect();
        grid.nodes.push(Node {
            depth: 0,
            bounds: Aabb::EMPTY,
            children: Vec::new(),
            objects: Vec::new(),
            split: [f32::NAN; 3],
            lo: [0; 3],
            hi: dims,
            parent: 0,
        });
        grid.fill(0, [0; 3], dims, &mut items, scene);
        // Nodes come parents first, so a later node that holds a voxel is
        // deeper than any earlier one that does.
        let mut owner = vec![0; (dims[0] * dims[1] * dims[2]) as usize];
        for (n, node) in grid.nodes.iter().enumerate() {
            for z in node.lo[2]..node.hi[2] {
                for y in node.lo[1]..node.hi[1] {
                    for x in node.lo[0]..node.hi[0] {
                        owner[grid.voxel_index([x, y, z])] = n as u32;
                    }
                }
            }
        }
        grid.owner = owner;
        grid
    }

    fn voxel_index(&self, v: [u32; 3]) -> usize {
        ((v[2] * self.dims[1] + v[1]) * self.dims[0] + v[0]) as usize
    }

    /// The node that keeps a movable object with box `b`: the deepest one
    /// whose range holds [`Grid::voxel_of`] `b` (§3.1's constant-time
    /// placement). `None` for a grid without nodes.
    pub fn owner_of(&self, b: &Aabb) -> Option<u32> {
        self.owner.get(self.voxel_index(self.voxel_of(b))).copied()
    }

    /// The parent of node `n` (the root's is itself).
    pub fn parent(&self, n: u32) -> u32 {
        self.nodes[n as usize].parent
    }

    /// The voxel an object with box `b` belongs to: the one holding the
    /// box's minimum corner (clamped into the grid).
    pub fn voxel_of(&self, b: &Aabb) -> [u32; 3] {
        [0, 1, 2].map(|a| {
            let i = ((b.min[a] - self.min[a]) / self.voxel).floor();
            (i.max(0.0) as u32).min(self.dims[a] - 1)
        })
    }

    /// Builds node `index` over voxels `lo..hi` with the objects `items`.
    fn fill(
        &mut self,
        index: usize,
        lo: [u32; 3],
        hi: [u32; 3],
        items: &mut [([u32; 3], u32)],
        scene: &Scene,
    ) {
        let mut bounds = Aabb::EMPTY;
        for (_, id) in items.iter() {
            bounds.merge(&scene.objects()[*id as usize].bounds);
        }
        let node = &mut self.nodes[index];
        node.bounds = bounds;
        node.lo = lo;
        node.hi = hi;
        if (0..3).all(|a| hi[a] - lo[a] <= 1) {
            node.objects = items.iter().map(|(_, id)| *id).collect();
            return;
        }
        let depth = node.depth;
        let mid = [0, 1, 2].map(|a| lo[a] + (hi[a] - lo[a]) / 2);
        let split = [0, 1, 2].map(|a| {
            if hi[a] - lo[a] > 1 {
                self.min[a] + mid[a] as f32 * self.voxel
            } else {
                f32::NAN
            }
        });
        self.nodes[index].split = split;
        // Sort the objects into octants, then build each non-empty one.
        let octant = |v: &[u32; 3]| -> usize {
            (0..3)
                .filter(|&a| hi[a] - lo[a] > 1 && v[a] >= mid[a])
                .map(|a| 1 << a)
                .sum()
        };
        items.sort_unstable_by_key(|(v, _)| octant(v));
        let mut start = 0;
        while start < items.len() {
            let o = octant(&items[start].0);
            let end = start + items[start..].partition_point(|(v, _)| octant(v) == o);
            let child_lo = [0, 1, 2].map(|a| if o >> a & 1 == 1 { mid[a] } else { lo[a] });
            let child_hi = [0, 1, 2].map(|a| {
                if hi[a] - lo[a] > 1 && o >> a & 1 == 0 {
                    mid[a]
                } else {
                    hi[a]
                }
            });
            let child = self.nodes.len();
            self.nodes.push(Node {
                depth: depth + 1,
                bounds: Aabb::EMPTY,
                children: Vec::new(),
                objects: Vec::new(),
                split: [f32::NAN; 3],
                lo: child_lo,
                hi: child_hi,
                parent: index as u32,
            });
            self.nodes[index].children.push(child as u32);
            self.fill(child, child_lo, child_hi, &mut items[start..end], scene);
            start = end;
        }
    }

    /// The nodes; the root is node 0 (no nodes for a scene without objects).
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// Voxels along each axis.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// The eye-siding number of `child` of `parent` (§3.3): on how many of
    /// the parent's three partition planes it lies on the eye's side (an
    /// axis the parent does not split counts as the eye's side). 3 holds
    /// the eye's octant, 0 is the one opposite.
    pub fn eye_siding(&self, parent: &Node, child: &Node, eye: DVec3) -> usize {
        (0..3)
            .filter(|&a| {
                let s = parent.split[a];
                if s.is_nan() {
                    return true;
                }
                let child_low = (self.min[a] + child.lo[a] as f32 * self.voxel) < s;
                let eye_low = eye[a] < s as f64;
                child_low == eye_low
            })
            .count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::generate::{CityOptions, city};
    use crate::scene::load_slice;

    fn city_of(buildings: u32) -> Scene {
        let doc = city(&CityOptions {
            buildings,
            seed: 3,
            ..CityOptions::default()
        });
        let path = std::path::Path::new("city.glb");
        load_slice("city", &doc.to_glb(), None, path).unwrap()
    }

    #[test]
    fn every_object_is_in_exactly_one_voxel_and_boxes_cover_their_objects() {
        let scene = city_of(200);
        let grid = Grid::build(&scene);
        let mut seen = vec![0; scene.objects().len()];
        for n in grid.nodes() {
            for &id in &n.objects {
                seen[id as usize] += 1;
            }
            for &c in &n.children {
                let c = &grid.nodes()[c as usize];
                assert!(n.bounds.contains(&c.bounds));
                assert_eq!(c.depth, n.depth + 1);
            }
            for &id in &n.objects {
                assert!(n.bounds.contains(&scene.objects()[id as usize].bounds));
                assert!(n.children.is_empty());
            }
        }
        assert!(seen.iter().all(|&s| s == 1), "{seen:?}");
        assert!(grid.dims().iter().all(|&d| (1..=MAX_VOXELS).contains(&d)));
    }

    #[test]
    fn eye_siding_orders_the_eyes_octant_first_and_the_opposite_last() {
        let scene = city_of(200);
        let grid = Grid::build(&scene);
        let root = &grid.nodes()[0];
        let b = scene.bounds();
        let eye = b.min.as_dvec3() - DVec3::ONE;
        for &c in &root.children {
            let child = &grid.nodes()[c as usize];
            let low_everywhere = (0..3).all(|a| {
                root.split[a].is_nan() || (grid.min[a] + child.lo[a] as f32 * grid.voxel) < root.split[a]
            });
            let siding = grid.eye_siding(root, child, eye);
            assert_eq!(siding == 3, low_everywhere, "child {c}: siding {siding}");
        }
    }
}
