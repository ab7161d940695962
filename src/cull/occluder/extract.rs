//! Merging an object's coplanar triangles into maximal convex polygons.

use rustc_hash::FxHashMap;

use glam::{DVec3, Vec3};

use super::Occluder;
use crate::geom::ConvexPolygon;
use crate::scene::{Object, Scene};

/// Occluder polygons of a scene (module docs of [`super`]).
pub(super) fn occluder_polygons(scene: &Scene) -> Vec<Occluder> {
    let hinted = scene.objects().iter().any(|o| o.occluder_hint.is_some());
    let b = scene.bounds();
    if b.is_empty() {
        return Vec::new();
    }
    let diagonal = b.extent().length() as f64;
    // Flagged files name their occluders: keep all but slivers. Unflagged
    // ones are searched: keep only what is large against the scene.
    let min_area = if hinted {
        (1e-3 * diagonal).powi(2)
    } else {
        (0.05 * diagonal).powi(2)
    };
    let mut out = Vec::new();
    for o in scene.objects() {
        if (hinted && o.occluder_hint != Some(true)) || !o.is_static() {
            continue;
        }
        for polygon in object_polygons(scene, o) {
            let area = polygon.area();
            let Some(plane) = polygon.plane() else {
                continue;
            };
            if area < min_area {
                continue;
            }
            out.push(Occluder::new(polygon, plane, area));
        }
    }
    out
}

/// An object's opaque triangles merged into maximal convex polygons, of
/// every size (see-through triangles left out: they never hide anything).
pub(crate) fn object_polygons(scene: &Scene, o: &Object) -> Vec<ConvexPolygon> {
    let tris: Vec<[Vec3; 3]> = (o.triangles.start..o.triangles.end)
        .filter(|t| !o.see_through.iter().any(|r| r.contains(t)))
        .map(|t| scene.triangles()[t as usize])
        .collect();
    merge_coplanar(&tris)
}

/// A vertex's exact position, as a hashable key.
type Key = [u32; 3];

fn key(v: Vec3) -> Key {
    [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]
}

/// What a bake of the occluders depends on beyond the scene file: change
/// it whenever extraction changes (a rule, a constant below), so that old
/// bakes are rebuilt.
pub(super) const BAKE_PARAMS: &str = "merge-v1 normal=1e-4 offset=1e-3 planarity=2ulps";

/// Triangles whose unit normals round to the same multiple of this are
/// tried together for merging. Grouping only proposes candidates: every
/// merge must still pass [`is_planar`], so a coarser or finer quantum
/// changes which polygons merge, never whether an occluder floats off its
/// surface.
const NORMAL_QUANTUM: f64 = 1e-4;

/// Likewise for the planes' offsets from the origin (scene units).
const OFFSET_QUANTUM: f64 = 1e-3;

/// A merged polygon is planar when every corner lies within this many
/// `f32` ulps (of the largest coordinate) of its plane: see [`is_planar`].
pub(crate) const PLANARITY_ULPS: f64 = 2.0;

/// A corner counts as convex when its turn against the loop's normal is
/// above minus this share of its edges' lengths: a union bent inwards by
/// no more than rounding is still taken as convex. Its edge planes then
/// bound a region inside the union of the object's own triangles, so its
/// shadow is never larger than the real one.
const TURN_TOLERANCE: f64 = 1e-9;

/// A corner whose edges' cross product is under this share of their
/// lengths' product does not turn and is dropped: moving the outline by
/// 1e-12 of an edge is a thousand times below the plane tolerance
/// (`occlusion::tolerance`) every shadow test already allows for.
const COLLINEAR: f64 = 1e-12;

/// Groups triangles by plane, then merges triangles that share an edge
/// exactly while the union stays convex.
fn merge_coplanar(tris: &[[Vec3; 3]]) -> Vec<ConvexPolygon> {
    let mut groups: FxHashMap<[i64; 4], Vec<Vec<Vec3>>> = FxHashMap::default();
    for t in tris {
        let n = (t[1] - t[0]).as_dvec3().cross((t[2] - t[0]).as_dvec3());
        let Some(n) = n.try_normalize() else { continue };
        // One orientation per plane, so a wall's two sides stay apart but
        // the two windings of one side group together.
        let d = -n.dot(t[0].as_dvec3());
        let q = |x: f64, quantum: f64| (x / quantum).round() as i64;
        groups
            .entry([
                q(n.x, NORMAL_QUANTUM),
                q(n.y, NORMAL_QUANTUM),
                q(n.z, NORMAL_QUANTUM),
                q(d, OFFSET_QUANTUM),
            ])
            .or_default()
            .push(t.to_vec());
    }
    let mut out = Vec::new();
    for (_, polys) in groups {
        out.extend(
            merge_group(polys)
                .into_iter()
                .map(|p| ConvexPolygon::new(drop_collinear(&p))),
        );
    }
    out
}

