//! `pvsd gen city`: a city after the urbania generator of Downs et al. §4.1.
//!
//! What the paper asks of it: long straight streets, simple buildings of
//! 120–180 polygons kept small with space between them (so occluders do not
//! fuse easily), some tall buildings that break the horizon, and the whole
//! city rotated 15° to the axes. Blocks of 3 × 2 lots sit on a grid of
//! straight streets; each lot holds one box-shaped building whose facades are
//! cut into bays and floors, some with a rooftop box.

use glam::{Quat, Vec3};
use rand::Rng;
use rand::seq::IndexedRandom;
use serde_json::json;

use super::mesh::MeshBuilder;
use super::rng;
use crate::scene::glb::{Document, Node};

/// Knobs of the city generator.
#[derive(Clone, Debug, PartialEq)]
pub struct CityOptions {
    /// Seed: the same seed gives the same bytes.
    pub seed: u64,
    /// Number of buildings (1000 ≈ urban1k, 10000 ≈ urban10k).
    pub buildings: u32,
    /// Share of tall buildings (50–150 m instead of 8–30 m).
    pub tall_share: f64,
    /// Translation of the whole city, for precision tests far from the origin.
    pub offset: [f32; 3],
}

impl Default for CityOptions {
    fn default() -> Self {
        CityOptions {
            seed: 1,
            buildings: 1000,
            tall_share: 0.05,
            offset: [0.0; 3],
        }
    }
}

/// Width of a lot along x and z, metres.
const LOT: f32 = 24.0;
/// Street width between blocks.
const STREET: f32 = 16.0;
const LOTS_X: u32 = 3;
const LOTS_Z: u32 = 2;

/// Facade layouts `(bays around, floors)` giving 4·floors·bays + 2 roof
/// triangles between 122 and 170: with an optional 10-triangle rooftop box
/// every building has 120–180 triangles, as in urbania.
const FACADES: [(u32, u32); 6] = [(6, 5), (6, 6), (7, 5), (7, 6), (8, 4), (8, 5)];

/// The city as a glTF document: one root `city` node (rotated 15° about +Y,
/// translated by `offset`) whose children are `building_0000`… and, last, `ground`.
pub fn city(opts: &CityOptions) -> Document {
    let mut rng = rng(opts.seed);
    let mut doc = Document::default();
    let n = opts.buildings as usize;
    let blocks = n.div_ceil((LOTS_X * LOTS_Z) as usize).max(1);
    let blocks_x = (blocks as f64).sqrt().ceil() as usize;
    let block_w = LOTS_X as f32 * LOT + STREET;
    let block_d = LOTS_Z as f32 * LOT + STREET;
    let mut children = Vec::with_capacity(n + 1);
    let mut extent = Vec3::ZERO;
    for i in 0..n {
        let block = i / (LOTS_X * LOTS_Z) as usize;
        let lot = (i % (LOTS_X * LOTS_Z) as usize) as u32;
        let (bx, bz) = ((block % blocks_x) as f32, (block / blocks_x) as f32);
        let (lx, lz) = ((lot % LOTS_X) as f32, (lot / LOTS_X) as f32);
        // Footprint 10–20 m with at least 2 m to each lot edge.
        let w: f32 = rng.random_range(10.0..20.0);
        let d: f32 = rng.random_range(10.0..20.0);
        let x = bx * block_w + lx * LOT + rng.random_range(2.0..(LOT - w - 2.0).max(2.0001));
        let z = bz * block_d + lz * LOT + rng.random_range(2.0..(LOT - d - 2.0).max(2.0001));
        let tall = rng.random_bool(opts.tall_share);
        let h: f32 = if tall {
            rng.random_range(50.0..150.0)
        } else {
            rng.random_range(8.0..30.0)
        };
        let mesh = building(&mut rng, w, d, h);
        extent = extent.max(Vec3::new(x + w, 0.0, z + d));
        let mesh = doc.add_mesh(mesh);
        let mut node = Node::named(format!("building_{i:04}"));
        node.translation = [x, 0.0, z];
        node.mesh = Some(mesh);
        node.extras = Some(json!({ "occluder": true, "kind": "building" }));
        children.push(doc.add_node(node));
    }
    let margin = STREET;
    let mut ground = MeshBuilder::new();
    let (lo, hi) = (Vec3::splat(-margin), extent + Vec3::splat(margin));
    ground.quad(
        Vec3::new(lo.x, 0.0, lo.z),
        Vec3::new(lo.x, 0.0, hi.z),
        Vec3::new(hi.x, 0.0, hi.z),
        Vec3::new(hi.x, 0.0, lo.z),
    );
    let mesh = doc.add_mesh(ground.build(false));
    let mut node = Node::named("ground");
    node.mesh = Some(mesh);
    node.extras = Some(json!({ "occluder": true, "kind": "ground" }));
    children.push(doc.add_node(node));

    let mut root = Node::named("city");
    root.rotation = Quat::from_rotation_y(15f32.to_radians()).to_array();
    root.translation = opts.offset;
    root.children = children;
    let root = doc.add_node(root);
    doc.roots.push(root);
    doc
}

/// One building of footprint `w × d` and height `h`, its local origin at a corner.
fn building(rng: &mut impl Rng, w: f32, d: f32, h: f32) -> crate::scene::glb::Mesh {
    let &(around, floors) = FACADES.choose(rng).expect("non-empty table");
    // Split the bays around between the x- and z-facing walls by proportion.
    let bays_x = ((around as f32 * w / (w + d)).round() as u32).clamp(1, around - 1);
    let bays_z = around - bays_x;
    let mut m = MeshBuilder::new();
    let c = [
        Vec3::ZERO,
        Vec3::new(w, 0.0, 0.0),
        Vec3::new(w, 0.0, d),
        Vec3::new(0.0, 0.0, d),
    ];
    m.wall_grid(c[0], c[1], h, bays_x, floors);
    m.wall_grid(c[1], c[2], h, bays_z, floors);
    m.wall_grid(c[2], c[3], h, bays_x, floors);
    m.wall_grid(c[3], c[0], h, bays_z, floors);
    let top = Vec3::Y * h;
    m.quad(c[0] + top, c[3] + top, c[2] + top, c[1] + top);
    if m.triangle_count() + 10 <= 180 && rng.random_bool(0.5) {
        let s = Vec3::new(w * 0.3, 0.0, d * 0.3);
        m.cuboid(
            top + s,
            top + Vec3::new(w, 0.0, d) - s + Vec3::Y * rng.random_range(2.0..5.0),
            false,
        );
    }
    m.build(false)
}
