//! `pvsd gen crowd`: a square of ground with rows of walls across it and
//! many small objects on a regular grid between them (one per cell, placed
//! at random within it), half of them movable — the dynamic scene of Tai &
//! Hsu §4 ("half of the objects are dynamic and the others are static"),
//! at a size a server answers for many clients.
//!
//! Walls and the ground are flagged `extras.occluder = true`; the movable
//! objects `extras.movable = true` (each placed by its node's translation,
//! so a `PUT` of a new translation moves it the way a glTF viewer would).

use glam::{Quat, Vec3};
use rand::Rng;
use serde_json::json;

use super::mesh::MeshBuilder;
use super::rng;
use crate::scene::glb::{Document, Node};

/// Knobs of the crowd generator.
#[derive(Clone, Debug, PartialEq)]
pub struct CrowdOptions {
    /// Seed: the same seed gives the same bytes.
    pub seed: u64,
    /// Small objects, half of them movable.
    pub objects: u32,
    /// Translation of the whole scene, for precision tests far from the origin.
    pub offset: [f32; 3],
}

impl Default for CrowdOptions {
    fn default() -> Self {
        CrowdOptions {
            seed: 1,
            objects: 2000,
            offset: [0.0; 3],
        }
    }
}

/// Side of the square, metres, per thousand objects (the density holds).
const SIDE_PER_THOUSAND: f32 = 120.0;
/// Distance between rows of walls.
const ROW: f32 = 20.0;
/// Wall height and thickness.
const WALL_H: f32 = 4.0;
const WALL_T: f32 = 0.3;

/// The crowd as a glTF document: one root `crowd` node whose children are
/// `ground`, the walls `wall_<row>_<k>`, then `thing_<n>`: even `n` static,
/// odd `n` movable.
pub fn crowd(opts: &CrowdOptions) -> Document {
    let mut rng = rng(opts.seed);
    let mut doc = Document::default();
    let side = (SIDE_PER_THOUSAND * (opts.objects.max(1) as f32 / 1000.0).sqrt()).max(ROW * 2.0);
    let mut children = Vec::new();

    let mut ground = MeshBuilder::new();
    ground.quad(
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.0, 0.0, side),
        Vec3::new(side, 0.0, side),
        Vec3::new(side, 0.0, 0.0),
    );
    let mesh = doc.add_mesh(ground.build(false));
    let mut node = Node::named("ground");
    node.mesh = Some(mesh);
    node.extras = Some(json!({ "occluder": true, "kind": "ground" }));
    children.push(doc.add_node(node));

    // Rows of wall segments with gaps, so some of what is behind shows.
    let rows = (side / ROW) as u32;
    for r in 1..rows {
        let z = r as f32 * ROW;
        let mut x = rng.random_range(0.0..4.0);
        let mut k = 0;
        while x < side - 2.0 {
            let len = rng.random_range(6.0f32..16.0).min(side - x);
            let mut wall = MeshBuilder::new();
            wall.cuboid(
                Vec3::new(x, 0.0, z),
                Vec3::new(x + len, WALL_H, z + WALL_T),
                false,
            );
            let mesh = doc.add_mesh(wall.build(false));
            let mut node = Node::named(format!("wall_{r}_{k}"));
            node.mesh = Some(mesh);
            node.extras = Some(json!({ "occluder": true, "kind": "wall" }));
            children.push(doc.add_node(node));
            x += len + rng.random_range(2.0..6.0);
            k += 1;
        }
    }

    // Things: boxes of 0.4–1.8 m, meshes around their own origin, placed
    // by translation (and a turn about y) like a glTF scene's props, one
    // per cell of a regular grid over the ground.
    let cols = (opts.objects as f64).sqrt().ceil().max(1.0) as u32;
    let cell = side / cols as f32;
    for n in 0..opts.objects {
        let size = Vec3::new(
            rng.random_range(0.4..1.2),
            rng.random_range(0.4..1.8),
            rng.random_range(0.4..1.2),
        );
        let mut thing = MeshBuilder::new();
        thing.cuboid(
            Vec3::new(-size.x * 0.5, 0.0, -size.z * 0.5),
            Vec3::new(size.x * 0.5, size.y, size.z * 0.5),
            true,
        );
        let mesh = doc.add_mesh(thing.build(false));
        let mut node = Node::named(format!("thing_{n:05}"));
        node.mesh = Some(mesh);
        let (i, j) = ((n % cols) as f32, (n / cols) as f32);
        let margin = (cell * 0.5).min(1.0);
        node.translation = [
            i * cell + rng.random_range(margin..(cell - margin).max(margin + 1e-3)),
            0.0,
            j * cell + rng.random_range(margin..(cell - margin).max(margin + 1e-3)),
        ];
        node.rotation =
            Quat::from_rotation_y(rng.random_range(0.0..std::f32::consts::TAU)).to_array();
        let movable = n % 2 == 1;
        node.extras = Some(json!({ "movable": movable, "kind": "thing" }));
        children.push(doc.add_node(node));
    }

    let mut root = Node::named("crowd");
    root.translation = opts.offset;
    root.children = children;
    let root = doc.add_node(root);
    doc.roots.push(root);
    doc
}
