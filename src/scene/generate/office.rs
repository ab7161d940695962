//! `pvsd gen office`: building interiors after the test scenes of Bittner et
//! al. §7 and Coorg–Teller: floors of rooms on a grid, walls with doors,
//! floor slabs, and about a hundred detail objects of ~650 triangles (the
//! papers' "virtual plant" of 644 polygons) spread at random over the rooms.
//!
//! Walls and slabs are flagged `extras.occluder = true`; plants are not.

use glam::Vec3;
use rand::Rng;
use serde_json::json;

use super::mesh::MeshBuilder;
use super::rng;
use crate::scene::glb::{Document, Node};

/// Knobs of the office generator.
#[derive(Clone, Debug, PartialEq)]
pub struct OfficeOptions {
    /// Seed: the same seed gives the same bytes.
    pub seed: u64,
    /// Storeys.
    pub floors: u32,
    /// Rooms along x on each storey.
    pub rooms_x: u32,
    /// Rooms along z on each storey.
    pub rooms_z: u32,
    /// Detail objects (plants) spread over all rooms.
    pub details: u32,
    /// Translation of the whole building, for precision tests far from the origin.
    pub offset: [f32; 3],
}

impl Default for OfficeOptions {
    fn default() -> Self {
        OfficeOptions {
            seed: 1,
            floors: 2,
            rooms_x: 6,
            rooms_z: 4,
            details: 100,
            offset: [0.0; 3],
        }
    }
}

const ROOM_X: f32 = 5.0;
const ROOM_Z: f32 = 4.0;
const STOREY: f32 = 3.0;
const WALL: f32 = 0.2;
const SLAB: f32 = 0.3;
const DOOR_W: f32 = 1.0;
const DOOR_H: f32 = 2.1;

/// The office as a glTF document: one root `office` node whose children are,
/// storey by storey, `floor_<f>` and its walls `wall_<f>_<k>`, then the roof
/// slab, then `plant_<n>`.
pub fn office(opts: &OfficeOptions) -> Document {
    let mut rng = rng(opts.seed);
    let mut doc = Document::default();
    let mut children = Vec::new();
    let (w, d) = (opts.rooms_x as f32 * ROOM_X, opts.rooms_z as f32 * ROOM_Z);
    let occluder = |kind: &str| Some(json!({ "occluder": true, "kind": kind }));
    let mut add = |doc: &mut Document, name: String, mesh: MeshBuilder, extras| {
        let mesh = doc.add_mesh(mesh.build(false));
        let mut node = Node::named(name);
        node.mesh = Some(mesh);
        node.extras = extras;
        children.push(doc.add_node(node));
    };
    for f in 0..=opts.floors {
        let y0 = f as f32 * STOREY;
        let mut slab = MeshBuilder::new();
        slab.cuboid(
            Vec3::new(-WALL, y0, -WALL),
            Vec3::new(w + WALL, y0 + SLAB, d + WALL),
            true,
        );
        add(&mut doc, format!("floor_{f}"), slab, occluder("floor"));
        if f == opts.floors {
            break; // the last slab is the roof
        }
        let (lo, hi) = (y0 + SLAB, y0 + STOREY);
        let mut k = 0;
        // Walls along x (constant z), then along z (constant x); interior ones get a door.
        for j in 0..=opts.rooms_z {
            for i in 0..opts.rooms_x {
                let z = j as f32 * ROOM_Z;
                let (a, b) = (i as f32 * ROOM_X, (i + 1) as f32 * ROOM_X);
                let door = (j > 0 && j < opts.rooms_z)
                    .then(|| rng.random_range(a + 0.5..b - 0.5 - DOOR_W));
                let mesh = wall(|u, v, t| Vec3::new(u, v, z + t), a, b, lo, hi, door);
                add(&mut doc, format!("wall_{f}_{k}"), mesh, occluder("wall"));
                k += 1;
            }
        }
        for i in 0..=opts.rooms_x {
            for j in 0..opts.rooms_z {
                let x = i as f32 * ROOM_X;
                let (a, b) = (j as f32 * ROOM_Z, (j + 1) as f32 * ROOM_Z);
                let door = (i > 0 && i < opts.rooms_x)
                    .then(|| rng.random_range(a + 0.5..b - 0.5 - DOOR_W));
                let mesh = wall(|u, v, t| Vec3::new(x + t, v, u), a, b, lo, hi, door);
                add(&mut doc, format!("wall_{f}_{k}"), mesh, occluder("wall"));
                k += 1;
            }
        }
    }
    for n in 0..opts.details {
        let f = rng.random_range(0..opts.floors.max(1));
        let x = rng.random_range(0.6..w - 0.6);
        let z = rng.random_range(0.6..d - 0.6);
        let base = Vec3::new(x, f as f32 * STOREY + SLAB, z);
        let mut plant = MeshBuilder::new();
        plant.cylinder(base, 0.25, 0.4, 24);
        plant.uv_sphere(base + Vec3::Y * 0.85, 0.45, 15, 20);
        add(
            &mut doc,
            format!("plant_{n}"),
            plant,
            Some(json!({ "occluder": false, "kind": "plant" })),
        );
    }
    let mut root = Node::named("office");
    root.translation = opts.offset;
    root.children = children;
    let root = doc.add_node(root);
    doc.roots.push(root);
    doc
}

/// A wall segment from `a` to `b` along its own axis `u`, between heights
/// `lo` and `hi`, `WALL` thick across `t`; `at(u, v, t)` places it. With a
/// door starting at `u = door`, it is built of two piers and a lintel.
fn wall(
    at: impl Fn(f32, f32, f32) -> Vec3,
    a: f32,
    b: f32,
    lo: f32,
    hi: f32,
    door: Option<f32>,
) -> MeshBuilder {
    let mut m = MeshBuilder::new();
    let mut block = |u0: f32, u1: f32, v0: f32, v1: f32| {
        let (p, q) = (at(u0, v0, -WALL / 2.0), at(u1, v1, WALL / 2.0));
        m.cuboid(p.min(q), p.max(q), true);
    };
    match door {
        None => block(a, b, lo, hi),
        Some(s) => {
            block(a, s, lo, hi);
            block(s + DOOR_W, b, lo, hi);
            block(s, s + DOOR_W, lo + DOOR_H, hi);
        }
    }
    m
}
