//! DDO validation (Bernardini et al. §3.2, Fig. 6): whether an octree face
//! is a valid occluder from every viewpoint of a viewspace region.
//!
//! **What is proved.** Take face `f` of a node of size `s`, in its frame
//! `(u, v, t)` ([`super::regions`]), and a region whose eyes have slopes in
//! `[a₀, a₁] × [b₀, b₁]` and `t ≥ 2s` ([`CLIP`]). A ray from such an eye to
//! a point `p` of `f` has slopes within `[a₀ − ¼, a₁ + ¼] × [b₀ − ¼, b₁ + ¼]`
//! (the eye is at least `2s` away, `p` at most `s/2` from the centre), so
//! below the plane `t = H` (`H` a hair under `2s`) it runs inside the *viewspace
//! frustum* `V = {(u, v, t) : 0 ≤ t ≤ H, u₀ + t·a_lo ≤ u ≤ u₁ + t·a_hi, …}`,
//! with those slopes widened by [`SLOPE_MARGIN`], from a point of its top
//! cap (`t = H`) to a point of its bottom cap (`f` itself). `V` is convex.
//!
//! The face is **valid** for the region when some connected set `K` of
//! opaque triangles (the paper's connected collection of polygons) has
//! 1. every *boundary edge* outside `V`: an edge of a triangle of `K` on which
//!    an odd number of `K`'s triangles meet (triangles are joined where they
//!    share two exactly equal corners; an edge of a crack, a hole, a window
//!    or a T-junction is a boundary edge);
//! 2. no point on either cap of `V`;
//! 3. an odd number of proper crossings with one reference segment from
//!    the top cap to the bottom cap inside `V` (the paper's "projected
//!    boundary contains the centre of the face").
//!
//! Then `K ∩ V` is a surface whose boundary lies on `V`'s sides only; by
//! (3) the caps are in different components of `V \ K` (a path between
//! them crosses `K` a number of times whose parity does not depend on the
//! path, because `K` has no boundary inside `V` and does not touch the
//! caps); so every eye ray meets `K` at some `0 < t < H`: before it reaches
//! `f`. Whatever lies behind `f` along the ray is hidden by `K`, which is
//! opaque and static. (The paper validates per seed component and falls
//! back to "invalid" where this is hard; so does this test.)
//!
//! **Why floating point cannot make an invalid face valid.** Triangle
//! corners are the scene's `f32` values, held exactly in `f64`. Conditions
//! (1) and (2) are checked against `V` grown by a margin ([`margin`], 10⁻⁹
//! of the scene's size, some 10⁷ times the rounding of the `f64` plane
//! tests): an edge or triangle is only taken to miss `V` or a cap when it
//! misses the grown one. Which triangles form `K` may be decided loosely
//! (the argument holds for any set): taking a triangle that misses `V` only
//! adds boundary edges outside `V`. Condition (3) is decided exactly, with
//! Shewchuk's adaptive predicates (the `robust` crate): a crossing through
//! an edge or a corner, or a triangle in the plane of the segment, makes
//! the test retry with other segments and, after three, give up (invalid).
//! The region's eyes are widened by [`SLOPE_MARGIN`] in slope and `H` is
//! [`CLIP_MARGIN`] under `s`, so an eye that rounding at run time puts in
//! a neighbouring bin or a hair nearer still lies in what was proved.

use glam::DVec3;
use robust::{Coord3D, orient3d};

use super::octree::{Segment, Skeleton};
use super::regions::Regions;

/// The eyes of a region are widened by this much in slope.
pub const SLOPE_MARGIN: f64 = 1e-6;

/// The paper's clipping plane: a face is an occluder only for eyes at
/// least this many node sizes from its plane. Two, not one, so that a
/// surface lying exactly on the node's front face (walls on round
/// coordinates, a box's sides on the octree's planes) is strictly inside
/// the slab it must cross, not on its top cap.
pub const CLIP: f64 = 2.0;

/// `H = CLIP · s · (1 − CLIP_MARGIN)`: the viewspace frustum stops a hair
/// short of the eyes' plane.
pub const CLIP_MARGIN: f64 = 1e-6;

/// A connected set of more triangles than this is given up on (invalid):
/// it bounds the bake's time on faces of large nodes.
pub const MAX_COMPONENT: usize = 3_000;

/// The margin by which `V` is grown for conditions (1) and (2), for a
/// scene of `extent`.
pub fn margin(extent: f64) -> f64 {
    1e-9 * extent + 1e-30
}

/// In [`Surfaces::neighbours`]: the edge is not shared by exactly two
/// triangles.
const SHARED: u32 = u32::MAX;