/// Greedy merging within one plane. Polygons keep collinear vertices while
/// merging, so that a neighbour's edge still matches one of theirs exactly.
fn merge_group(mut polys: Vec<Vec<Vec3>>) -> Vec<Vec<Vec3>> {
    let mut alive = vec![true; polys.len()];
    loop {
        let mut edges: FxHashMap<(Key, Key), usize> = FxHashMap::default();
        for (i, p) in polys.iter().enumerate().filter(|(i, _)| alive[*i]) {
            for e in 0..p.len() {
                edges.insert((key(p[e]), key(p[(e + 1) % p.len()])), i);
            }
        }
        let mut merged_any = false;
        for i in 0..polys.len() {
            if !alive[i] {
                continue;
            }
            let p = polys[i].clone();
            for e in 0..p.len() {
                let (a, b) = (key(p[e]), key(p[(e + 1) % p.len()]));
                let Some(&j) = edges.get(&(b, a)) else {
                    continue;
                };
                if j == i || !alive[j] {
                    continue;
                }
                if let Some(m) = union_if_convex(&polys[i], &polys[j], p[e]) {
                    polys[i] = m;
                    alive[j] = false;
                    merged_any = true;
                    break;
                }
            }
        }
        if !merged_any {
            break;
        }
    }
    polys
        .into_iter()
        .zip(alive)
        .filter(|(_, a)| *a)
        .map(|(p, _)| p)
        .collect()
}

/// The union of `p` (with edge `a → b`) and `q` (with edge `b → a`), if convex.
fn union_if_convex(p: &[Vec3], q: &[Vec3], a: Vec3) -> Option<Vec<Vec3>> {
    let (np, nq) = (p.len(), q.len());
    // The exact edge a → b of p, and b → a of q (a vertex may repeat elsewhere).
    let ia = (0..np).find(|&i| key(p[i]) == key(a) && edge_in(q, p[(i + 1) % np], a))?;
    let ja = (0..nq)
        .find(|&j| key(q[j]) == key(a) && key(q[(j + nq - 1) % nq]) == key(p[(ia + 1) % np]))?;
    // p's loop from b round to a, then q's loop strictly between a and b.
    let mut out: Vec<Vec3> = (0..np).map(|k| p[(ia + 1 + k) % np]).collect();
    out.extend((1..nq - 1).map(|k| q[(ja + k) % nq]));
    remove_spikes(&mut out);
    let mut keys: Vec<Key> = out.iter().map(|&v| key(v)).collect();
    keys.sort_unstable();
    let simple = keys.windows(2).all(|w| w[0] != w[1]);
    (simple && out.len() >= 3 && is_convex(&out) && is_planar(&out)).then_some(out)
}

/// Whether every corner lies within 2 `f32` ulps of the loop's plane.
/// Triangles whose planes differ by more (a floor bent by a centimetre)
/// are not merged: the merged plane would float off the real surface and
/// hide what lies just above it. Two ulps stay well inside the ground
/// truth's tie tolerance of eight.
fn is_planar(loop_: &[Vec3]) -> bool {
    let n = loop_.len();
    let v = |i: usize| loop_[i % n].as_dvec3();
    let Some(normal) = (0..n)
        .fold(DVec3::ZERO, |acc, i| acc + v(i).cross(v(i + 1)))
        .try_normalize()
    else {
        return false;
    };
    let centroid = (0..n).map(v).sum::<DVec3>() / n as f64;
    let magnitude = (0..n).map(|i| v(i).abs().max_element()).fold(0.0, f64::max);
    let tolerance = PLANARITY_ULPS * f32::EPSILON as f64 * magnitude;
    (0..n).all(|i| normal.dot(v(i) - centroid).abs() <= tolerance)
}

/// Whether `q` has the edge `b → a`.
fn edge_in(q: &[Vec3], b: Vec3, a: Vec3) -> bool {
    let n = q.len();
    (0..n).any(|j| key(q[j]) == key(b) && key(q[(j + 1) % n]) == key(a))
}

