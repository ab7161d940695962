//! Solid occluders: rectangles that lie inside a closed opaque surface,
//! found at bake time beside the DDO masks. They are not in Bernardini et
//! al.; they answer what §3's faces cannot on a thin curved skin, where a
//! face is valid only when a node is a few centimetres across: inside a
//! closed skin a rectangle metres long hides from every eye outside it,
//! with no viewspace regions at all, so a frame draws tens of polygons
//! where it drew thousands of faces (docs/ddo.md measures both).
//!
//! **What is proved.** Let `S` be a connected set of the scene's opaque
//! static triangles with an even number of its triangles on every edge
//! (edges joined where two corners are exactly equal:
//! [`Surfaces::closed_components`]). Then the parity of a point (how many
//! of `S`'s triangles a ray from it to far away crosses) does not depend
//! on the ray, and it can change along a path only where the path meets a
//! triangle of `S`. A rectangle `R` is kept when (1) no triangle of `S`
//! has a point in any of `R`'s closed cells (each triangle's part within
//! a margin of the plane is bounded by a box grown by the margin, and every
//! cell that box touches is struck off), (2) `R`'s cells are joined by
//! shared sides to a cell whose centre has odd parity, counted exactly
//! ([`crossing`], Shewchuk's predicates; a degenerate crossing makes the
//! count move to another cell, and after a few, give up). So every point of
//! `R` has odd parity. An eye outside `S`'s box has even parity, so the
//! segment from it to any point of `R` meets a triangle of `S` before `R`:
//! whatever lies behind `R` from that eye is hidden by `S`, which is
//! opaque and static. The run time uses `R` only when the whole box of
//! `S` lies beyond the view's near plane, so that the hiding triangle is
//! one the near plane does not clip away; that also puts the eye outside
//! the box.
//!
//! **Why rounding cannot break it.** Corners are the scene's `f32` values,
//! held exactly in `f64`. A triangle's corners in a plane's frame (exact
//! for the three axes, which only permute coordinates), its part near the
//! plane and that part's box are computed to ~10⁻¹⁶ of the scene's size,
//! and the box is grown by [`margin`] (10⁻⁹ of it), so a cell whose
//! computed bounds the grown box misses is clear of the triangle by far
//! more than any rounding. The same holds for the segment whose crossings
//! give a cell's parity: its ends, turned back into scene coordinates,
//! move by ~10⁻¹⁶, and no triangle lies that near a clear cell. A
//! rectangle's corners move as much, so every point drawn is still
//! inside; the draw also takes it the margin farther from the eye than its
//! plane.

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::validity::{Crossing, Surfaces, clip_to_box, crossing, margin};
use crate::geom::{Aabb, Plane};

/// Cells along the longest side of a large closed set's box when it
/// fills its box ([`large_grid`]).
const GRID: usize = 256;

/// Cells along the longest side of a large closed set's box at most: a
/// thin shell gets them. On the CAD body (a skin 30–88 mm thick) 8.6 mm
/// cells fit rectangles further into its rounded edges than 17 mm did,
/// and hid 13 more objects of the orbit's 240 at the same cull time;
/// 1,024 cells hid no more and took four times as long to search
/// (docs/ddo.md).
const GRID_THIN: usize = 512;

/// Cells along the longest side of a small closed set's box.
const SMALL_GRID: usize = 32;

/// Rectangles kept of a large closed set, those that cover most of it
/// ([`covering`]): on the CAD body the 150 so chosen hide 7 more objects
/// of the orbit's 240 than the 150 largest did, at the same cull time
/// (docs/ddo.md).
const LARGE_KEEP: usize = 150;

/// How near a large set's surface must lie over a rectangle to count as
/// covered by it ([`covering`]), as a share of the set's box's longest
/// side: on the CAD body 13 cm, a few skin thicknesses. Twice that
/// counted the far wall of narrow places and covered less.
const COVER_REACH: f64 = 0.03;

/// Rectangles on near parallel planes of one frame within this many
/// cells of each other, of which the smaller lies over the larger by at
/// least [`OVERLAP`] of its area, are one: the smaller is dropped.
const REACH: f64 = 3.0;

/// See [`REACH`].
const OVERLAP: f64 = 0.5;

/// A rectangle of fewer cells than this is not kept: it hides less than
/// drawing it costs.
const MIN_CELLS: usize = 16;

/// Rectangles taken from one plane's cells at most.
const PER_PLANE: usize = 8;

/// Closed sets whose box's longest side is at least this share of the
/// scene's are large: bodies and shells, searched in finer cells, whose
/// rectangles are drawn before anything is tested. The others (parts)
/// are drawn when their object is found visible.
const LARGE_SHARE: f64 = 0.25;

/// Cells whose centre is tried for a region's parity before it is given
/// up on (a crossing through an edge or corner of a triangle is retried
/// from another cell).
const PARITY_TRIES: usize = 4;

/// Buckets along each side of the grid that finds the triangles above a
/// point.
const BUCKETS: usize = 64;

/// A rectangle inside a closed set, as drawn: its corners in order
/// around it and its plane (`normal · p + d = 0`, to within rounding).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolidRect {
    pub corners: [DVec3; 4],
    pub normal: DVec3,
    pub d: f64,
}

impl SolidRect {
    /// Its area.
    pub fn area(&self) -> f64 {
        (self.corners[1] - self.corners[0]).length() * (self.corners[3] - self.corners[0]).length()
    }

    /// Its centre.
    pub fn centre(&self) -> DVec3 {
        (self.corners[0] + self.corners[2]) * 0.5
    }
}

/// Which sides of a rectangle's plane some object's box reaches into,
/// strictly: `positive` where `normal · p + d > 0`, `negative` where it is
/// below. Boxes that hold the whole rectangle are left out: a box's
/// nearest point is never farther than a rectangle inside it, so the
/// rectangle cannot hide it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Beyond {
    pub positive: bool,
    pub negative: bool,
}

impl Beyond {
    /// Whether a box reaches past the plane on the side away from `eye`:
    /// only there can the rectangle hide anything tested.
    pub fn from(self, r: &SolidRect, eye: DVec3) -> bool {
        self.past(r.normal.dot(eye) + r.d > 0.0)
    }

