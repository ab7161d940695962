//! Conservative proxies for closed objects made of many small polygons
//! (issue 16's "proxies that lie inside the geometry"): boxes strictly
//! inside the solid that an object's opaque triangles enclose, found on a
//! voxel grid as in Schaufler et al.'s volumetric occluders (SIGGRAPH
//! 2000), then merged into few large boxes whose faces `raster` draws
//! where the object's own polygons are each too small to fill a cell.
//!
//! **Why a proxy hides no more than the object.** The object's opaque
//! triangles close up (every edge, by its ends' exact positions, shared by
//! an even number of them, [`super::surfaces`]; how they are wound does
//! not matter), so they bound a solid: a point is inside when a ray from
//! it crosses them an odd number of times, and any path from outside to an
//! inside point crosses them. An eye outside the
//! object's box is outside the solid; the segment from it to a point of a
//! proxy therefore crosses a triangle first, at least `margin` nearer
//! (every proxy point lies that far from every triangle). So at every
//! pixel centre a proxy face covers, ground truth's nearest surface is at
//! least as near as the face, and whatever lies behind the face there is
//! behind the object too. `raster` draws proxies only when the eye is
//! outside the object's box and the box lies beyond the near plane (where
//! ground truth clips nothing of the crossing), and their corners are
//! rounded inward to `f32`: a smaller box is still inside.
//!
//! **How a voxel is known to be inside.** A voxel is kept only if (a) no
//! triangle comes within `margin` of it — a separating-axis test
//! (Akenine-Möller's 13 axes) against the voxel grown by `margin`, far
//! above `f64` rounding of the object's local coordinates, so rounding can
//! only report a touch that is not there — and (b) the line along `x`
//! through its centre crosses the triangles an odd number of times before
//! it. Crossings are counted per row of voxel centres, in coordinates
//! local to the object's box (each vertex rounded once, the same for every
//! triangle that shares it, so the mesh stays closed). A row whose line
//! passes within a tolerance of any triangle's edge (as seen along `x`),
//! or crosses an odd number of times, could be counted wrong: it is
//! counted again along a line moved inside its voxels (an untouched voxel
//! is crossed by no triangle, so every line through it gives it the same
//! parity), and if that is unsure too it keeps no voxel.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::surfaces::outside;
use crate::geom::Aabb;
use crate::scene::{BakeCache, Object, Scene};

/// Closed static objects of at least this many opaque triangles get
/// proxies: one of fewer has polygons about as large as itself already.
const PROXY_TRIANGLES: usize = 64;

/// The bake cache's parameters for proxies: the method's version and every
/// constant that changes what it finds.
const BAKE_PARAMS: &str = "proxies-v2 resolution=512 voxels/triangle=512 max=2^25 side=3 smallest=1/16 triangles/box=64 boxes>=8 triangles>=64 margin=1e-6";

/// Per object, whether it gets proxies: static, of enough opaque
/// triangles, and closed.
fn solids(scene: &Scene) -> Vec<bool> {
    scene
        .objects()
        .par_iter()
        .map(|o| {
            o.is_static()
                && o.triangle_count() as usize >= PROXY_TRIANGLES
                && o.opaque_ranges().iter().map(|r| r.len()).sum::<usize>() >= PROXY_TRIANGLES
                && outside(scene, o).1
        })
        .collect()
}

/// The opaque triangles of `o`.
fn opaque_triangles(scene: &Scene, o: &Object) -> Vec<[Vec3; 3]> {
    o.opaque_ranges()
        .into_iter()
        .flat_map(|r| &scene.triangles()[r.start as usize..r.end as usize])
        .copied()
        .collect()
}

/// The proxies of every object of a scene (none for most).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Proxies {
    by_object: Vec<Vec<Aabb>>,
}

impl Proxies {
    /// The proxies of the objects `solid` marks, on all cores.
    fn of_solids(scene: &Scene, solid: &[bool]) -> Proxies {
        let by_object = scene
            .objects()
            .par_iter()
            .zip(solid)
            .map(|(o, &solid)| {
                if !solid {
                    return Vec::new();
                }
                inner_boxes(&opaque_triangles(scene, o), &o.bounds)
            })
            .collect();
        Proxies { by_object }
    }

