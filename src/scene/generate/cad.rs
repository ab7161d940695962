//! `pvsd gen cad`: a closed, finely tessellated body around many dense
//! parts, like the car of Bernardini et al. §5 (162k polygons): the kind of
//! model in which no single triangle hides much, for directional
//! discretized occluders.
//!
//! The body is a rounded box (a cube's six faces on a grid, pushed out to
//! a superellipsoid) with a skin of two layers, outer and inner, joined by
//! rims around its windows: a closed surface with openings, so some parts
//! are seen from outside and most are not. The parts (spheres of a few
//! hundred triangles, stretched into pipes and blocks) fill its inside.
//! Deterministic by seed.

use glam::Vec3;
use rand::Rng;
use serde_json::json;

use super::mesh::MeshBuilder;
use super::rng;
use crate::scene::glb::{Document, Node};

/// Knobs of the CAD generator.
#[derive(Clone, Debug, PartialEq)]
pub struct CadOptions {
    /// Seed: the same seed gives the same bytes.
    pub seed: u64,
    /// Cells along each edge of each of the body's six faces (the body has
    /// 24 × cells² triangles before its windows).
    pub cells: u32,
    /// Inner parts.
    pub parts: u32,
    /// Translation of the whole model, for precision tests far from the origin.
    pub offset: [f32; 3],
}

impl Default for CadOptions {
    fn default() -> Self {
        // ~65k body triangles and ~100k in parts: the paper's car.
        CadOptions {
            seed: 1,
            cells: 52,
            parts: 400,
            offset: [0.0; 3],
        }
    }
}

/// Half-extents of the body, metres (a car's proportions).
const HALF: Vec3 = Vec3::new(2.2, 0.75, 0.9);
/// The inner layer of the skin, as a share of the outer one.
const INNER: f32 = 0.96;
/// Exponent of the superellipsoid: 4 gives a rounded box.
const ROUNDNESS: f32 = 4.0;

/// A point of the unit cube's surface pushed out to the rounded box, at
/// `scale` of the body's size.
fn skin_point(c: Vec3, scale: f32) -> Vec3 {
    let norm = (c.x.abs().powf(ROUNDNESS) + c.y.abs().powf(ROUNDNESS) + c.z.abs().powf(ROUNDNESS))
        .powf(1.0 / ROUNDNESS);
    c / norm * HALF * scale
}