    /// [`Beyond::from`] an eye on the normal's side of the plane
    /// (`eye_above`) or not.
    pub fn past(self, eye_above: bool) -> bool {
        if eye_above { self.negative } else { self.positive }
    }
}

/// [`Beyond`] of every rectangle of `solids` against `boxes`, per solid
/// and rectangle. Rectangles share a few normals (one per searched
/// frame), so per normal the boxes are sorted once by how far they
/// reach along it, and a rectangle looks at the farthest-reaching few
/// until one does not hold it.
pub fn beyond(solids: &[Solid], boxes: &[Aabb]) -> Vec<Vec<Beyond>> {
    let mut out: Vec<Vec<Beyond>> = solids.iter().map(|s| vec![Beyond::default(); s.rects.len()]).collect();
    let mut normals: Vec<DVec3> = Vec::new();
    for s in solids {
        for r in &s.rects {
            if !normals.contains(&r.normal) {
                normals.push(r.normal);
            }
        }
    }
    let boxes: Vec<&Aabb> = boxes.iter().filter(|b| !b.is_empty()).collect();
    let holds = |b: &Aabb, r: &SolidRect| {
        let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
        r.corners.iter().all(|c| c.cmpge(lo).all() && c.cmple(hi).all())
    };
    for normal in normals {
        // Each box's reach along the normal: its least and greatest n · p.
        let along = Plane { normal, d: 0.0 };
        let reach: Vec<(f64, f64)> = boxes.iter().map(|b| along.box_range(b)).collect();
        let mut by_max: Vec<(f64, usize)> = reach.iter().enumerate().map(|(k, r)| (r.1, k)).collect();
        let mut by_min: Vec<(f64, usize)> = reach.iter().enumerate().map(|(k, r)| (r.0, k)).collect();
        by_max.sort_by(|a, b| b.0.total_cmp(&a.0));
        by_min.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (s, solid) in solids.iter().enumerate() {
            for (i, r) in solid.rects.iter().enumerate().filter(|(_, r)| r.normal == normal) {
                // The plane is n · p = −d.
                let first = |sorted: &[(f64, usize)]| {
                    sorted.iter().find(|&&(_, k)| !holds(boxes[k], r)).map(|&(v, _)| v)
                };
                out[s][i] = Beyond {
                    positive: first(&by_max).is_some_and(|v| v > -r.d),
                    negative: first(&by_min).is_some_and(|v| v < -r.d),
                };
            }
        }
    }
    out
}

/// An orthonormal frame: `n` across the planes searched, `u` and `v` along
/// them.
#[derive(Clone, Copy, Debug)]
struct Frame {
    u: DVec3,
    v: DVec3,
    n: DVec3,
}

impl Frame {
    /// The frames searched: the three axes (exact: coordinates are only
    /// permuted), the six diagonals of the axis planes and the four of the
    /// cube, so that a rounded edge or corner has a plane within ~30° of
    /// its surface.
    fn all() -> Vec<Frame> {
        let axis = |i: usize| {
            let mut e = DVec3::ZERO;
            e[i] = 1.0;
            e
        };
        let mut frames: Vec<Frame> = (0..3)
            .map(|i| Frame {
                u: axis((i + 1) % 3),
                v: axis((i + 2) % 3),
                n: axis(i),
            })
            .collect();
        let diagonals = [
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(0.0, 1.0, 1.0),
            DVec3::new(0.0, 1.0, -1.0),
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(1.0, 0.0, -1.0),
            DVec3::new(1.0, 1.0, 1.0),
            DVec3::new(1.0, 1.0, -1.0),
            DVec3::new(1.0, -1.0, 1.0),
            DVec3::new(-1.0, 1.0, 1.0),
        ];
        for d in diagonals {
            let n = d.normalize();
            let other = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
            let u = n.cross(other).normalize();
            frames.push(Frame { u, v: n.cross(u), n });
        }
        frames
    }

    /// `p` in the frame: `(u, v, n)`.
    fn local(&self, p: DVec3) -> DVec3 {
        DVec3::new(p.dot(self.u), p.dot(self.v), p.dot(self.n))
    }

    /// The scene-local point of frame coordinates `l`.
    fn world(&self, l: DVec3) -> DVec3 {
        self.u * l.x + self.v * l.y + self.n * l.z
    }
}

/// One closed set's box and the rectangles inside it.
#[derive(Clone, Debug, PartialEq)]
pub struct Solid {
    pub lo: DVec3,
    pub hi: DVec3,
    /// The object all its triangles belong to, if one does.
    pub object: Option<u32>,
    /// Searched as a large set (finer cells, more rectangles kept).
    pub large: bool,
    /// A part's largest first; a large set's in the order [`covering`]
    /// chose them, most new cover first.
    pub rects: Vec<SolidRect>,
}

/// The solid occluders of `surfaces` (a scene of `extent`, triangle `t`
/// of object `owner[t]`): one [`Solid`] per closed set that holds any
/// rectangle.
pub fn find(surfaces: &Surfaces, owner: &[u32], extent: f64) -> Vec<Solid> {
    let closed = surfaces.closed_components();
    let boxes = surfaces.component_boxes();
    let m = margin(extent);
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); boxes.len()];
    for (t, &c) in surfaces.component_of().iter().enumerate() {
        if closed[c as usize] {
            members[c as usize].push(t as u32);
        }
    }
    (0..boxes.len())
        .filter(|&c| closed[c])
        .filter_map(|c| {
            let [lo, hi] = boxes[c];
            let large = (hi - lo).max_element() >= LARGE_SHARE * extent;
            let cells = if large {
                large_grid(&surfaces.triangles, &members[c], lo, hi)
            } else {
                SMALL_GRID
            };
            let cell = (hi - lo).max_element() / cells as f64;
            let mut rects: Vec<SolidRect> = Frame::all()
                .into_iter()
                .flat_map(|frame| rects_across(surfaces, &members[c], frame, cell, m))
                .collect();
            rects.sort_by(|a, b| b.area().total_cmp(&a.area()));
            if large {
                let reach = COVER_REACH * (hi - lo).max_element();
                rects = covering(rects, &surfaces.triangles, &members[c], reach, LARGE_KEEP);
            } else {
                rects = largest_per_direction(rects);
            }
            let first = owner[members[c][0] as usize];
            let object = members[c].iter().all(|&t| owner[t as usize] == first).then_some(first);
            (!rects.is_empty()).then_some(Solid {
                lo,
                hi,
                object,
                large,
                rects,
            })
        })
        .collect()
}