    /// The proxies of `scene`'s closed static objects, read from `cache`
    /// when an earlier run baked them for this scene file, and baked there
    /// when not. A scene with no object that could have proxies writes no
    /// file.
    pub fn build_cached(scene: &Scene, cache: Option<&BakeCache>) -> Proxies {
        let solid = solids(scene);
        match cache {
            Some(cache) if solid.contains(&true) => {
                let bounds: Vec<Aabb> = scene.objects().iter().map(|o| o.bounds).collect();
                cache
                    .load_or_build(
                        scene,
                        "proxies",
                        BAKE_PARAMS,
                        || Proxies::of_solids(scene, &solid),
                        Proxies::encode,
                        |bytes| Proxies::decode(bytes, &solid, &bounds),
                    )
                    .0
            }
            _ => Proxies::of_solids(scene, &solid),
        }
    }

    /// The proxies of object `id`, largest first.
    pub fn of(&self, id: usize) -> &[Aabb] {
        self.by_object.get(id).map_or(&[], Vec::as_slice)
    }

    /// How many in all.
    pub fn len(&self) -> usize {
        self.by_object.iter().map(Vec::len).sum()
    }

    /// The bake payload (proto/bake-format.md): a `u32` count of objects,
    /// each a `u32` count of boxes and six `f32` per box (min, then max).
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(&(self.by_object.len() as u32).to_le_bytes());
        for boxes in &self.by_object {
            out.extend_from_slice(&(boxes.len() as u32).to_le_bytes());
            for b in boxes {
                for v in b.min.to_array().into_iter().chain(b.max.to_array()) {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        out
    }

    /// A payload read back, for a scene of `objects` objects; an error
    /// names what does not fit (the cache then rebuilds).
    pub fn decode(bytes: &[u8], solid: &[bool], bounds: &[Aabb]) -> Result<Proxies, String> {
        if bytes.len() % 4 != 0 {
            return Err("proxies: not a whole number of words".into());
        }
        let objects = solid.len();
        let mut words = bytes
            .chunks(4)
            .map(|c| <[u8; 4]>::try_from(c).map_err(|_| "proxies: truncated".to_string()));
        let mut next = || words.next().unwrap_or(Err("proxies: truncated".into()));
        let count = u32::from_le_bytes(next()?) as usize;
        if count != objects {
            return Err(format!("proxies: {count} objects, the scene has {objects}"));
        }
        let mut by_object = Vec::with_capacity(count);
        for (&solid, within) in solid.iter().zip(bounds) {
            let n = u32::from_le_bytes(next()?) as usize;
            if n > 0 && !solid {
                return Err("proxies: boxes for an object that does not close up".into());
            }
            let mut boxes = Vec::with_capacity(n.min(1 << 20));
            for _ in 0..n {
                let mut v = [0f32; 6];
                for x in &mut v {
                    *x = f32::from_le_bytes(next()?);
                }
                let b = Aabb::new(Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5]));
                if !(b.min.is_finite() && b.max.is_finite() && b.min.cmplt(b.max).all()) {
                    return Err("proxies: a box that is not one".into());
                }
                if !(b.min.cmpgt(within.min).all() && b.max.cmplt(within.max).all()) {
                    return Err("proxies: a box not inside its object's".into());
                }
                boxes.push(b);
            }
            by_object.push(boxes);
        }
        if next().is_ok() {
            return Err("proxies: bytes after the last object".into());
        }
        Ok(Proxies { by_object })
    }
}

/// Voxels along an object's longest side: a finer grid finds boxes inside
/// thinner walls (the generated CAD body's skin is 1/60 of its length).
const RESOLUTION: f64 = 512.0;

/// Voxels per triangle an object may have: a finely tessellated object
/// may have thin walls, a coarse one is worth a coarse grid only.
const VOXELS_PER_TRIANGLE: f64 = 512.0;