/// The opaque static triangles of a scene with their shared edges.
pub struct Surfaces {
    /// Triangles, scene-local, exactly the scene's `f32` corners.
    pub triangles: Vec<[DVec3; 3]>,
    /// Per triangle, its three edges (corner `i` to corner `i + 1`).
    edges: Vec<[u32; 3]>,
    /// The triangles on each edge.
    on_edges: EdgeTriangles,
    /// Per triangle and edge, the one other triangle on it, or [`SHARED`]
    /// when the edge has none or more than one (then `on_edges` says
    /// which): the walks' common case without two lookups.
    neighbours: Vec<[u32; 3]>,
    /// Per triangle, its box.
    boxes: Vec<[DVec3; 2]>,
    /// Per triangle, its connected set over the whole scene (joined as in
    /// the walks, through every shared edge).
    component: Vec<u32>,
    /// Per connected set, the box of its triangles.
    component_boxes: Vec<[DVec3; 2]>,
}

impl Surfaces {
    /// Joins `triangles` (whose corners are exact `f32` values) where two
    /// share both ends of an edge exactly.
    pub fn new(triangles: Vec<[DVec3; 3]>) -> Surfaces {
        use rustc_hash::FxHashMap;
        let key = |p: DVec3| p.to_array().map(f64::to_bits);
        let mut vertex: FxHashMap<[u64; 3], u32> = FxHashMap::default();
        let mut edge: FxHashMap<(u32, u32), u32> = FxHashMap::default();
        let mut edges = Vec::with_capacity(triangles.len());
        let mut counts: Vec<u32> = Vec::new();
        for t in &triangles {
            let ids = t.map(|p| {
                let n = vertex.len() as u32;
                *vertex.entry(key(p)).or_insert(n)
            });
            let mut es = [0u32; 3];
            for i in 0..3 {
                let (a, b) = (ids[i], ids[(i + 1) % 3]);
                let k = (a.min(b), a.max(b));
                let n = edge.len() as u32;
                let e = *edge.entry(k).or_insert_with(|| {
                    counts.push(0);
                    n
                });
                counts[e as usize] += 1;
                es[i] = e;
            }
            edges.push(es);
        }
        let mut edge_start = Vec::with_capacity(counts.len() + 1);
        let mut total = 0u32;
        for c in &counts {
            edge_start.push(total);
            total += c;
        }
        edge_start.push(total);
        let mut fill = edge_start.clone();
        let mut edge_triangles = vec![0u32; total as usize];
        for (t, es) in edges.iter().enumerate() {
            for &e in es {
                edge_triangles[fill[e as usize] as usize] = t as u32;
                fill[e as usize] += 1;
            }
        }
        let on_edges = EdgeTriangles {
            start: edge_start,
            triangles: edge_triangles,
        };
        let neighbours = edges
            .iter()
            .enumerate()
            .map(|(t, es)| {
                es.map(|e| {
                    match *on_edges.on(e) {
                        [a, b] if a as usize == t => b,
                        [a, b] if b as usize == t => a,
                        _ => SHARED,
                    }
                })
            })
            .collect();
        let boxes: Vec<[DVec3; 2]> = triangles
            .iter()
            .map(|t| [t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])])
            .collect();
        let (component, component_boxes) = components(&on_edges, &boxes);
        Surfaces {
            boxes,
            component,
            component_boxes,
            triangles,
            edges,
            on_edges,
            neighbours,
        }
    }
}

impl Surfaces {
    /// Per connected set, whether it is closed: an even number of its
    /// triangles on every edge (joined as in [`Surfaces::new`]), so that
    /// whether a point lies inside it (an odd number of crossings on a
    /// ray to far away) does not depend on the ray.
    pub fn closed_components(&self) -> Vec<bool> {
        let mut closed = vec![true; self.component_boxes.len()];
        for (t, es) in self.edges.iter().enumerate() {
            if es.iter().any(|&e| self.on_edges.on(e).len() % 2 == 1) {
                closed[self.component[t] as usize] = false;
            }
        }
        closed
    }

    /// Each triangle's connected set.
    pub fn component_of(&self) -> &[u32] {
        &self.component
    }

    /// Each connected set's box.
    pub fn component_boxes(&self) -> &[[DVec3; 2]] {
        &self.component_boxes
    }
}

/// The triangles on each edge, edge after edge in one list.
struct EdgeTriangles {
    /// Per edge, where its triangles start in `triangles`; one more entry
    /// closes the last edge's.
    start: Vec<u32>,
    triangles: Vec<u32>,
}

impl EdgeTriangles {
    /// The triangles on edge `e`.
    fn on(&self, e: u32) -> &[u32] {
        &self.triangles[self.start[e as usize] as usize..self.start[e as usize + 1] as usize]
    }

    /// How many edges.
    fn len(&self) -> usize {
        self.start.len() - 1
    }
}