/// A small closed set's (a part's) rectangles: the largest of each plane
/// direction searched, largest first, from `rects` sorted so. The run
/// time draws only the one a view shows largest (its area times the
/// cosine between its normal and the direction to the eye): a part's
/// largest section shows thin when seen edge-on, where a section of
/// another direction shows broad, and drawing a second costs a draw for
/// little.
/// On the CAD orbit the one seen largest of 13 hid 15 more objects of 234
/// than the largest two, with a third fewer draws (docs/ddo.md).
fn largest_per_direction(rects: Vec<SolidRect>) -> Vec<SolidRect> {
    let mut kept: Vec<SolidRect> = Vec::new();
    for r in rects {
        if kept.iter().all(|k| k.normal != r.normal) {
            kept.push(r);
        }
    }
    kept
}

/// Up to `keep` of `rects` (inside the closed set `tris`, indices into
/// `triangles`), chosen one at a time by how much of the set's surface
/// each newly covers: a surface point is covered by a rectangle it lies
/// over, within `reach` of its plane. The largest rectangles overlap
/// each other on the broad faces of a shell (one per plane that fits
/// between its layers) while its rounded edges, where only narrow ones
/// fit, stay open; choosing by new cover closes them first (docs/ddo.md).
/// The surface is sampled at its triangles' centroids, weighted by area.
/// Greedy with lazy gains: a rectangle's gain only falls as others are
/// taken, so one whose recomputed gain still heads the queue is taken.
fn covering(rects: Vec<SolidRect>, triangles: &[[DVec3; 3]], tris: &[u32], reach: f64, keep: usize) -> Vec<SolidRect> {
    let samples: Vec<(DVec3, f64)> = tris
        .iter()
        .map(|&t| {
            let [a, b, c] = triangles[t as usize];
            ((a + b + c) / 3.0, 0.5 * (b - a).cross(c - a).length())
        })
        .collect();
    // Per rectangle, the samples it covers, as indices.
    let covers: Vec<Vec<u32>> = rects
        .par_iter()
        .map(|r| {
            let (o, u, v) = (r.corners[0], r.corners[1] - r.corners[0], r.corners[3] - r.corners[0]);
            let (uu, vv) = (u.length_squared(), v.length_squared());
            (0..samples.len() as u32)
                .filter(|&k| {
                    let d = samples[k as usize].0 - o;
                    let (s, t) = (d.dot(u) / uu, d.dot(v) / vv);
                    (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&t) && d.dot(r.normal).abs() <= reach
                })
                .collect()
        })
        .collect();
    let mut covered = vec![false; samples.len()];
    let gain = |i: usize, covered: &[bool]| -> f64 {
        covers[i].iter().filter(|&&k| !covered[k as usize]).map(|&k| samples[k as usize].1).sum()
    };
    // Largest gain first; on a tie, the earlier (larger) rectangle.
    let mut queue: Vec<(f64, usize)> = (0..rects.len()).map(|i| (gain(i, &covered), i)).collect();
    let mut out = Vec::new();
    while out.len() < keep {
        let Some(top) = (0..queue.len()).max_by(|&a, &b| {
            queue[a].0.total_cmp(&queue[b].0).then(queue[b].1.cmp(&queue[a].1))
        }) else {
            break;
        };
        let (stale, i) = queue[top];
        if stale <= 0.0 {
            break; // nothing left adds cover
        }
        let fresh = gain(i, &covered);
        if fresh < stale {
            queue[top].0 = fresh;
            continue;
        }
        queue.swap_remove(top);
        for &k in &covers[i] {
            covered[k as usize] = true;
        }
        out.push(rects[i]);
    }
    out
}

/// Cells along the longest side of the box `[lo, hi]` of the large
/// closed set `tris` (indices into `triangles`): [`GRID`] for a set that
/// fills its box, up to [`GRID_THIN`] as the share of the box inside it
/// falls to an eighth, so that about as many cells lie inside it. The
/// search's cost follows those cells, and a thin shell needs fine ones:
/// a plane must fit between its layers. The share is a guess (whatever
/// it is changes how fine the search is, never what it proves).
fn large_grid(triangles: &[[DVec3; 3]], tris: &[u32], lo: DVec3, hi: DVec3) -> usize {
    let cells = GRID as f64 / inside_share(triangles, tris, lo, hi).cbrt();
    if cells.is_finite() {
        cells.clamp(GRID as f64, GRID_THIN as f64) as usize
    } else {
        GRID
    }
}

/// Columns along each side of a box, for [`inside_share`].
const COLUMNS: usize = 16;

/// About what share of the box `[lo, hi]` lies inside the closed set
/// `tris`: along vertical lines through [`COLUMNS`]² points of the box,
/// the lengths between the 1st and 2nd crossing, 3rd and 4th..., over
/// the box's height. Parity needs no winding, so a set wound either way
/// gets the same share; a line with an odd count (through an edge) is
/// left out, and with none left the share is 1 (the coarse cells).
fn inside_share(triangles: &[[DVec3; 3]], tris: &[u32], lo: DVec3, hi: DVec3) -> f64 {
    let size = hi - lo;
    // Off the middle of the columns by odd shares, different across and
    // down, so that lines miss the edges and diagonals of triangles laid
    // out on a regular grid.
    const OFF: [f64; 2] = [0.5137, 0.4289];
    let at = |i: usize, axis: usize| lo[axis] + size[axis] * (i as f64 + OFF[axis]) / COLUMNS as f64;
    let mut hits: Vec<Vec<f64>> = vec![Vec::new(); COLUMNS * COLUMNS];
    for &t in tris {
        let [a, b, c] = triangles[t as usize];
        let (tlo, thi) = (a.min(b).min(c), a.max(b).max(c));
        let first = |v: f64, axis: usize| ((v - lo[axis]) / size[axis] * COLUMNS as f64 - OFF[axis]).ceil().max(0.0) as usize;
        let (i0, j0) = (first(tlo.x, 0), first(tlo.y, 1));
        let (i1, j1) = (first(thi.x, 0).min(COLUMNS), first(thi.y, 1).min(COLUMNS));
        let area = (b - a).truncate().perp_dot((c - a).truncate());
        if area == 0.0 {
            continue;
        }
        for i in i0..i1 {
            for j in j0..j1 {
                let p = DVec2::new(at(i, 0), at(j, 1));
                // Barycentric weights of p in the triangle's shadow.
                let (pa, pb, pc) = (a.truncate() - p, b.truncate() - p, c.truncate() - p);
                let (wa, wb) = (pb.perp_dot(pc) / area, pc.perp_dot(pa) / area);
                let wc = 1.0 - wa - wb;
                if wa >= 0.0 && wb >= 0.0 && wc >= 0.0 {
                    hits[i * COLUMNS + j].push(wa * a.z + wb * b.z + wc * c.z);
                }
            }
        }
    }
    let (mut inside, mut lines) = (0.0, 0usize);
    for zs in &mut hits {
        if zs.len() % 2 == 1 {
            continue;
        }
        zs.sort_by(f64::total_cmp);
        inside += zs.chunks(2).map(|z| z[1] - z[0]).sum::<f64>();
        lines += 1;
    }
    if lines == 0 || size.z <= 0.0 {
        return 1.0;
    }
    inside / (lines as f64 * size.z)
}