/// Whether cell `(i, j)` of face `face` (of `n × n`) is a window: two
/// windows on each long side, a windscreen and a rear window, none on the
/// roof, the floor or the ends.
fn is_window(face: usize, i: u32, j: u32, n: u32) -> bool {
    let (u, v) = ((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
    let band = |lo: f32, hi: f32, x: f32| lo <= x && x < hi;
    match face {
        // ±z: the long sides; u runs along x, v along y.
        4 | 5 => band(0.55, 0.8, v) && (band(0.15, 0.42, u) || band(0.58, 0.85, u)),
        // ±x: the ends; u along y, v along z.
        0 | 1 => band(0.55, 0.82, u) && band(0.2, 0.8, v),
        _ => false,
    }
}

/// The body: both layers of the skin on every face, rims where a window
/// cell meets a solid one (or the next face), all one closed surface.
fn body(n: u32) -> MeshBuilder {
    let mut m = MeshBuilder::new();
    // Face f: axis f / 2 fixed at ±1, (u, v) over the other two axes.
    let corner = |face: usize, i: u32, j: u32| -> Vec3 {
        let axis = face / 2;
        let sign = if face % 2 == 0 { -1.0 } else { 1.0 };
        let (a, b) = (
            -1.0 + 2.0 * i as f32 / n as f32,
            -1.0 + 2.0 * j as f32 / n as f32,
        );
        match axis {
            0 => Vec3::new(sign, a, b),
            1 => Vec3::new(a, sign, b),
            _ => Vec3::new(a, b, sign),
        }
    };
    for face in 0..6 {
        for j in 0..n {
            for i in 0..n {
                if is_window(face, i, j, n) {
                    // Rims on the window's edges that border solid cells.
                    let edges = [
                        (
                            i + 1 == n || !is_window(face, i + 1, j, n),
                            (i + 1, j),
                            (i + 1, j + 1),
                        ),
                        (i == 0 || !is_window(face, i - 1, j, n), (i, j + 1), (i, j)),
                        (
                            j + 1 == n || !is_window(face, i, j + 1, n),
                            (i + 1, j + 1),
                            (i, j + 1),
                        ),
                        (j == 0 || !is_window(face, i, j - 1, n), (i, j), (i + 1, j)),
                    ];
                    for (solid, p, q) in edges {
                        if solid {
                            let (p, q) = (corner(face, p.0, p.1), corner(face, q.0, q.1));
                            m.quad(
                                skin_point(p, 1.0),
                                skin_point(q, 1.0),
                                skin_point(q, INNER),
                                skin_point(p, INNER),
                            );
                        }
                    }
                    continue;
                }
                let c = [
                    corner(face, i, j),
                    corner(face, i + 1, j),
                    corner(face, i + 1, j + 1),
                    corner(face, i, j + 1),
                ];
                for scale in [1.0, INNER] {
                    let p = c.map(|c| skin_point(c, scale));
                    m.quad(p[0], p[1], p[2], p[3]);
                }
            }
        }
    }
    m
}

/// The model as a glTF document: one root `cad` node whose children are
/// `body` (flagged `extras.occluder`) and `part_<n>`.
pub fn cad(opts: &CadOptions) -> Document {
    let mut rng = rng(opts.seed);
    let mut doc = Document::default();
    let mut children = Vec::new();
    let n = opts.cells.max(2);
    let mesh = doc.add_mesh(body(n).build(false));
    let mut node = Node::named("body");
    node.mesh = Some(mesh);
    node.extras = Some(json!({ "occluder": true, "kind": "body" }));
    children.push(doc.add_node(node));

    // Parts well inside the inner skin (its rounded box holds the box of
    // 0.7 of its half-extents).
    let room = HALF * INNER * 0.7;
    for k in 0..opts.parts {
        let radius: f32 = rng.random_range(0.04..0.16);
        let stretch = Vec3::new(
            rng.random_range(0.5..3.0),
            rng.random_range(0.5..1.5),
            rng.random_range(0.5..1.5),
        );
        let reach = stretch * radius;
        let center = Vec3::new(
            rng.random_range(-room.x + reach.x..room.x - reach.x),
            rng.random_range(-room.y + reach.y..room.y - reach.y),
            rng.random_range(-room.z + reach.z..room.z - reach.z),
        );
        let mut part = MeshBuilder::new();
        part.uv_sphere(Vec3::ZERO, 1.0, 11, 14);
        let mut mesh = part.build(false);
        // Stretched into a pipe, a block or a ball.
        for p in &mut mesh.positions {
            *p = (Vec3::from(*p) * reach).to_array();
        }
        let mesh = doc.add_mesh(mesh);
        let mut node = Node::named(format!("part_{k:04}"));
        node.mesh = Some(mesh);
        node.translation = center.to_array();
        node.extras = Some(json!({ "kind": "part" }));
        children.push(doc.add_node(node));
    }

    let mut root = Node::named("cad");
    root.translation = opts.offset;
    root.children = children;
    let root = doc.add_node(root);
    doc.roots.push(root);
    doc
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;

    /// Every edge of the body is shared by exactly two of its triangles.
    #[test]
    fn the_body_is_closed_and_has_windows() {
        let n = 12;
        let mesh = body(n).build(false);
        let key = |v: Vec3| v.to_array().map(f32::to_bits);
        let mut edges: HashMap<([u32; 3], [u32; 3]), u32> = HashMap::new();
        let mut triangles = 0;
        for t in mesh.triangles() {
            triangles += 1;
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                let (a, b) = (key(a), key(b));
                *edges
                    .entry(if a < b { (a, b) } else { (b, a) })
                    .or_default() += 1;
            }
        }
        let open: Vec<_> = edges.values().filter(|&&c| c != 2).collect();
        assert!(
            open.is_empty(),
            "{} edges not shared by two triangles",
            open.len()
        );
        assert!(triangles < 24 * n * n, "windows cut the skin ({triangles})");
    }

    #[test]
    fn the_default_is_the_papers_size_and_the_same_for_a_seed() {
        let a = cad(&CadOptions::default());
        let triangles: usize = a.meshes.iter().map(|m| m.triangles().count()).sum();
        assert!((140_000..190_000).contains(&triangles), "{triangles}");
        assert_eq!(a.to_glb(), cad(&CadOptions::default()).to_glb());
        let other = cad(&CadOptions {
            seed: 2,
            ..CadOptions::default()
        });
        assert_ne!(a.to_glb(), other.to_glb());
    }
}