/// Each triangle's connected set (triangles sharing an edge are joined) and
/// each set's box, by union–find.
fn components(on_edges: &EdgeTriangles, boxes: &[[DVec3; 2]]) -> (Vec<u32>, Vec<[DVec3; 2]>) {
    let mut parent: Vec<u32> = (0..boxes.len() as u32).collect();
    fn root(parent: &mut [u32], mut t: u32) -> u32 {
        while parent[t as usize] != t {
            let up = parent[parent[t as usize] as usize];
            parent[t as usize] = up;
            t = up;
        }
        t
    }
    for e in 0..on_edges.len() as u32 {
        for w in on_edges.on(e).windows(2) {
            let (a, b) = (root(&mut parent, w[0]), root(&mut parent, w[1]));
            parent[a.max(b) as usize] = a.min(b);
        }
    }
    let mut id = vec![u32::MAX; boxes.len()];
    let mut component = Vec::with_capacity(boxes.len());
    let mut component_boxes: Vec<[DVec3; 2]> = Vec::new();
    for (t, tbox) in boxes.iter().enumerate() {
        let r = root(&mut parent, t as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = component_boxes.len() as u32;
            component_boxes.push([DVec3::INFINITY, DVec3::NEG_INFINITY]);
        }
        let c = id[r];
        let b = &mut component_boxes[c as usize];
        *b = [b[0].min(tbox[0]), b[1].max(tbox[1])];
        component.push(c);
    }
    (component, component_boxes)
}

/// Per-thread scratch of the test, reused between faces.
pub struct Scratch {
    stamp: u32,
    visited: Vec<u32>,
    crossing: Vec<u32>,
    candidates: Vec<u32>,
    stack: Vec<u32>,
    /// The index walk's stack.
    path: Vec<u32>,
}

impl Scratch {
    /// Scratch for `surfaces`.
    pub fn new(surfaces: &Surfaces) -> Scratch {
        let n = surfaces.triangles.len();
        Scratch {
            stamp: 0,
            visited: vec![0; n],
            crossing: vec![0; n],
            candidates: Vec::new(),
            stack: Vec::new(),
            path: Vec::new(),
        }
    }

    /// A stamp no triangle carries yet; stamps only grow (they are
    /// compared), and running out clears the marks and starts again.
    fn next_stamp(&mut self) -> u32 {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.visited.fill(0);
            self.crossing.fill(0);
            self.stamp = 1;
        }
        self.stamp
    }
}

/// A face of a node and the frame it is tested in.
#[derive(Clone, Copy, Debug)]
pub struct Face {
    /// The axis it is perpendicular to.
    pub axis: usize,
    /// +1 when its node lies at larger coordinates (the face at `min`), −1 otherwise.
    pub sign: f64,
    /// Its plane's coordinate along `axis`.
    pub w: f64,
    /// Its extent along the frame's `u` and `v` axes.
    pub u: [f64; 2],
    /// See `u`.
    pub v: [f64; 2],
    /// The node's size.
    pub size: f64,
}

impl Face {
    /// Face `side` (0: at `min[axis]`) of the cube at `min` of edge `size`.
    pub fn of_cube(min: DVec3, size: f64, axis: usize, side: usize) -> Face {
        let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
        Face {
            axis,
            sign: if side == 0 { 1.0 } else { -1.0 },
            w: min[axis] + side as f64 * size,
            u: [min[ua], min[ua] + size],
            v: [min[va], min[va] + size],
            size,
        }
    }

    /// `p` in the face's frame: `(u, v, t)`, `t` growing into the node.
    pub fn local(&self, p: DVec3) -> DVec3 {
        let (ua, va) = ((self.axis + 1) % 3, (self.axis + 2) % 3);
        DVec3::new(p[ua], p[va], self.sign * (p[self.axis] - self.w))
    }

    /// The scene-local point at frame coordinates `(u, v)` on the plane
    /// `w` along the axis.
    fn point(&self, u: f64, v: f64, w: f64) -> DVec3 {
        let mut p = DVec3::ZERO;
        p[(self.axis + 1) % 3] = u;
        p[(self.axis + 2) % 3] = v;
        p[self.axis] = w;
        p
    }
}

/// The viewspace frustum of one face and region, grown by a margin.
struct Frustum {
    u: [f64; 2],
    v: [f64; 2],
    a: [f64; 2],
    b: [f64; 2],
    /// Height of the top cap.
    h: f64,
    /// The top cap's coordinate along the face's axis.
    w_top: f64,
    m: f64,
}

impl Frustum {
    /// The six signed margins of `q` (frame coordinates): all ≥ 0 inside the grown frustum.
    fn margins(&self, q: DVec3) -> [f64; 6] {
        let (u, v, t) = (q.x, q.y, q.z);
        [
            t + self.m,
            self.h + self.m - t,
            u - self.u[0] - self.a[0] * t + self.m,
            self.u[1] + self.a[1] * t + self.m - u,
            v - self.v[0] - self.b[0] * t + self.m,
            self.v[1] + self.b[1] * t + self.m - v,
        ]
    }