/// `rects` less each one that mostly lies over a larger one of a near
/// parallel plane: seen from anywhere but edge-on, those two cover nearly
/// the same rays. Sorted and compared as found, not as grown: a grown
/// rectangle reaches over the neighbours it was found beside.
fn distinct(mut rects: Vec<(f64, Found)>, cell: f64) -> Vec<(f64, Found)> {
    let reach = REACH * cell;
    let area = |r: &(f64, Found)| {
        let d = r.1.found[1] - r.1.found[0];
        d.x * d.y
    };
    rects.sort_by(|a, b| area(b).total_cmp(&area(a)));
    let mut kept: Vec<(f64, Found)> = Vec::new();
    for r in rects {
        let covered = kept.iter().any(|k| {
            if (k.0 - r.0).abs() > reach {
                return false;
            }
            let [lo, hi] = r.1.found;
            let d = (hi.min(k.1.found[1]) - lo.max(k.1.found[0])).max(DVec2::ZERO);
            d.x * d.y >= OVERLAP * area(&r)
        });
        if !covered {
            kept.push(r);
        }
    }
    kept
}

/// A rectangle of a plane's inside cells as [`largest_rects`] found it
/// and as it grew, each as its low and high corners.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Found {
    found: [DVec2; 2],
    grown: [DVec2; 2],
}

/// The cells of one plane.
struct Grid {
    origin: DVec2,
    cell: f64,
    nu: usize,
    nv: usize,
}

impl Grid {
    /// The cells whose squares meet the box `[lo, hi]` (one whose square
    /// only touches it along a side may be left out or not: callers grow
    /// the box by the margin first, so the triangle inside stays clear).
    fn span(&self, lo: DVec2, hi: DVec2) -> Option<([usize; 2], [usize; 2])> {
        let first = |x: f64, n: usize| (x.floor().max(0.0) as usize).min(n);
        let a = (lo - self.origin) / self.cell;
        let b = (hi - self.origin) / self.cell;
        let (i0, j0) = (first(a.x, self.nu), first(a.y, self.nv));
        let (i1, j1) = (first(b.x, self.nu - 1), first(b.y, self.nv - 1));
        if b.x < 0.0 || b.y < 0.0 || i0 >= self.nu || j0 >= self.nv {
            return None;
        }
        Some(([i0, i1], [j0, j1]))
    }

    /// Cell `(i, j)`'s low corner.
    fn at(&self, i: usize, j: usize) -> DVec2 {
        self.origin + DVec2::new(i as f64, j as f64) * self.cell
    }
}

/// The rectangles inside the closed set `tris` on planes across `frame`'s
/// `n`, in cells of side `cell`.
fn rects_across(surfaces: &Surfaces, tris: &[u32], frame: Frame, cell: f64, m: f64) -> Vec<SolidRect> {
    let local: Vec<[DVec3; 3]> = tris
        .iter()
        .map(|&t| surfaces.triangles[t as usize].map(|p| frame.local(p)))
        .collect();
    let boxes: Vec<[DVec3; 2]> = local
        .iter()
        .map(|t| [t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])])
        .collect();
    let (lo, hi) = boxes
        .iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), [l, h]| (a.min(*l), b.max(*h)));
    let grid = Grid {
        origin: lo.truncate() - DVec2::splat(cell),
        cell,
        nu: ((hi.x - lo.x) / cell).ceil() as usize + 2,
        nv: ((hi.y - lo.y) / cell).ceil() as usize + 2,
    };
    let planes = (((hi.z - lo.z) / cell).ceil() as usize).max(1);
    let step = (hi.z - lo.z) / planes as f64;
    let plane_w = |k: usize| lo.z + (k as f64 + 0.5) * step;
    // Each plane's triangles (a plane or so more on each side than the
    // box says: the clip below decides), and a coarse grid of them by
    // their extent along the planes.
    let mut on_plane: Vec<Vec<u32>> = vec![Vec::new(); planes];
    let buckets = Grid {
        origin: grid.origin,
        cell: grid.cell * (grid.nu.max(grid.nv) as f64 / BUCKETS as f64),
        nu: BUCKETS,
        nv: BUCKETS,
    };
    let mut in_bucket: Vec<Vec<u32>> = vec![Vec::new(); BUCKETS * BUCKETS];
    let g = DVec3::splat(m);
    for (t, [blo, bhi]) in boxes.iter().enumerate() {
        let (blo, bhi) = (*blo - g, *bhi + g);
        let k0 = ((blo.z - lo.z) / step - 1.5).max(0.0) as usize;
        let k1 = (((bhi.z - lo.z) / step + 0.5).max(0.0) as usize).min(planes - 1);
        for list in on_plane.iter_mut().take(k1 + 1).skip(k0) {
            list.push(t as u32);
        }
        if let Some(([i0, i1], [j0, j1])) = buckets.span(blo.truncate(), bhi.truncate()) {
            for i in i0..=i1 {
                for j in j0..=j1 {
                    in_bucket[i * BUCKETS + j].push(t as u32);
                }
            }
        }
    }
    let beyond = hi.z + cell;
    let found: Vec<(f64, Found)> = (0..planes)
        .into_par_iter()
        .flat_map_iter(|k| {
            let w = plane_w(k);
            // Whether the point `p` of the plane has odd parity: crossings
            // of the segment from it along `n` to beyond the set, counted
            // exactly on the scene's triangles (the segment's ends are
            // rounded from the frame; no triangle lies within the margin of
            // a clear cell, so that moves no crossing).
            let parity = |p: DVec2| -> Option<bool> {
                let ([i, _], [j, _]) = buckets.span(p, p)?;
                let from = frame.world(p.extend(w));
                let to = frame.world(p.extend(beyond));
                let mut odd = false;
                for &t in &in_bucket[i * BUCKETS + j] {
                    let [blo, bhi] = boxes[t as usize];
                    if bhi.z < w - m || blo.x > p.x + m || bhi.x < p.x - m || blo.y > p.y + m || bhi.y < p.y - m {
                        continue;
                    }
                    match crossing(from, to, &surfaces.triangles[tris[t as usize] as usize]) {
                        Crossing::Through => odd = !odd,
                        Crossing::Misses => {}
                        Crossing::Degenerate => return None,
                    }
                }
                Some(odd)
            };
            let inside = inside_cells(&local, &on_plane[k], &grid, w, m, parity);
            largest_rects(inside, &grid).into_iter().map(move |r| (w, r))
        })
        .collect();
    distinct(found, cell)
        .into_iter()
        .map(|(w, Found { grown: [a, b], .. })| SolidRect {
            corners: [a, DVec2::new(b.x, a.y), b, DVec2::new(a.x, b.y)].map(|c| frame.world(c.extend(w))),
            normal: frame.n,
            d: -w,
        })
        .collect()
}

