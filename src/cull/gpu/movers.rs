//! The scene's movable objects placed in the grid (Tai & Hsu §3.1: "the
//! actual position of dynamic objects is updated for each cell"), so that
//! the walk culls them with the static objects around them, a hidden node
//! hiding its movers too.
//!
//! Each mover is kept by the deepest node whose range holds the voxel of
//! its box's minimum corner ([`Grid::owner_of`]: a subtraction, a division
//! and a floor, then a table). A node's box for queries grows by the boxes
//! of the movers below it, so it holds all of them wherever they are (the
//! paper grows voxels by a fixed overlap instead; the union is tighter and
//! needs no limit on a mover's size). The placement is redone from
//! `Scene::motion` when its version has changed since the last cull: each
//! mover costs its lookup and a walk up to the root.

use super::grid::Grid;
use crate::geom::Aabb;
use crate::scene::Scene;

/// The movers of one scene as the grid holds them.
#[derive(Clone, Debug, Default)]
pub struct Movers {
    /// The `Scene::motion` version they were placed at; `None`: never.
    version: Option<u64>,
    /// Their ids and boxes (scene-local), in `Motion::ids` order.
    ids: Vec<u32>,
    boxes: Vec<Aabb>,
    /// Per node: the movers it keeps (indices into `ids`).
    kept: Vec<Vec<u32>>,
    /// Per node: the union of the boxes of the movers below it.
    reach: Vec<Aabb>,
    /// Movers no node keeps (a grid without static objects has no nodes):
    /// the walk tests them last, one by one.
    loose: Vec<u32>,
}

impl Movers {
    /// Places the scene's movers in `grid` again if any has moved since.
    pub fn update(&mut self, grid: &Grid, scene: &Scene) {
        let motion = scene.motion();
        let version = motion.version();
        if self.version == Some(version) {
            return;
        }
        self.version = Some(version);
        self.ids.clear();
        self.ids.extend(motion.ids());
        self.boxes = motion.boxes();
        let n = grid.nodes().len();
        self.kept.iter_mut().for_each(Vec::clear);
        self.kept.resize(n, Vec::new());
        self.reach.clear();
        self.reach.resize(n, Aabb::EMPTY);
        self.loose.clear();
        for (i, b) in self.boxes.iter().enumerate() {
            if b.is_empty() {
                continue;
            }
            let Some(mut node) = grid.owner_of(b) else {
                self.loose.push(i as u32);
                continue;
            };
            self.kept[node as usize].push(i as u32);
            loop {
                self.reach[node as usize].merge(b);
                let up = grid.parent(node);
                if up == node {
                    break;
                }
                node = up;
            }
        }
    }

    /// Node `n`'s box for a query: its objects' and its movers'.
    pub fn bounds(&self, grid: &Grid, n: u32) -> Aabb {
        let own = grid.nodes()[n as usize].bounds;
        match self.reach.get(n as usize) {
            Some(r) => own.merged(r),
            None => own,
        }
    }

    /// The movers node `n` keeps (indices for [`Movers::id`] and [`Movers::bounds_of`]).
    pub fn kept(&self, n: u32) -> &[u32] {
        self.kept.get(n as usize).map_or(&[], Vec::as_slice)
    }

    /// The movers no node keeps.
    pub fn loose(&self) -> &[u32] {
        &self.loose
    }

    /// The object id of mover `i`.
    pub fn id(&self, i: u32) -> u32 {
        self.ids[i as usize]
    }

    /// The box of mover `i` when placed.
    pub fn bounds_of(&self, i: u32) -> Aabb {
        self.boxes[i as usize]
    }
}

#[cfg(test)]
mod tests {
    use glam::{DMat4, DVec3};

    use super::*;
    use crate::scene::generate::{CrowdOptions, crowd};
    use crate::scene::load_slice;

    #[test]
    fn every_mover_is_kept_once_and_held_by_its_nodes_wherever_it_goes() {
        let doc = crowd(&CrowdOptions {
            objects: 300,
            seed: 2,
            ..CrowdOptions::default()
        });
        let path = std::path::Path::new("crowd.glb");
        let scene = load_slice("crowd", &doc.to_glb(), None, path).unwrap();
        let grid = Grid::build(&scene);
        let mut movers = Movers::default();
        let check = |movers: &Movers| {
            let mut kept = vec![0; movers.ids.len()];
            for n in 0..grid.nodes().len() as u32 {
                for &i in movers.kept(n) {
                    kept[i as usize] += 1;
                    // The node and every ancestor hold the mover's box.
                    let mut at = n;
                    loop {
                        assert!(movers.bounds(&grid, at).contains(&movers.bounds_of(i)));
                        if grid.parent(at) == at {
                            break;
                        }
                        at = grid.parent(at);
                    }
                }
            }
            assert!(kept.iter().all(|&k| k == 1), "{kept:?}");
        };
        movers.update(&grid, &scene);
        assert_eq!(movers.ids.len(), 150);
        check(&movers);
        // Moves: across the grid, and far outside it.
        let ids: Vec<u32> = scene.motion().ids().collect();
        for (k, &id) in ids.iter().enumerate() {
            let to = DVec3::new((k * 37 % 500) as f64 - 100.0, 0.0, (k * 11 % 300) as f64);
            scene
                .motion()
                .place(id, DMat4::from_translation(to), scene.origin, scene.objects().len())
                .unwrap();
        }
        movers.update(&grid, &scene);
        check(&movers);
    }
}