    /// Whether the box `[lo, hi]` (frame coordinates) lies inside the
    /// frustum without touching its caps, with the margin to spare.
    fn holds_box(&self, lo: DVec3, hi: DVec3) -> bool {
        (0..8).all(|k| {
            let q = DVec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            );
            self.margins(q).iter().all(|&g| g > 3.0 * self.m)
        })
    }

    /// Whether triangle `q` (frame coordinates) may meet the grown frustum:
    /// no plane of it has all three corners outside.
    fn may_meet_triangle(&self, q: &[DVec3; 3]) -> bool {
        let (g0, g1, g2) = (self.margins(q[0]), self.margins(q[1]), self.margins(q[2]));
        // Without a branch per plane: most triangles the walks test meet `V`.
        let mut meets = true;
        for ((a, b), c) in g0.iter().zip(&g1).zip(&g2) {
            meets &= *a >= 0.0 || *b >= 0.0 || *c >= 0.0;
        }
        meets
    }

    /// Whether segment `p q` (frame coordinates) may meet the grown frustum
    /// (Liang–Barsky clipping).
    fn may_meet_segment(&self, p: DVec3, q: DVec3) -> bool {
        let (gp, gq) = (self.margins(p), self.margins(q));
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for k in 0..6 {
            let (a, b) = (gp[k], gq[k]);
            if a < 0.0 && b < 0.0 {
                return false;
            }
            if a < 0.0 {
                lo = lo.max(a / (a - b));
            } else if b < 0.0 {
                hi = hi.min(a / (a - b));
            }
        }
        lo <= hi + 1e-9
    }

    /// Whether triangle `q` (frame coordinates) may touch a cap, grown by
    /// the margin: the triangle clipped to the cap's slab of thickness
    /// `2m` keeps a point inside the cap's rectangle.
    fn may_touch_caps(&self, q: &[DVec3; 3]) -> bool {
        let top = [
            [self.u[0] + self.h * self.a[0], self.u[1] + self.h * self.a[1]],
            [self.v[0] + self.h * self.b[0], self.v[1] + self.h * self.b[1]],
        ];
        [(0.0, [self.u, self.v]), (self.h, top)]
            .iter()
            .any(|&(t, [u, v])| {
                let lo = DVec3::new(u[0], v[0], t) - DVec3::splat(self.m);
                let hi = DVec3::new(u[1], v[1], t) + DVec3::splat(self.m);
                triangle_meets_box(q, lo, hi)
            })
    }
}

/// Whether triangle `q` has a point in the box `[lo, hi]` (clipping; a
/// triangle that only grazes the box may be reported either way, which
/// the margin already allows for).
fn triangle_meets_box(q: &[DVec3; 3], lo: DVec3, hi: DVec3) -> bool {
    let (tlo, thi) = (q[0].min(q[1]).min(q[2]), q[0].max(q[1]).max(q[2]));
    if tlo.cmpgt(hi).any() || thi.cmplt(lo).any() {
        return false;
    }
    clip_to_box(q, lo, hi).is_none_or(|(_, len)| len > 0)
}

/// Most corners a clipped triangle keeps here: six planes leave at most
/// nine.
const CLIPPED: usize = 16;

/// Triangle `q` clipped to the box `[lo, hi]` (a bound may be infinite):
/// its corners and how many; `None` when rounding would make more than
/// [`CLIPPED`], which callers take as "meets" (the answer that never
/// proves an occluder).
pub(super) fn clip_to_box(q: &[DVec3; 3], lo: DVec3, hi: DVec3) -> Option<([DVec3; CLIPPED], usize)> {
    let (mut poly, mut len) = ([DVec3::ZERO; CLIPPED], 3);
    poly[..3].copy_from_slice(q);
    for axis in 0..3 {
        for (bound, keep_above) in [(lo[axis], true), (hi[axis], false)] {
            let inside = |p: &DVec3| {
                if keep_above {
                    p[axis] >= bound
                } else {
                    p[axis] <= bound
                }
            };
            let (mut next, mut kept) = ([DVec3::ZERO; CLIPPED], 0);
            for i in 0..len {
                if kept + 2 > CLIPPED {
                    return None;
                }
                let (a, b) = (poly[i], poly[(i + 1) % len]);
                if inside(&a) {
                    next[kept] = a;
                    kept += 1;
                }
                if inside(&a) != inside(&b) {
                    let s = (bound - a[axis]) / (b[axis] - a[axis]);
                    let mut x = a + (b - a) * s;
                    x[axis] = bound;
                    next[kept] = x;
                    kept += 1;
                }
            }
            (poly, len) = (next, kept);
            if len == 0 {
                return Some((poly, 0));
            }
        }
    }
    Some((poly, len))
}