/// Per cell of `grid` on the plane `n = w` of a frame, whether it lies
/// inside the closed set whose triangles (frame coordinates) near the
/// plane are `near`: clear of all of them, and joined to a cell whose
/// centre `parity` finds odd.
fn inside_cells(
    local: &[[DVec3; 3]],
    near: &[u32],
    grid: &Grid,
    w: f64,
    m: f64,
    parity: impl Fn(DVec2) -> Option<bool>,
) -> Vec<bool> {
    let (nu, nv) = (grid.nu, grid.nv);
    let mut clear = vec![true; nu * nv];
    let slab_lo = DVec2::NEG_INFINITY.extend(w - m);
    let slab_hi = DVec2::INFINITY.extend(w + m);
    for &t in near {
        let tri = &local[t as usize];
        let clipped = clip_to_box(tri, slab_lo, slab_hi);
        let part: &[DVec3] = match &clipped {
            Some((_, 0)) => continue,
            Some((poly, len)) => &poly[..*len],
            None => tri,
        };
        let (mut blo, mut bhi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for p in part {
            let q = p.truncate();
            (blo, bhi) = (blo.min(q), bhi.max(q));
        }
        if let Some(([i0, i1], [j0, j1])) = grid.span(blo - DVec2::splat(m), bhi + DVec2::splat(m)) {
            for i in i0..=i1 {
                for j in j0..=j1 {
                    clear[i * nv + j] = false;
                }
            }
        }
    }
    // Regions of clear cells joined by sides, each judged by its parity.
    let mut inside = vec![false; nu * nv];
    let mut seen = vec![false; nu * nv];
    let mut stack = Vec::new();
    let mut region = Vec::new();
    for start in 0..nu * nv {
        if !clear[start] || seen[start] {
            continue;
        }
        region.clear();
        seen[start] = true;
        stack.push(start);
        while let Some(c) = stack.pop() {
            region.push(c);
            let (i, j) = (c / nv, c % nv);
            let mut push = |n: usize| {
                if clear[n] && !seen[n] {
                    seen[n] = true;
                    stack.push(n);
                }
            };
            if i > 0 {
                push(c - nv);
            }
            if i + 1 < nu {
                push(c + nv);
            }
            if j > 0 {
                push(c - 1);
            }
            if j + 1 < nv {
                push(c + 1);
            }
        }
        let odd = region
            .iter()
            .take(PARITY_TRIES)
            .find_map(|&c| parity(grid.at(c / nv, c % nv) + DVec2::splat(0.5 * grid.cell)))
            .unwrap_or(false);
        if odd {
            for &c in &region {
                inside[c] = true;
            }
        }
    }
    inside
}

/// Rectangles of `inside` cells, largest first, each found among cells
/// no earlier one took, while they have [`MIN_CELLS`], then grown over
/// `inside` cells as far as they go. Grown, neighbours found side by side
/// overlap where inside cells reach past their seam (where one's side
/// lies along the other's, always): a cell of the screen map on the seam
/// is then covered whole by one of them, where it was by neither. Every
/// `inside` cell is proved inside, so the grown rectangle is too.
fn largest_rects(inside: Vec<bool>, grid: &Grid) -> Vec<Found> {
    let (nu, nv) = (grid.nu, grid.nv);
    let counts = CellCounts::new(&inside, nu, nv);
    let mut free = inside;
    let mut out = Vec::new();
    let mut heights = vec![0usize; nv];
    let mut stack: Vec<(usize, usize)> = Vec::new();
    while out.len() < PER_PLANE {
        // The largest all-free rectangle: per row `i`, column heights of
        // free cells ending there, and the largest rectangle under them.
        let mut best = (0usize, [0usize; 4]);
        heights.fill(0);
        for i in 0..nu {
            for (h, &f) in heights.iter_mut().zip(&free[i * nv..(i + 1) * nv]) {
                *h = if f { *h + 1 } else { 0 };
            }
            stack.clear();
            for j in 0..=nv {
                let h = heights.get(j).copied().unwrap_or(0);
                let mut start = j;
                while let Some(&(s, sh)) = stack.last() {
                    if sh < h {
                        break;
                    }
                    stack.pop();
                    let area = sh * (j - s);
                    if area > best.0 {
                        best = (area, [i + 1 - sh, i, s, j - 1]);
                    }
                    start = s;
                }
                if h > 0 {
                    stack.push((start, h));
                }
            }
        }
        let (area, found) = best;
        if area < MIN_CELLS {
            break;
        }
        let [i0, i1, j0, j1] = found;
        for i in i0..=i1 {
            for j in j0..=j1 {
                free[i * nv + j] = false;
            }
        }
        let [g0, g1, h0, h1] = grown(&counts, found);
        out.push(Found {
            found: [grid.at(i0, j0), grid.at(i1 + 1, j1 + 1)],
            grown: [grid.at(g0, h0), grid.at(g1 + 1, h1 + 1)],
        });
    }
    out
}

/// Counts of cells in rectangles of a grid, each in four look-ups: a
/// summed-area table.
struct CellCounts {
    nu: usize,
    nv: usize,
    sums: Vec<u32>,
}

impl CellCounts {
    /// Over the `nu × nv` cells where `set` (row `i` at `i * nv`).
    fn new(set: &[bool], nu: usize, nv: usize) -> CellCounts {
        let w = nv + 1;
        let mut sums = vec![0u32; (nu + 1) * w];
        for i in 0..nu {
            let mut row = 0;
            for j in 0..nv {
                row += set[i * nv + j] as u32;
                sums[(i + 1) * w + j + 1] = sums[i * w + j + 1] + row;
            }
        }
        CellCounts { nu, nv, sums }
    }

    /// Whether every cell of `[i0, i1, j0, j1]` (inclusive) is set.
    fn all(&self, [i0, i1, j0, j1]: [usize; 4]) -> bool {
        let w = self.nv + 1;
        let s = |i: usize, j: usize| self.sums[i * w + j];
        let count = s(i1 + 1, j1 + 1) + s(i0, j0) - s(i0, j1 + 1) - s(i1 + 1, j0);
        count as usize == (i1 + 1 - i0) * (j1 + 1 - j0)
    }
}

/// The rectangle of cells `[i0, i1, j0, j1]` (inclusive) grown a row or
/// column at a time on each side while all of the new one is among the
/// cells `inside` counts.
fn grown(inside: &CellCounts, [mut i0, mut i1, mut j0, mut j1]: [usize; 4]) -> [usize; 4] {
    let (nu, nv) = (inside.nu, inside.nv);
    loop {
        let before = [i0, i1, j0, j1];
        if i0 > 0 && inside.all([i0 - 1, i0 - 1, j0, j1]) {
            i0 -= 1;
        }
        if i1 + 1 < nu && inside.all([i1 + 1, i1 + 1, j0, j1]) {
            i1 += 1;
        }
        if j0 > 0 && inside.all([i0, i1, j0 - 1, j0 - 1]) {
            j0 -= 1;
        }
        if j1 + 1 < nv && inside.all([i0, i1, j1 + 1, j1 + 1]) {
            j1 += 1;
        }
        if [i0, i1, j0, j1] == before {
            return before;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::grid_box_triangles as box_surface;
    use super::*;

    /// Whether `p` has odd parity, by brute force on a ray in a direction
    /// no test surface is parallel to.
    fn odd(p: DVec3, tris: &[[DVec3; 3]]) -> bool {
        let far = p + DVec3::new(0.3713, 0.5119, 0.7741) * 1e3;
        tris.iter()
            .filter(|t| {
                let c = crossing(p, far, t);
                assert_ne!(c, Crossing::Degenerate, "the brute-force ray is generic");
                c == Crossing::Through
            })
            .count()
            % 2
            == 1
    }

    /// Whether segment `p q` comes within 10⁻⁹ of rectangle `r` where it
    /// meets `r`'s plane (or lies in it at an end).
    fn touches(r: &SolidRect, p: DVec3, q: DVec3) -> bool {
        let [a, b, _, d] = r.corners;
        let within = |x: DVec3| {
            let (e, f) = (b - a, d - a);
            let (s, t) = ((x - a).dot(e) / e.length_squared(), (x - a).dot(f) / f.length_squared());
            (-1e-9..=1.0 + 1e-9).contains(&s) && (-1e-9..=1.0 + 1e-9).contains(&t)
        };
        let (dp, dq) = (r.normal.dot(p) + r.d, r.normal.dot(q) + r.d);
        if dp.abs() < 1e-12 && dq.abs() < 1e-12 {
            return within(p) || within(q);
        }
        if dp * dq > 0.0 {
            return false;
        }
        within(p + (q - p) * (dp / (dp - dq)))
    }

    /// Checks that every rectangle of `solid` lies inside the closed
    /// surface `tris`: points of it have odd parity, and no edge of a
    /// triangle crosses it nor an edge of it a triangle.
    fn all_inside(solid: &Solid, tris: &[[DVec3; 3]]) {
        for r in &solid.rects {
            let [a, b, c, d] = r.corners;
            for p in [a, b, c, d, (a + c) * 0.5, (a + b) * 0.5, (b + c) * 0.5, (c + d) * 0.5, (d + a) * 0.5] {
                assert!(odd(p, tris), "{p} of {r:?} is outside");
                assert!((r.normal.dot(p) + r.d).abs() < 1e-9, "{p} is off its plane");
            }
            for t in tris {
                for k in 0..3 {
                    assert!(!touches(r, t[k], t[(k + 1) % 3]), "{r:?} meets {t:?}");
                    for (p, q) in [(a, b), (b, c), (c, d), (d, a)] {
                        assert_eq!(crossing(p, q, t), Crossing::Misses, "{r:?} meets {t:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn rectangles_of_a_closed_box_lie_inside_it_and_span_it() {
        let tris = box_surface(DVec3::splat(-2.0), DVec3::splat(2.0), 4, None);
        let owner = vec![7; tris.len()];
        let solids = find(&Surfaces::new(tris.clone()), &owner, 4.0);
        assert_eq!(solids.len(), 1);
        let s = &solids[0];
        assert_eq!(s.object, Some(7));
        assert!(s.large);
        assert!(!s.rects.is_empty() && s.rects.len() <= LARGE_KEEP);
        all_inside(s, &tris);
        // The largest is a cross-section, all but its edge cells.
        assert!(s.rects[0].area() > 0.9 * 16.0, "{}", s.rects[0].area());
    }

    #[test]
    fn a_thin_shell_is_searched_in_finer_cells_than_a_full_box_whatever_its_winding() {
        let (lo, hi) = (DVec3::splat(-2.0), DVec3::splat(2.0));
        let outer = box_surface(lo, hi, 4, None);
        let all = |tris: &[[DVec3; 3]]| (0..tris.len() as u32).collect::<Vec<_>>();
        let shell = |wall: f64| {
            let mut tris = outer.clone();
            tris.extend(box_surface(lo + wall, hi - wall, 4, None));
            tris
        };
        assert_eq!(large_grid(&outer, &all(&outer), lo, hi), GRID);
        // Walls 0.5 thick: 58% of the box inside.
        let thick = shell(0.5);
        let share = inside_share(&thick, &all(&thick), lo, hi);
        assert!((share - (1.0 - 0.75f64.powi(3))).abs() < 0.1, "{share}");
        let cells = large_grid(&thick, &all(&thick), lo, hi);
        assert!(GRID < cells && cells < GRID_THIN, "{cells}");
        // Walls 0.1 thick: as fine as the search goes, wound either way.
        let thin = shell(0.1);
        assert_eq!(large_grid(&thin, &all(&thin), lo, hi), GRID_THIN);
        let flipped: Vec<_> = thin.iter().map(|&[a, b, c]| [a, c, b]).collect();
        assert_eq!(large_grid(&flipped, &all(&flipped), lo, hi), GRID_THIN);
        let flipped: Vec<_> = thick.iter().map(|&[a, b, c]| [a, c, b]).collect();
        assert_eq!(large_grid(&flipped, &all(&flipped), lo, hi), cells);
    }

    #[test]
    fn nested_closed_surfaces_each_hold_their_own_rectangles() {
        // Two separate closed boxes: everything inside the outer one is
        // hidden from outside it, the inner one's inside too.
        let outer = box_surface(DVec3::splat(-2.0), DVec3::splat(2.0), 4, None);
        let inner = box_surface(DVec3::splat(-1.0), DVec3::new(1.0, 1.5, 1.0), 3, None);
        let tris: Vec<_> = outer.iter().chain(&inner).copied().collect();
        let owner = vec![0; tris.len()];
        let solids = find(&Surfaces::new(tris), &owner, 4.0);
        assert_eq!(solids.len(), 2);
        let (o, i) = if solids[0].hi.x > 1.5 { (&solids[0], &solids[1]) } else { (&solids[1], &solids[0]) };
        all_inside(o, &outer);
        all_inside(i, &inner);
    }

    #[test]
    fn an_open_surface_holds_none() {
        // A box with one cell missing: whether a point is inside depends on
        // the ray, so nothing is proved; the closed box within it still is.
        let open = box_surface(DVec3::splat(-2.0), DVec3::splat(2.0), 8, Some((3, 3)));
        let closed = box_surface(DVec3::splat(-1.0), DVec3::splat(1.0), 4, None);
        let tris: Vec<_> = open.iter().chain(&closed).copied().collect();
        let owner = vec![0; tris.len()];
        let surfaces = Surfaces::new(tris);
        assert_eq!(surfaces.closed_components().iter().filter(|c| **c).count(), 1);
        let solids = find(&surfaces, &owner, 4.0);
        assert_eq!(solids.len(), 1);
        all_inside(&solids[0], &closed);
    }

    #[test]
    fn a_small_closed_part_keeps_its_largest_section_of_each_direction_and_its_owner() {
        let mut tris = box_surface(DVec3::splat(-2.0), DVec3::splat(2.0), 4, None);
        let part = box_surface(DVec3::new(0.5, 0.5, 0.5), DVec3::new(0.8, 0.7, 0.9), 2, None);
        let mut owner = vec![0; tris.len()];
        owner.extend(vec![3; part.len()]);
        tris.extend(part);
        let solids = find(&Surfaces::new(tris.clone()), &owner, 4.0);
        let small: Vec<_> = solids.iter().filter(|s| !s.large).collect();
        assert_eq!(small.len(), 1);
        assert_eq!(small[0].object, Some(3));
        let rects = &small[0].rects;
        assert!(rects.len() > 1);
        for (i, r) in rects.iter().enumerate() {
            assert!(rects[..i].iter().all(|q| q.normal != r.normal && q.area() >= r.area()));
        }
        for r in &small[0].rects {
            for c in r.corners {
                assert!(c.cmpgt(DVec3::new(0.5, 0.5, 0.5)).all() && c.cmplt(DVec3::new(0.8, 0.7, 0.9)).all());
            }
        }
    }

    /// A rectangle in the plane `z = z` over `[x0, x1] × [y0, y1]`,
    /// facing +z.
    fn flat(x0: f64, x1: f64, y0: f64, y1: f64, z: f64) -> SolidRect {
        SolidRect {
            corners: [
                DVec3::new(x0, y0, z),
                DVec3::new(x1, y0, z),
                DVec3::new(x1, y1, z),
                DVec3::new(x0, y1, z),
            ],
            normal: DVec3::Z,
            d: -z,
        }
    }

    #[test]
    fn a_rectangle_is_kept_for_the_sides_some_other_box_reaches() {
        let r = flat(0.0, 1.0, 0.0, 1.0, 0.0);
        let solid = Solid {
            lo: DVec3::new(0.0, 0.0, -0.1),
            hi: DVec3::new(1.0, 1.0, 0.1),
            object: Some(0),
            large: true,
            rects: vec![r],
        };
        let aabb = |lo: [f32; 3], hi: [f32; 3]| Aabb {
            min: lo.into(),
            max: hi.into(),
        };
        // The box holding it counts for neither side; one below it counts.
        let holder = aabb([0.0, 0.0, -0.1], [1.0, 1.0, 0.1]);
        let below = aabb([0.2, 0.2, -2.0], [0.4, 0.4, -1.0]);
        let b = beyond(std::slice::from_ref(&solid), &[holder, below])[0][0];
        assert_eq!(b, Beyond { positive: false, negative: true });
        // From above, what lies below is beyond it; from below, nothing is.
        assert!(b.from(&r, DVec3::new(0.5, 0.5, 5.0)));
        assert!(!b.from(&r, DVec3::new(0.5, 0.5, -5.0)));
        // Touching the plane from above is not reaching below it.
        let touching = aabb([0.2, 0.2, 0.0], [0.4, 0.4, 1.0]);
        let b = beyond(std::slice::from_ref(&solid), &[holder, touching])[0][0];
        assert_eq!(b, Beyond { positive: true, negative: false });
        assert!(!b.from(&r, DVec3::new(0.5, 0.5, 5.0)));
    }

    #[test]
    fn covering_takes_the_rectangle_that_adds_most_surface_not_the_next_largest() {
        // A 2 × 1 surface of small triangles at z = 0.
        let mut tris = Vec::new();
        for i in 0..40 {
            for j in 0..20 {
                let (x, y) = (i as f64 * 0.05, j as f64 * 0.05);
                let p = |a: f64, b: f64| DVec3::new(x + a, y + b, 0.0);
                tris.push([p(0.0, 0.0), p(0.05, 0.0), p(0.05, 0.05)]);
                tris.push([p(0.0, 0.0), p(0.05, 0.05), p(0.0, 0.05)]);
            }
        }
        let ids: Vec<u32> = (0..tris.len() as u32).collect();
        // Largest first: two that overlap on the left, then one on the right.
        let left = flat(0.0, 1.25, 0.0, 1.0, -0.01);
        let shifted = flat(0.1, 1.3, 0.0, 1.0, -0.01);
        let right = flat(1.0, 2.0, 0.0, 1.0, -0.01);
        let kept = covering(vec![left, shifted, right], &tris, &ids, 0.05, 2);
        assert_eq!(kept, vec![left, right]);
        // Too far under the surface, a rectangle covers none of it.
        let deep = flat(0.0, 2.0, 0.0, 1.0, -1.0);
        assert!(covering(vec![deep], &tris, &ids, 0.05, 2).is_empty());
    }

    /// A grid of unit cells, `n` a side.
    fn unit_grid(n: usize) -> Grid {
        Grid {
            origin: DVec2::ZERO,
            cell: 1.0,
            nu: n,
            nv: n,
        }
    }

    /// Per cell `(i, j)` of an `n × n` grid (row `i` at `i * n`), whether
    /// `set` says so.
    fn cells_where(n: usize, set: impl Fn(usize, usize) -> bool) -> Vec<bool> {
        (0..n * n).map(|c| set(c / n, c % n)).collect()
    }

    /// Cells `(i, j)` of rectangle `[lo, hi]` on a unit grid.
    fn cells_of([lo, hi]: [DVec2; 2]) -> impl Iterator<Item = (usize, usize)> {
        let (i, j) = (lo.x as usize..hi.x as usize, lo.y as usize..hi.y as usize);
        i.flat_map(move |i| j.clone().map(move |j| (i, j)))
    }

    #[test]
    fn rectangles_found_side_by_side_grow_over_each_other_and_stay_inside() {
        // A square ring two cells wide, as a thin shell's cross-section
        // shows: two long sides are found first, then the short ones
        // between them, which grow over the corners.
        let n = 16;
        let inside = cells_where(n, |i, j| i < 2 || i >= n - 2 || j < 2 || j >= n - 2);
        let rects = largest_rects(inside.clone(), &unit_grid(n));
        assert_eq!(rects.len(), 4);
        let mut cover = vec![0; n * n];
        for &Found {
            found: [fa, fb],
            grown: [a, b],
        } in &rects
        {
            // Grown over inside cells only, around what was found.
            assert!(a.cmple(fa).all() && fb.cmple(b).all(), "{rects:?}");
            for (i, j) in cells_of([a, b]) {
                assert!(inside[i * n + j], "({i}, {j}) of {a}–{b} is not inside");
                cover[i * n + j] += 1;
            }
            // Every side spans the ring's whole length.
            let size = b - a;
            assert_eq!(size.max_element(), n as f64, "{a}–{b}");
        }
        // The corners, where the found ones only met, are covered twice.
        for (i, j) in [(0, 0), (1, 1), (0, n - 1), (n - 1, 0), (n - 2, n - 2)] {
            assert_eq!(cover[i * n + j], 2, "({i}, {j})");
        }
        assert!((0..n * n).all(|c| inside[c] == (cover[c] > 0)));
    }

    #[test]
    fn a_grown_rectangle_stops_where_any_cell_of_a_new_side_is_outside() {
        // An L: a 6×3 foot and a 3-wide upright to row 8. From a cell of
        // the upright, the rectangle grows up and down the upright, not
        // into the foot past its width, and no side can grow further.
        let n = 10;
        let inside = cells_where(n, |i, j| (i < 6 && j < 3) || (i < 3 && j < 9));
        let counts = CellCounts::new(&inside, n, n);
        assert_eq!(grown(&counts, [1, 1, 5, 5]), [0, 2, 0, 8]);
        assert_eq!(grown(&counts, [4, 4, 1, 1]), [0, 5, 0, 2]);
        assert!(counts.all([0, 5, 0, 2]) && counts.all([0, 2, 0, 8]));
        assert!(!counts.all([0, 3, 0, 3]) && !counts.all([6, 6, 0, 0]));
    }

    #[test]
    fn distinct_compares_rectangles_as_found_not_as_grown() {
        let v = |x: f64, y: f64| DVec2::new(x, y);
        let rect = |plane: f64, found: [DVec2; 2], grown: [DVec2; 2]| (plane, Found { found, grown });
        // Two found side by side, each grown over the other: both stay.
        let lower = rect(0.0, [v(0.0, 0.0), v(4.0, 2.0)], [v(0.0, 0.0), v(4.0, 4.0)]);
        let upper = rect(0.0, [v(0.0, 2.0), v(4.0, 4.0)], [v(0.0, 0.0), v(4.0, 4.0)]);
        assert_eq!(distinct(vec![lower, upper], 1.0).len(), 2);
        // One found mostly over another of a near plane is dropped, though
        // grown it would reach mostly past it.
        let over = rect(1.0, [v(0.0, 0.5), v(4.0, 2.0)], [v(0.0, 0.5), v(4.0, 12.0)]);
        assert_eq!(distinct(vec![over, lower], 1.0), vec![lower]);
        // Farther than the reach, it stays.
        let far = rect(5.0, over.1.found, over.1.grown);
        assert_eq!(distinct(vec![far, lower], 1.0), vec![lower, far]);
    }
}
