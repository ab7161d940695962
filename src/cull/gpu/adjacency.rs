//! Which drawn triangles continue each other's surface: for each edge, the
//! neighbour's far corner, so the depth pass can tell an outline or a
//! silhouette (pulled in by a fraction of a pixel) from an edge the surface
//! runs on across (left whole, so a mesh has no cracks inside its outline).

use std::ops::Range;

use glam::Vec3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use super::vulkan::{FLAT, NO_NEIGHBOUR};

/// A vertex's exact position, as a key.
type Key = [u32; 3];

fn key(v: Vec3) -> Key {
    v.to_array().map(f32::to_bits)
}

/// For every triangle of `triangles` and each corner i, the vertex index
/// (3 × triangle + corner) of the far corner of the one other triangle of
/// its group that shares the edge opposite i exactly, or [`NO_NEIGHBOUR`]
/// (no such triangle, or more than one). Each group is a list of triangle
/// ranges (an object's opaque triangles, one proxy polygon's fan);
/// triangles of no group have no neighbours.
pub fn neighbours(triangles: &[[Vec3; 3]], groups: &[Vec<Range<u32>>]) -> Vec<[u32; 3]> {
    let mut out = vec![[NO_NEIGHBOUR; 3]; triangles.len()];
    // Groups share no triangle: found on all cores, written after.
    let pairs: Vec<Vec<(u32, u32)>> = groups
        .par_iter()
        .map(|group| shared_edges(triangles, group))
        .collect();
    for (first, second) in pairs.into_iter().flatten() {
        // Two triangles of one plane continue each other whatever the
        // view: no per-view test needed.
        let flat = coplanar(triangles, first, second) && coplanar(triangles, second, first);
        out[(first / 3) as usize][(first % 3) as usize] = if flat { FLAT } else { second };
        out[(second / 3) as usize][(second % 3) as usize] = if flat { FLAT } else { first };
    }
    out
}

/// Whether the far corner `other` (a vertex index) lies in the plane of
/// the triangle of vertex `here`, up to a few `f32` ulps of the corners'
/// size: merged occluder polygons are planar to 2 ulps, and a fold that
/// shallow shows no pixel of silhouette.
fn coplanar(triangles: &[[Vec3; 3]], here: u32, other: u32) -> bool {
    let t = triangles[(here / 3) as usize].map(|v| v.as_dvec3());
    let q = triangles[(other / 3) as usize][(other % 3) as usize].as_dvec3();
    let n = (t[1] - t[0]).cross(t[2] - t[0]);
    let size = t
        .iter()
        .chain([&q])
        .map(|v| v.abs().max_element())
        .fold(0.0, f64::max);
    let length = n.length();
    length > 0.0 && (n.dot(q - t[0]) / length).abs() <= 8.0 * f32::EPSILON as f64 * size
}

/// The pairs of (3 × triangle + corner) of one group whose opposite edges
/// are the same edge, shared by those two triangles only.
fn shared_edges(triangles: &[[Vec3; 3]], group: &[Range<u32>]) -> Vec<(u32, u32)> {
    let mut edges: FxHashMap<(Key, Key), (u32, u32)> = FxHashMap::default();
    for t in group.iter().flat_map(|r| r.clone()) {
        let v = triangles[t as usize];
        for i in 0..3 {
            let (a, b) = (key(v[(i + 1) % 3]), key(v[(i + 2) % 3]));
            let edge = if a < b { (a, b) } else { (b, a) };
            let here = 3 * t + i as u32;
            match edges.get_mut(&edge) {
                None => {
                    edges.insert(edge, (here, NO_NEIGHBOUR));
                }
                Some(seen) if seen.1 == NO_NEIGHBOUR => seen.1 = here,
                // A third triangle on one edge: no single neighbour.
                Some(seen) => *seen = (NO_NEIGHBOUR, NO_NEIGHBOUR),
            }
        }
    }
    edges
        .into_values()
        .filter(|&(first, second)| first != NO_NEIGHBOUR && second != NO_NEIGHBOUR)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quad_continues_across_its_diagonal_and_nothing_else() {
        let (a, b, c, d) = (Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
        let tris = [[a, b, c], [a, c, d]];
        let one = |r: Range<u32>| std::iter::once(r).collect::<Vec<_>>();
        let n = neighbours(&tris, &[one(0..2)]);
        // Triangle 0's edge opposite corner 1 (c–a) is shared with
        // triangle 1's edge opposite corner 2 (a–c), in one plane.
        assert_eq!(n[0], [NO_NEIGHBOUR, FLAT, NO_NEIGHBOUR]);
        assert_eq!(n[1], [NO_NEIGHBOUR, NO_NEIGHBOUR, FLAT]);
        // Folded along the diagonal: the far corners (b, and d lifted).
        let folded = [[a, b, c], [a, c, d + Vec3::Z * 0.5]];
        let n = neighbours(&folded, &[one(0..2)]);
        assert_eq!((n[0][1], n[1][2]), (3 + 2, 1));
        // In different groups they are strangers.
        let apart = neighbours(&tris, &[one(0..1), one(1..2)]);
        assert!(apart.iter().flatten().all(|&v| v == NO_NEIGHBOUR));
        // A third triangle on the same edge: nobody's neighbour there.
        let fin = [[a, b, c], [a, c, d], [a, c, Vec3::Z]];
        let n = neighbours(&fin, &[one(0..3)]);
        assert_eq!(n[0][1], NO_NEIGHBOUR);
    }
}