/// At most this many voxels per object (a byte each while it is built).
const MAX_VOXELS: f64 = (1u64 << 25) as f64;

/// A box is kept only if its two longer sides span this many voxels: a
/// smaller one would cost more to draw than it hides.
const MIN_SIDE: usize = 3;

/// Boxes whose largest face is under this share of the largest box's
/// are left out: they hide little for their cost.
const SMALLEST: f32 = 1.0 / 16.0;

/// Boxes kept: one per this many triangles, and at least `LEAST_BOXES`.
const TRIANGLES_PER_BOX: usize = 64;
const LEAST_BOXES: usize = 8;

/// Where a row is counted again when its line passes too near an edge, in
/// voxels from their centres (inside the voxels, off their diagonals).
const ROW_MOVES: [(f64, f64); 2] = [(0.1234, 0.2718), (-0.3141, 0.1618)];

/// The voxel touches a triangle.
const TOUCHED: u8 = 1;
/// The voxel lies inside the solid, untouched.
const INSIDE: u8 = 2;
/// The voxel is in a box already.
const TAKEN: u8 = 4;

/// Boxes inside the solid that `triangles` (a closed surface) enclose
/// within `bounds`, each at least `margin` from every triangle, their
/// corners `f32` values; largest first.
pub fn inner_boxes(triangles: &[[Vec3; 3]], bounds: &Aabb) -> Vec<Aabb> {
    let origin = bounds.min.as_dvec3();
    let extent = bounds.max.as_dvec3() - origin;
    let longest = extent.max_element();
    if triangles.is_empty() || !(longest > 0.0 && longest.is_finite()) {
        return Vec::new();
    }
    let mut size = longest / RESOLUTION;
    let dims = |size: f64| (extent / size).ceil().max(DVec3::ONE);
    let most = (VOXELS_PER_TRIANGLE * triangles.len() as f64).min(MAX_VOXELS);
    while dims(size).element_product() > most {
        size *= 1.25;
    }
    let d = dims(size);
    let (dx, dy, dz) = (d.x as usize, d.y as usize, d.z as usize);
    // Far above the rounding of coordinates local to the box (~1e-16 of
    // `longest`), far below a voxel.
    let margin = 1e-6 * longest;
    let tolerance = 1e-10 * longest * longest;
    let local: Vec<[DVec3; 3]> = triangles
        .iter()
        .map(|t| t.map(|v| v.as_dvec3() - origin))
        .collect();

    // Triangles by the slabs of voxels (along z) they may touch.
    let cell = |v: f64, n: usize| ((v / size).floor().max(0.0) as usize).min(n - 1);
    let mut slabs: Vec<Vec<u32>> = vec![Vec::new(); dz];
    for (i, t) in local.iter().enumerate() {
        let (lo, hi) = span(t);
        for slab in &mut slabs[cell(lo.z - margin, dz)..=cell(hi.z + margin, dz)] {
            slab.push(i as u32);
        }
    }

    let mut voxels = vec![0u8; dx * dy * dz];
    voxels
        .par_chunks_mut(dx * dy)
        .zip(slabs.par_iter())
        .enumerate()
        .for_each(|(k, (slab, members))| {
            let zc = (k as f64 + 0.5) * size;
            let mut crossings: Vec<Vec<f64>> = vec![Vec::new(); dy];
            let mut unsure = vec![false; dy];
            let half = 0.5 * size + margin;
            for &t in members {
                let t = &local[t as usize];
                let (lo, hi) = span(t);
                let (j0, j1) = (cell(lo.y - margin, dy), cell(hi.y + margin, dy));
                let (i0, i1) = (cell(lo.x - margin, dx), cell(hi.x + margin, dx));
                for j in j0..=j1 {
                    let yc = (j as f64 + 0.5) * size;
                    for i in i0..=i1 {
                        let centre = DVec3::new((i as f64 + 0.5) * size, yc, zc);
                        if touches(t, centre, half) {
                            slab[j * dx + i] |= TOUCHED;
                        }
                    }
                    if lo.z <= zc && zc <= hi.z && lo.y <= yc && yc <= hi.y {
                        match crossing(t, yc, zc, tolerance) {
                            Crossing::None => {}
                            Crossing::At(x) => crossings[j].push(x),
                            Crossing::Unsure => unsure[j] = true,
                        }
                    }
                }
            }
            // A row that could be counted wrong is counted again along a
            // line moved inside its voxels (any line through an untouched
            // voxel gives it the same parity), twice at most.
            let along = |y: f64, z: f64| -> Option<Vec<f64>> {
                let mut row = Vec::new();
                for &t in members {
                    let t = &local[t as usize];
                    let (lo, hi) = span(t);
                    if lo.z <= z && z <= hi.z && lo.y <= y && y <= hi.y {
                        match crossing(t, y, z, tolerance) {
                            Crossing::None => {}
                            Crossing::At(x) => row.push(x),
                            Crossing::Unsure => return None,
                        }
                    }
                }
                (row.len() % 2 == 0).then_some(row)
            };
            for (j, row) in crossings.iter_mut().enumerate() {
                if unsure[j] || row.len() % 2 == 1 {
                    let yc = (j as f64 + 0.5) * size;
                    let moved = ROW_MOVES
                        .iter()
                        .find_map(|(dy, dz)| along(yc + dy * size, zc + dz * size));
                    match moved {
                        Some(again) => *row = again,
                        None => continue,
                    }
                }
                row.sort_unstable_by(f64::total_cmp);
                let mut before = 0;
                for i in 0..dx {
                    let xc = (i as f64 + 0.5) * size;
                    while before < row.len() && row[before] < xc {
                        before += 1;
                    }
                    let v = &mut slab[j * dx + i];
                    if before % 2 == 1 && *v & TOUCHED == 0 {
                        *v |= INSIDE;
                    }
                }
            }
        });

    // Greedy boxes: from each free inside voxel, grown along one axis,
    // then a second, then the third, as far as every voxel is free and
    // inside; of the three orders that leave a different axis for last,
    // the one with the largest face (a thin wall's box must grow along
    // the wall first).
    let at = |p: [usize; 3]| (p[2] * dy + p[1]) * dx + p[0];
    let n = [dx, dy, dz];
    let free = |v: &[u8], p: [usize; 3]| v[at(p)] & INSIDE != 0;
    // Whether the slab `at` along `axis` of box `lo..hi` is free.
    let slab_free = |v: &[u8], lo: [usize; 3], hi: [usize; 3], axis: usize, at: usize| {
        let (mut a, mut b) = (lo, hi);
        (a[axis], b[axis]) = (at, at + 1);
        (a[2]..b[2]).all(|z| (a[1]..b[1]).all(|y| (a[0]..b[0]).all(|x| free(v, [x, y, z]))))
    };
    let mut boxes = Vec::new();
    for k in 0..dz {
        for j in 0..dy {
            for i in 0..dx {
                let seed = [i, j, k];
                if voxels[at(seed)] & (INSIDE | TAKEN) != INSIDE {
                    continue;
                }
                let mut best: Option<([usize; 3], f64)> = None;
                for order in [[0, 1, 2], [2, 0, 1], [1, 2, 0]] {
                    let mut hi = [i + 1, j + 1, k + 1];
                    for axis in order {
                        while hi[axis] < n[axis] && slab_free(&voxels, seed, hi, axis, hi[axis]) {
                            hi[axis] += 1;
                        }
                    }
                    let mut sides = [hi[0] - i, hi[1] - j, hi[2] - k];
                    sides.sort_unstable();
                    let face = (sides[1] * sides[2]) as f64;
                    if best.is_none_or(|(_, f)| face > f) {
                        best = Some((hi, face));
                    }
                }
                let (hi, _) = best.expect("three orders tried");
                for z in k..hi[2] {
                    for y in j..hi[1] {
                        for x in i..hi[0] {
                            voxels[at([x, y, z])] |= TAKEN;
                        }
                    }
                }
                let mut sides = [hi[0] - i, hi[1] - j, hi[2] - k];
                sides.sort_unstable();
                if sides[1] < MIN_SIDE {
                    continue;
                }
                let lo = origin + DVec3::new(i as f64, j as f64, k as f64) * size;
                let hi = origin + DVec3::new(hi[0] as f64, hi[1] as f64, hi[2] as f64) * size;
                if let Some(b) = Aabb::enclosed(lo, hi) {
                    boxes.push(b);
                }
            }
        }
    }
    // What a box hides is about its largest face; boxes overlap, so the
    // largest few hide nearly all the many would.
    let face = |b: &Aabb| {
        let e = b.extent();
        (e.x * e.y).max(e.y * e.z).max(e.z * e.x)
    };
    boxes.sort_by(|a, b| face(b).total_cmp(&face(a)));
    let least = boxes.first().map_or(0.0, |b| face(b) * SMALLEST);
    let most = (triangles.len() / TRIANGLES_PER_BOX).max(LEAST_BOXES);
    boxes.truncate(most);
    boxes.retain(|b| face(b) >= least);
    boxes
}