/// How a segment meets a triangle, decided exactly.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Crossing {
    /// Through the triangle's interior.
    Through,
    /// Not at all.
    Misses,
    /// Through an edge or corner, an end on its plane, or in its plane.
    Degenerate,
}

fn coord(p: DVec3) -> Coord3D<f64> {
    Coord3D {
        x: p.x,
        y: p.y,
        z: p.z,
    }
}

/// How segment `p q` meets triangle `t`, with exact predicates.
pub fn crossing(p: DVec3, q: DVec3, t: &[DVec3; 3]) -> Crossing {
    let [a, b, c] = t.map(coord);
    let (p, q) = (coord(p), coord(q));
    let collinear = [(0, 1), (1, 2), (0, 2)].iter().all(|&(i, j)| {
        let pick = |x: Coord3D<f64>| {
            let v = [x.x, x.y, x.z];
            robust::Coord { x: v[i], y: v[j] }
        };
        robust::orient2d(pick(a), pick(b), pick(c)) == 0.0
    });
    if collinear {
        // A segment of zero area is met only by a segment in its line's
        // plane, which the caller takes as degenerate.
        let coplanar = orient3d(p, q, a, b) == 0.0 && orient3d(p, q, a, c) == 0.0;
        return if coplanar {
            Crossing::Degenerate
        } else {
            Crossing::Misses
        };
    }
    let (sp, sq) = (orient3d(a, b, c, p), orient3d(a, b, c, q));
    if sp == 0.0 || sq == 0.0 {
        return Crossing::Degenerate;
    }
    if (sp > 0.0) == (sq > 0.0) {
        return Crossing::Misses;
    }
    let o = [orient3d(p, q, a, b), orient3d(p, q, b, c), orient3d(p, q, c, a)];
    if o.contains(&0.0) {
        return Crossing::Degenerate;
    }
    if o.iter().all(|&x| x > 0.0) || o.iter().all(|&x| x < 0.0) {
        Crossing::Through
    } else {
        Crossing::Misses
    }
}

/// What the test searches: the opaque surfaces and an octree over them.
pub struct Validator<'a> {
    /// The opaque static triangles.
    pub surfaces: &'a Surfaces,
    /// An octree whose leaves list `surfaces`' triangles (and, numbered
    /// after them, see-through ones).
    pub index: &'a Skeleton,
    /// The scene's size, for [`margin`].
    pub extent: f64,
}

