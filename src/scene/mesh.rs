//! One object's triangles as an indexed mesh, for clients that draw them
//! (`GET /scenes/{id}/objects/{oid}/mesh`).
//!
//! A scene keeps triangles as soup ([`Scene::triangles`]); a client wants
//! shared vertices. Vertices are merged only where their `f32` bits are
//! equal, so the mesh is the very triangles the methods cull with: a client
//! drawing it sees nothing a conservative answer did not promise. Opaque
//! triangles come first and see-through ones after, so one count tells
//! them apart. A movable object is drawn where it is now
//! ([`crate::scene::Motion::carry_of`]).

use glam::Vec3;
use rustc_hash::FxHashMap;

use super::{Object, Scene};

/// An object's triangles with shared vertices, scene-local.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IndexedMesh {
    /// Vertex positions, scene-local.
    pub positions: Vec<[f32; 3]>,
    /// Three indices per triangle: opaque triangles, then see-through ones.
    pub indices: Vec<u32>,
    /// How many of the first triangles are opaque.
    pub opaque: u32,
}

impl IndexedMesh {
    /// The triangles of `object` of `scene`, where the object is now.
    pub fn of(scene: &Scene, object: &Object) -> IndexedMesh {
        let all = scene.triangles();
        let opaque = object.opaque_ranges();
        let carry = object
            .movable
            .then(|| scene.motion().carry_of(object.id))
            .flatten()
            .filter(|c| *c != glam::DMat4::IDENTITY);
        let mut mesh = IndexedMesh::default();
        let mut seen: FxHashMap<[u32; 3], u32> = FxHashMap::default();
        let mut push = |mesh: &mut IndexedMesh, range: &std::ops::Range<u32>| {
            for t in &all[range.start as usize..range.end as usize] {
                for &v in t {
                    let v = match carry {
                        // Carried in f64 about the world, as the object's
                        // box was (`Motion::place`).
                        Some(c) => (c.transform_point3(scene.origin + v.as_dvec3()) - scene.origin)
                            .as_vec3(),
                        None => v,
                    };
                    let next = mesh.positions.len() as u32;
                    let i = *seen.entry(bits(v)).or_insert_with(|| {
                        mesh.positions.push(v.to_array());
                        next
                    });
                    mesh.indices.push(i);
                }
            }
        };
        for r in &opaque {
            push(&mut mesh, r);
        }
        mesh.opaque = (mesh.indices.len() / 3) as u32;
        for r in &object.see_through {
            push(&mut mesh, r);
        }
        mesh
    }
}

/// The bits of a position: `-0.0` and `0.0` stay apart, which is harmless
/// (a duplicate vertex) and keeps every vertex exactly as culled.
fn bits(v: Vec3) -> [u32; 3] {
    [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::scene::SceneBuilder;

    #[test]
    fn shares_vertices_and_keeps_every_triangle_exactly() {
        let mut b = SceneBuilder::new("t");
        b.begin_object("quad", None);
        let (p, q, r, s) = (
            DVec3::new(1000.0, 0.0, 0.0),
            DVec3::new(1001.0, 0.0, 0.0),
            DVec3::new(1001.0, 1.0, 0.0),
            DVec3::new(1000.0, 1.0, 0.0),
        );
        b.add_triangles([[p, q, r], [p, r, s]], false);
        b.add_triangles([[p, q, s]], true);
        let scene = b.finish();
        let o = &scene.objects()[0];
        let m = IndexedMesh::of(&scene, o);
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.indices.len(), 9);
        assert_eq!(m.opaque, 2);
        let triangles: Vec<[Vec3; 3]> = m
            .indices
            .chunks(3)
            .map(|t| [0, 1, 2].map(|k| Vec3::from_array(m.positions[t[k] as usize])))
            .collect();
        let soup = scene.object_triangles(o);
        assert_eq!(triangles, soup);
    }
}