/// The least and greatest corner of a triangle.
fn span(t: &[DVec3; 3]) -> (DVec3, DVec3) {
    (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]))
}

/// Whether triangle `t` comes within the box of half-side `half` around
/// `centre`, by the separating-axis theorem; `true` when unsure.
fn touches(t: &[DVec3; 3], centre: DVec3, half: f64) -> bool {
    let v = t.map(|p| p - centre);
    // The box's own axes.
    let (lo, hi) = span(&v);
    if lo.cmpgt(DVec3::splat(half)).any() || hi.cmplt(DVec3::splat(-half)).any() {
        return false;
    }
    // The triangle's normal (as rounded: every corner is projected, so any
    // axis it comes out as separates only where it truly does).
    let n = (v[1] - v[0]).cross(v[2] - v[0]);
    let r = half * n.abs().element_sum();
    let p = v.map(|p| n.dot(p));
    if p[0].min(p[1]).min(p[2]) > r || p[0].max(p[1]).max(p[2]) < -r {
        return false;
    }
    // Each box axis crossed with each edge.
    for e in 0..3 {
        let edge = v[(e + 1) % 3] - v[e];
        for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
            let a = axis.cross(edge);
            let r = half * a.abs().element_sum();
            let p = v.map(|p| a.dot(p));
            if p[0].min(p[1]).min(p[2]) > r || p[0].max(p[1]).max(p[2]) < -r {
                return false;
            }
        }
    }
    true
}