impl Validator<'_> {
    /// Whether `face` is a valid occluder for every eye of `region` of
    /// `regions` (see the module doc).
    pub fn is_valid(&self, face: &Face, regions: Regions, region: usize, s: &mut Scratch) -> bool {
        let ([a0, a1], [b0, b1]) = regions.slopes(region);
        let grow = 0.5 / CLIP + SLOPE_MARGIN;
        let h = CLIP * face.size * (1.0 - CLIP_MARGIN);
        let w_top = face.w + face.sign * h;
        let v = Frustum {
            u: face.u,
            v: face.v,
            a: [a0 - grow, a1 + grow],
            b: [b0 - grow, b1 + grow],
            // The top cap where it really is, after the rounding of `w_top`.
            h: face.sign * (w_top - face.w),
            w_top,
            m: margin(self.extent),
        };
        // Reference segments: from the top cap above the face's centre
        // along the region's middle slope, to the face's centre; then two
        // others off-centre, for when a crossing is degenerate.
        let (uc, vc) = (
            0.5 * (face.u[0] + face.u[1]),
            0.5 * (face.v[0] + face.v[1]),
        );
        let (am, bm) = (0.5 * (a0 + a1), 0.5 * (b0 + b1));
        for (du, dv) in [(0.0, 0.0), (0.137, -0.211), (-0.193, 0.157)] {
            let (bu, bv) = (uc + du * face.size, vc + dv * face.size);
            let bottom = face.point(bu, bv, face.w);
            let top = face.point(bu + v.h * am, bv + v.h * bm, v.w_top);
            match self.separates(face, &v, top, bottom, s) {
                Some(valid) => return valid,
                None => continue,
            }
        }
        false
    }

    /// Whether some component of triangles meeting `v` that crosses the
    /// segment `top bottom` separates the caps; `None` when a crossing is
    /// degenerate (try another segment).
    fn separates(
        &self,
        face: &Face,
        v: &Frustum,
        top: DVec3,
        bottom: DVec3,
        s: &mut Scratch,
    ) -> Option<bool> {
        let surfaces = self.surfaces;
        // Every walk below takes a stamp: keep them from wrapping mid-way.
        if s.stamp > u32::MAX - surfaces.triangles.len() as u32 - 4 {
            s.stamp = u32::MAX;
        }
        let stamp = s.next_stamp();
        // Every triangle that can cross the segment is in a leaf it meets.
        let grow = DVec3::splat(v.m);
        s.candidates.clear();
        let candidates = &mut s.candidates;
        let crossing_marks = &mut s.crossing;
        let visited = &mut s.visited;
        let mut degenerate = false;
        let segment = Segment::new(top, bottom);
        self.index.leaves_along(&segment, v.m, &mut s.path, |leaf| {
            for &t in self.index.leaf_triangles(leaf) {
                // See-through triangles (numbered after the opaque ones)
                // hide nothing; `visited` doubles as "already tested".
                if degenerate || t as usize >= surfaces.triangles.len() || visited[t as usize] == stamp {
                    continue;
                }
                visited[t as usize] = stamp;
                // Most triangles near the segment miss even its box: no
                // need for the exact test.
                let [blo, bhi] = surfaces.boxes[t as usize];
                if !segment.meets_box(blo - grow, bhi + grow) {
                    continue;
                }
                match crossing(top, bottom, &surfaces.triangles[t as usize]) {
                    Crossing::Through => {
                        crossing_marks[t as usize] = stamp;
                        candidates.push(t);
                    }
                    Crossing::Misses => {}
                    Crossing::Degenerate => degenerate = true,
                }
            }
        });
        if degenerate {
            return None;
        }
        if s.candidates.is_empty() {
            return Some(false);
        }
        // Each walk a fresh stamp, above the candidates'; crossings keep
        // theirs. A triangle stamped by an earlier walk belongs to a
        // component already judged not to separate.
        let crossing_stamp = stamp;
        let local = |t: u32| {
            let [a, b, c] = &surfaces.triangles[t as usize];
            [face.local(*a), face.local(*b), face.local(*c)]
        };
        let seeds = std::mem::take(&mut s.candidates);
        let mut found = false;
        for &seed in &seeds {
            if s.visited[seed as usize] > crossing_stamp {
                continue;
            }
            // A connected set that lies wholly inside `V`, clear of the
            // caps, is never a separator: it has a boundary edge inside `V`
            // (condition 1 fails) or is closed, and a closed surface crosses
            // a segment whose ends lie outside its box an even number of
            // times (condition 3 fails). The dense parts inside a body are
            // such sets; walking them all to find that out was most of
            // the bake.
            let [lo, hi] = surfaces.component_boxes[surfaces.component[seed as usize] as usize];
            let (a, b) = (face.local(lo), face.local(hi));
            if v.holds_box(a.min(b), a.max(b)) {
                continue;
            }
            let walk = s.next_stamp();
            s.visited[seed as usize] = walk;
            s.stack.clear();
            s.stack.push(seed);
            let (mut parity, mut size, mut ok) = (0u32, 0usize, true);
            while let Some(t) = s.stack.pop() {
                size += 1;
                let corners = local(t);
                if size > MAX_COMPONENT || v.may_touch_caps(&corners) {
                    ok = false;
                    break;
                }
                if s.crossing[t as usize] == crossing_stamp {
                    parity ^= 1;
                }
                for (i, &e) in surfaces.edges[t as usize].iter().enumerate() {
                    // Most edges have one other triangle: `t` itself is
                    // counted without looking the edge up.
                    let other = surfaces.neighbours[t as usize][i];
                    let (on, mut inside) = if other == SHARED {
                        (surfaces.on_edges.on(e), 0)
                    } else {
                        (std::slice::from_ref(&other), 1)
                    };
                    for &n in on {
                        // A neighbour this walk already took meets `V`: no
                        // need to test it again from its other edges.
                        let mark = s.visited[n as usize];
                        if n == t || mark == walk || v.may_meet_triangle(&local(n)) {
                            inside += 1;
                            if mark > crossing_stamp && mark < walk {
                                // Joined to a component judged before:
                                // this walk only sees part of it.
                                ok = false;
                            } else if mark != walk {
                                s.visited[n as usize] = walk;
                                s.stack.push(n);
                            }
                        }
                    }
                    if inside % 2 == 1 && v.may_meet_segment(corners[i], corners[(i + 1) % 3]) {
                        ok = false;
                        break;
                    }
                }
                if !ok {
                    break;
                }
            }
            if ok && parity == 1 {
                found = true;
                break;
            }
        }
        s.candidates = seeds;
        Some(found)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_segment_through_a_triangle_crosses_and_one_through_its_corner_is_degenerate() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let (p, q) = (DVec3::new(0.2, 0.2, 1.0), DVec3::new(0.2, 0.2, -1.0));
        assert_eq!(crossing(p, q, &t), Crossing::Through);
        assert_eq!(crossing(p + DVec3::X, q + DVec3::X, &t), Crossing::Misses);
        assert_eq!(
            crossing(DVec3::new(0.0, 0.0, 1.0), DVec3::new(0.0, 0.0, -1.0), &t),
            Crossing::Degenerate
        );
        assert_eq!(crossing(p, DVec3::new(0.2, 0.2, 0.0), &t), Crossing::Degenerate);
        let sliver = [DVec3::ZERO, DVec3::X, DVec3::X * 2.0];
        assert_eq!(crossing(p, q, &sliver), Crossing::Misses);
    }

    /// A wall in the plane `z = z` over `[-3, 3]²`, an `n × n` grid, less
    /// the cells in `holes`.
    fn wall(z: f64, n: usize, holes: &[(usize, usize)]) -> Vec<[DVec3; 3]> {
        let at = |i: usize| -3.0 + 6.0 * i as f64 / n as f64;
        let mut tris = Vec::new();
        for i in 0..n {
            for j in 0..n {
                if holes.contains(&(i, j)) {
                    continue;
                }
                let p = |di: usize, dj: usize| DVec3::new(at(i + di), at(j + dj), z);
                tris.push([p(0, 0), p(1, 0), p(1, 1)]);
                tris.push([p(0, 0), p(1, 1), p(0, 1)]);
            }
        }
        tris
    }

    /// A wall in the plane `z = z` over `[-half, half]²`, two triangles.
    fn wide_wall(z: f64, half: f64) -> Vec<[DVec3; 3]> {
        let p = |x: f64, y: f64| DVec3::new(x, y, z);
        vec![
            [p(-half, -half), p(half, -half), p(half, half)],
            [p(-half, -half), p(half, half), p(-half, half)],
        ]
    }

    /// Whether the `-z` face of the unit cube around the origin (its node
    /// above it, eyes at `z ≥ 1.5`) is valid for the region of slopes
    /// `(a, b)`, with `triangles` as the scene.
    fn face_valid(triangles: Vec<[DVec3; 3]>, regions: Regions, a: f64, b: f64) -> bool {
        let boxes: Vec<(DVec3, DVec3)> = triangles
            .iter()
            .map(|t| (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])))
            .collect();
        let owner = vec![0; triangles.len()];
        let index = Skeleton::build(&boxes, &owner, super::super::OctreeParams::default()).unwrap();
        let surfaces = Surfaces::new(triangles);
        let validator = Validator {
            surfaces: &surfaces,
            index: &index,
            extent: 6.0,
        };
        let face = Face::of_cube(DVec3::splat(-0.5), 1.0, 2, 0);
        let Some(region) = regions.region_of(a, b) else {
            return false;
        };
        validator.is_valid(&face, regions, region, &mut Scratch::new(&surfaces))
    }

    #[test]
    fn a_whole_wall_between_the_eyes_and_a_face_makes_it_valid() {
        for regions in Regions::ALL {
            assert!(face_valid(wall(0.25, 24, &[]), regions, 0.1, 0.1), "{regions:?}");
            assert!(face_valid(wall(0.25, 24, &[]), regions, -0.7, 0.3), "{regions:?}");
            // The wall on the node's front face: still inside the slab.
            assert!(face_valid(wall(0.5, 24, &[]), regions, 0.1, 0.1), "{regions:?}");
        }
    }

    #[test]
    fn a_wall_with_a_hole_or_touching_the_face_does_not() {
        for regions in Regions::ALL {
            // One cell (0.25 wide) missing where the face's rays cross.
            assert!(!face_valid(wall(0.25, 24, &[(12, 12)]), regions, 0.1, 0.1), "{regions:?}");
            // A cell missing far to the side, outside every ray: still valid.
            assert!(face_valid(wall(0.25, 24, &[(0, 23)]), regions, 0.1, 0.1), "{regions:?}");
            // In the face's own plane: it hides nothing behind the face.
            assert!(!face_valid(wall(-0.5, 24, &[]), regions, 0.1, 0.1), "{regions:?}");
            // Behind the face.
            assert!(!face_valid(wall(-0.75, 24, &[]), regions, 0.1, 0.1), "{regions:?}");
        }
    }

    #[test]
    fn a_triangle_meets_a_box_only_where_it_reaches_inside() {
        let (lo, hi) = (DVec3::ZERO, DVec3::ONE);
        // Through the box, a corner inside, and one wholly inside.
        let through = [DVec3::new(-1.0, 0.5, 0.5), DVec3::new(2.0, 0.4, 0.5), DVec3::new(0.5, 0.5, 3.0)];
        assert!(triangle_meets_box(&through, lo, hi));
        let corner = [DVec3::splat(0.9), DVec3::new(3.0, 0.9, 0.9), DVec3::new(0.9, 3.0, 0.9)];
        assert!(triangle_meets_box(&corner, lo, hi));
        let inside = [DVec3::splat(0.1), DVec3::splat(0.2), DVec3::new(0.1, 0.2, 0.3)];
        assert!(triangle_meets_box(&inside, lo, hi));
        // Its box overlaps the box's, but the triangle passes by a corner.
        let past = [DVec3::new(2.7, -0.5, 0.5), DVec3::new(-0.5, 2.7, 0.5), DVec3::new(2.7, 2.7, 0.5)];
        assert!(!triangle_meets_box(&past, lo, hi));
        // Cut by all six planes: a large triangle across the box's middle.
        let big = [DVec3::new(-5.0, -5.0, 0.5), DVec3::new(9.0, 0.5, -4.0), DVec3::new(0.5, 9.0, 6.0)];
        assert!(triangle_meets_box(&big, lo, hi));
    }

    #[test]
    fn an_edge_of_three_triangles_is_a_boundary_and_a_shared_one_is_not() {
        // A fin on the grid edge from (0, 0) to (¼, 0) of a whole wall:
        // three triangles meet there, an odd number, so inside `V` it is
        // a boundary edge (the walk looks it up in full); the wall's
        // other edges each have one other triangle.
        let fin = |x: f64, y: f64| {
            [
                DVec3::new(x, y, 0.25),
                DVec3::new(x + 0.25, y, 0.25),
                DVec3::new(x + 0.125, y, 0.5),
            ]
        };
        let mut finned = wall(0.25, 24, &[]);
        finned.push(fin(0.0, 0.0));
        let surfaces = Surfaces::new(finned.clone());
        let shared = |t: usize| surfaces.neighbours[t].iter().filter(|&&n| n == SHARED).count();
        let fin_index = finned.len() - 1;
        assert_eq!(shared(fin_index), 3, "the fin's own edges: one of three, two of one");
        let on_fin_edge = (0..fin_index).filter(|&t| shared(t) > 0 && finned[t].iter().all(|p| p.z == 0.25));
        // The wall's border triangles have edges of one too; the two by
        // the fin are the ones inside.
        assert_eq!(on_fin_edge.filter(|&t| finned[t].iter().any(|p| p.x.abs() < 0.3 && p.y.abs() < 0.3)).count(), 2);
        for t in 0..fin_index {
            for (i, &n) in surfaces.neighbours[t].iter().enumerate() {
                if n != SHARED {
                    assert!(surfaces.neighbours[n as usize].contains(&(t as u32)), "{t} edge {i}");
                }
            }
        }
        for regions in Regions::ALL {
            assert!(!face_valid(finned.clone(), regions, 0.1, 0.1), "{regions:?}");
            // The same fin far to the side, outside every ray.
            let mut far = wall(0.25, 24, &[]);
            far.push(fin(-3.0, 2.75));
            assert!(face_valid(far, regions, 0.1, 0.1), "{regions:?}");
        }
    }

    /// The 12 triangles of the closed cube `[lo, hi]`.
    fn cube(lo: DVec3, hi: DVec3) -> Vec<[DVec3; 3]> {
        let c = |k: usize| {
            DVec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            )
        };
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        quads
            .iter()
            .flat_map(|q| [[c(q[0]), c(q[1]), c(q[2])], [c(q[0]), c(q[2]), c(q[3])]])
            .collect()
    }

    #[test]
    fn a_closed_part_inside_the_frustum_is_skipped_and_a_wall_beyond_it_still_counts() {
        // A small closed cube on the reference segment, inside `V` and
        // clear of its caps: two crossings, never a separator.
        let part = cube(DVec3::new(-0.1, -0.1, 0.0), DVec3::new(0.3, 0.3, 0.2));
        let surfaces = Surfaces::new(part.clone());
        assert_eq!(surfaces.component_boxes.len(), 1);
        for regions in Regions::ALL {
            assert!(!face_valid(part.clone(), regions, 0.1, 0.1), "{regions:?}");
            let mut both = part.clone();
            both.extend(wall(0.6, 24, &[]));
            assert!(face_valid(both, regions, 0.1, 0.1), "{regions:?}");
        }
        // Two walls are two sets, each with its own box.
        let mut two = wall(0.25, 4, &[]);
        two.extend(wall(0.75, 4, &[]));
        let surfaces = Surfaces::new(two);
        assert_eq!(surfaces.component_boxes.len(), 2);
        assert_eq!(surfaces.component_boxes[1][0].z, 0.75);
    }

    #[test]
    fn a_face_seen_edge_on_is_never_valid() {
        for regions in Regions::ALL {
            // Past 80° from the normal an eye is in no region: no wall is
            // wide enough for every ray towards grazing.
            assert!(!face_valid(wall(0.25, 24, &[]), regions, 50.0, 0.0), "{regions:?}");
            assert!(!face_valid(wall(0.25, 24, &[]), regions, 0.1, -80.0), "{regions:?}");
            // 70° off (slope 2.75): the rays travel up to `H · (5.67 + ¼)`
            // sideways below the clipping plane, beyond this 6-wide wall...
            assert!(!face_valid(wall(0.25, 24, &[]), regions, 2.75, 0.0), "{regions:?}");
            // ...and within one 40 wide.
            assert!(face_valid(wide_wall(0.25, 20.0), regions, 2.75, 0.0), "{regions:?}");
        }
    }
}