/// Removes the back-and-forth `x, v, x` left where two polygons shared a
/// chain of several edges and were joined across one of them.
fn remove_spikes(loop_: &mut Vec<Vec3>) {
    let mut changed = true;
    while changed && loop_.len() >= 3 {
        changed = false;
        let n = loop_.len();
        for i in 0..n {
            let (prev, next) = (loop_[(i + n - 1) % n], loop_[(i + 1) % n]);
            if key(prev) == key(next) {
                // Drop the tip and one copy of the base.
                let (tip, base) = (i, (i + 1) % n);
                let (first, second) = if tip > base { (tip, base) } else { (base, tip) };
                loop_.remove(first);
                loop_.remove(second);
                changed = true;
                break;
            }
        }
    }
}

/// Whether a planar loop turns one way only (straight corners allowed,
/// reversals not).
fn is_convex(loop_: &[Vec3]) -> bool {
    let n = loop_.len();
    let v = |i: usize| loop_[i % n].as_dvec3();
    let normal = (0..n).fold(DVec3::ZERO, |acc, i| acc + v(i).cross(v(i + 1)));
    let scale = normal.length();
    if scale <= 0.0 {
        return false;
    }
    (0..n).all(|i| {
        let (e1, e2) = (v(i + 1) - v(i), v(i + 2) - v(i + 1));
        let turn = e1.cross(e2);
        let tol = TURN_TOLERANCE * e1.length() * e2.length();
        turn.dot(normal) / scale >= -tol && (turn.length() > tol || e1.dot(e2) > 0.0)
    })
}

/// The loop without corners that do not turn.
fn drop_collinear(loop_: &[Vec3]) -> Vec<DVec3> {
    let n = loop_.len();
    let v = |i: usize| loop_[i % n].as_dvec3();
    (0..n)
        .filter(|&i| {
            let (a, b, c) = (v(i + n - 1), v(i), v(i + 1));
            (b - a).cross(c - b).length() > COLLINEAR * (b - a).length() * (c - b).length()
        })
        .map(v)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_facade_of_quads_becomes_one_rectangle() {
        let mut m = crate::scene::generate::MeshBuilder::new();
        m.wall_grid(Vec3::ZERO, Vec3::new(12.0, 0.0, 0.0), 9.0, 4, 3);
        let mesh = m.build(false);
        let tris: Vec<[Vec3; 3]> = mesh.triangles().collect();
        let polys = merge_coplanar(&tris);
        assert_eq!(polys.len(), 1, "{polys:?}");
        assert_eq!(polys[0].vertices.len(), 4);
        assert!((polys[0].area() - 108.0).abs() < 1e-9);
    }

    #[test]
    fn a_bent_floor_stays_two_triangles() {
        // Review finding: both halves had the same rounded plane key, merged
        // into one quad whose plane floated 1 cm above the real floor.
        let (a, b, c, d) = (
            Vec3::new(-500.0, -500.0, 0.0),
            Vec3::new(500.0, -500.0, 0.0),
            Vec3::new(500.0, 500.0, 0.0),
            Vec3::new(-500.0, 500.0, 0.04),
        );
        let polys = merge_coplanar(&[[a, b, c], [a, c, d]]);
        assert_eq!(polys.len(), 2, "{polys:?}");
    }

    #[test]
    fn a_box_gives_six_faces_and_an_l_stays_two() {
        let mut m = crate::scene::generate::MeshBuilder::new();
        m.cuboid(Vec3::ZERO, Vec3::new(2.0, 3.0, 4.0), true);
        m.quad(
            Vec3::new(10.0, 0.0, 0.0),
            Vec3::new(12.0, 0.0, 0.0),
            Vec3::new(12.0, 1.0, 0.0),
            Vec3::new(10.0, 1.0, 0.0),
        );
        m.quad(
            Vec3::new(10.0, 1.0, 0.0),
            Vec3::new(11.0, 1.0, 0.0),
            Vec3::new(11.0, 2.0, 0.0),
            Vec3::new(10.0, 2.0, 0.0),
        );
        let mesh = m.build(false);
        let tris: Vec<[Vec3; 3]> = mesh.triangles().collect();
        let polys = merge_coplanar(&tris);
        let total: f64 = polys.iter().map(|p| p.area()).sum();
        assert!((total - (2.0 * (6.0 + 8.0 + 12.0) + 3.0)).abs() < 1e-9);
        // Six box faces, and the L-shape (not convex) in two pieces.
        assert_eq!(polys.len(), 8, "{polys:?}");
        assert!(
            polys
                .iter()
                .all(|p| is_convex(&p.vertices.iter().map(|v| v.as_vec3()).collect::<Vec<_>>()))
        );
    }
}