/// Where the line along `x` through `(·, y, z)` meets a triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Crossing {
    None,
    At(f64),
    /// The line passes within the tolerance of an edge.
    Unsure,
}

fn crossing(t: &[DVec3; 3], y: f64, z: f64, tolerance: f64) -> Crossing {
    // Edge functions of the triangle seen along x, at (y, z).
    let edge = |a: DVec3, b: DVec3| (b.y - a.y) * (z - a.z) - (b.z - a.z) * (y - a.y);
    let e = [edge(t[1], t[2]), edge(t[2], t[0]), edge(t[0], t[1])];
    let above = e.iter().any(|&v| v > tolerance);
    let below = e.iter().any(|&v| v < -tolerance);
    if above && below {
        return Crossing::None;
    }
    if e.iter().any(|v| v.abs() <= tolerance) {
        return Crossing::Unsure;
    }
    // Barycentric weights: e[i] is the area opposite corner i.
    let sum = e[0] + e[1] + e[2];
    Crossing::At((e[0] * t[0].x + e[1] * t[1].x + e[2] * t[2].x) / sum)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The twelve triangles of a box, wound outward.
    fn cube(lo: Vec3, hi: Vec3, inward: bool) -> Vec<[Vec3; 3]> {
        let c = |i: usize| {
            Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            )
        };
        let quads = [
            [0, 4, 6, 2],
            [1, 3, 7, 5],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 2, 3, 1],
            [4, 5, 7, 6],
        ];
        let mut out = Vec::new();
        for q in quads {
            let (a, b, c2, d) = (c(q[0]), c(q[1]), c(q[2]), c(q[3]));
            if inward {
                out.push([a, c2, b]);
                out.push([a, d, c2]);
            } else {
                out.push([a, b, c2]);
                out.push([a, c2, d]);
            }
        }
        out
    }

    /// Every triangle split into four, `times` over: a skin of tiny ones.
    fn subdivide(mut t: Vec<[Vec3; 3]>, times: usize) -> Vec<[Vec3; 3]> {
        for _ in 0..times {
            t = t
                .into_iter()
                .flat_map(|[a, b, c]| {
                    let (ab, bc, ca) = ((a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5);
                    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
                })
                .collect();
        }
        t
    }

    /// Parity of `p` against `triangles` by a ray along a skewed direction.
    fn inside_by_ray(triangles: &[[Vec3; 3]], p: DVec3) -> bool {
        let d = DVec3::new(0.5773, 0.5741, 0.5809).normalize();
        let mut n = 0;
        for t in triangles {
            let [a, b, c] = t.map(|v| v.as_dvec3());
            let (e1, e2) = (b - a, c - a);
            let q = d.cross(e2);
            let det = e1.dot(q);
            if det.abs() < 1e-15 {
                continue;
            }
            let s = p - a;
            let u = s.dot(q) / det;
            let r = s.cross(e1);
            let v = d.dot(r) / det;
            let w = e2.dot(r) / det;
            if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && w > 0.0 {
                n += 1;
            }
        }
        n % 2 == 1
    }

    /// A hollow box: outer skin outward, inner skin inward, `wall` thick.
    fn shell(wall: f32, times: usize) -> (Vec<[Vec3; 3]>, Aabb) {
        let (lo, hi) = (Vec3::new(-2.0, -0.7, -0.9), Vec3::new(2.0, 0.7, 0.9));
        let mut t = subdivide(cube(lo, hi, false), times);
        t.extend(subdivide(cube(lo + wall, hi - wall, true), times));
        (t, Aabb::new(lo, hi))
    }

    #[test]
    fn a_solid_box_is_one_box_inside_it() {
        let (lo, hi) = (Vec3::new(1.0, 2.0, 3.0), Vec3::new(2.0, 4.0, 3.5));
        let boxes = inner_boxes(&subdivide(cube(lo, hi, false), 3), &Aabb::new(lo, hi));
        assert_eq!(boxes.len(), 1);
        let b = boxes[0];
        assert!(Aabb::new(lo, hi).contains(&b) && b.min.cmpgt(lo).all() && b.max.cmplt(hi).all());
        // All but a voxel or two of the solid (768 triangles: a grid of
        // about 1/70 of its length).
        let (e, f) = (b.extent(), hi - lo);
        assert!(e.x > 0.95 * f.x && e.y > 0.95 * f.y && e.z > 0.9 * f.z, "{b:?}");
    }

    #[test]
    fn a_thin_walled_shell_keeps_its_walls_and_nothing_of_its_hollow() {
        // 6,144 triangles: voxels of about 1.5 cm in walls 6 cm thick.
        let (triangles, bounds) = shell(0.06, 4);
        let boxes = inner_boxes(&triangles, &bounds);
        assert!(!boxes.is_empty());
        let mut area = 0.0;
        for b in &boxes {
            // Every corner and the centre inside the solid (a skewed ray's
            // parity), and clear of the hollow.
            for p in b.corners().into_iter().chain([b.center()]) {
                assert!(inside_by_ray(&triangles, p.as_dvec3()), "{b:?}");
            }
            let hollow = Aabb::new(bounds.min + 0.06, bounds.max - 0.06);
            assert!(!hollow.intersects(&Aabb::new(b.min + 1e-6, b.max - 1e-6)), "{b:?}");
            let e = b.extent();
            area += (e.x * e.y).max(e.y * e.z).max(e.z * e.x);
        }
        // The walls are found nearly whole (about 22 m² of them).
        assert!(area > 18.0, "{area}");
    }

    #[test]
    fn a_wall_thinner_than_a_voxel_yields_nothing() {
        let (triangles, bounds) = shell(0.002, 1);
        assert!(inner_boxes(&triangles, &bounds).is_empty());
    }

    #[test]
    fn a_skin_wound_either_way_gives_the_same_boxes() {
        let (lo, hi) = (Vec3::splat(-1.0), Vec3::splat(1.0));
        let out = inner_boxes(&cube(lo, hi, false), &Aabb::new(lo, hi));
        let inn = inner_boxes(&cube(lo, hi, true), &Aabb::new(lo, hi));
        assert!(!out.is_empty());
        assert_eq!(out, inn);
    }

    #[test]
    fn far_from_the_origin_boxes_stay_inside() {
        let offset = Vec3::new(1e6, -1e6, 1e6);
        let (lo, hi) = (offset - 1.0, offset + 1.0);
        let triangles = subdivide(cube(lo, hi, false), 2);
        let boxes = inner_boxes(&triangles, &Aabb::new(lo, hi));
        assert!(!boxes.is_empty());
        for b in boxes {
            assert!(b.min.cmpgt(lo).all() && b.max.cmplt(hi).all(), "{b:?}");
        }
    }

    #[test]
    fn a_payload_reads_back_and_a_wrong_one_is_refused() {
        let (triangles, bounds) = shell(0.06, 4);
        let p = Proxies {
            by_object: vec![Vec::new(), inner_boxes(&triangles, &bounds), Vec::new()],
        };
        assert!(!p.of(1).is_empty());
        let bytes = p.encode();
        let solid = [false, true, false];
        let within = [Aabb::EMPTY, bounds, Aabb::EMPTY];
        assert_eq!(Proxies::decode(&bytes, &solid, &within), Ok(p.clone()));
        assert!(Proxies::decode(&bytes, &solid[..2], &within[..2]).is_err());
        assert!(Proxies::decode(&bytes[..bytes.len() - 1], &solid, &within).is_err());
        assert!(Proxies::decode(&[bytes.as_slice(), &[0; 4]].concat(), &solid, &within).is_err());
        assert!(Proxies::decode(&[bytes.as_slice(), &[0]].concat(), &solid, &within).is_err());
        // Boxes for an object that is not closed, or outside its box: stale.
        assert!(Proxies::decode(&bytes, &[false; 3], &within).is_err());
        let smaller = [Aabb::EMPTY, Aabb::new(bounds.min + 0.5, bounds.max), Aabb::EMPTY];
        assert!(Proxies::decode(&bytes, &solid, &smaller).is_err());
        let mut flipped = bytes.clone();
        flipped[12..16].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(Proxies::decode(&flipped, &solid, &within).is_err());
    }

    #[test]
    fn the_separating_axis_test_sees_a_diagonal_triangle_miss_a_corner() {
        // The plane x + y + z = 2.9 passes 0.1/√3 from the unit box's corner.
        let t = [
            DVec3::new(2.9, 0.0, 0.0),
            DVec3::new(0.0, 2.9, 0.0),
            DVec3::new(0.0, 0.0, 2.9),
        ];
        assert!(!touches(&t, DVec3::ZERO, 0.95));
        assert!(touches(&t, DVec3::ZERO, 0.97));
    }

    #[test]
    fn a_line_through_an_edge_is_unsure() {
        let t = [DVec3::ZERO, DVec3::new(0.0, 1.0, 0.0), DVec3::new(1.0, 0.0, 1.0)];
        assert_eq!(crossing(&t, 0.5, 0.0, 1e-12), Crossing::Unsure);
        assert_eq!(crossing(&t, 2.0, 0.5, 1e-12), Crossing::None);
        assert!(matches!(crossing(&t, 0.25, 0.5, 1e-12), Crossing::At(x) if (x - 0.5).abs() < 1e-12));
    }
}
