//! The occlusion tree (OBSP, Bittner et al. §4–5) and its modified form
//! (MOBSP, §6): a BSP tree of shadow planes through the eye, whose in-leaves
//! link the occluder fragment that shadows their cell.
//!
//! **Soundness.** An in-leaf decides only with the plane of its own linked
//! fragment: what lies behind that plane inside the leaf's cell is hidden by
//! that fragment, whatever else the tree holds. So the front-to-back order of
//! insertion only affects how much is culled, never correctness. Every
//! classification against a plane errs towards "both sides" within `eps`,
//! and "both sides" explores both subtrees, which can only find more visible.

use std::cell::{Cell, RefCell};

use glam::DVec3;

use crate::cull::occlusion::Visibility;
use crate::cull::occlusion::tolerance::too_small_to_trust;
use crate::geom::{Aabb, ConvexPolygon, Plane};

/// A polygon that reaches past a plane by less than this share of the plane
/// tolerance does not count as reaching past it (the split's own rounding is
/// of that order); one that reaches further, but by no more than the
/// tolerance, is a sliver the split would drop, so it is sent whole to both
/// sides. Either way the polygon is tested on every side it lies on.
const SLIVER_FLOOR: f64 = 1e-3;

/// A path corner within this share of the plane tolerance of a cell's side
/// counts as on it ([`on_or_outside`]): a thousandth of the band in which
/// points are taken to lie on both sides, so an edge that is inside the
/// cell by more than rounding always keeps its own shadow plane.
const ON_PLANE_SHARE: f64 = 1e-3;

/// The visibility of a union of parts, combined as they come (Table 1).
#[derive(Clone, Copy, Debug, Default)]
struct Combined(Option<Visibility>);

impl Combined {
    /// Adds a part; true once the union is partially visible, which no
    /// further part can change.
    fn add(&mut self, v: Visibility) -> bool {
        let r = self.0.map_or(v, |r| r.combine(v));
        self.0 = Some(r);
        r == Visibility::Partial
    }

    /// The union's visibility (nothing at all counts as fully visible).
    fn visibility(self) -> Visibility {
        self.0.unwrap_or(Visibility::Full)
    }
}

/// How an in-leaf decides a region it cannot place wholly on one side of
/// the fragment's plane (Table 2's last letter).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LeafTest {
    /// Exact: the region misses the truncated pyramid between the eye and the
    /// fragment (a separating-axis test) → invisible there.
    Exact,
    /// Conservative: only the pyramid's own face planes may separate.
    Conservative,
}

/// Where a search of the tree for a box may start: the node where its
/// search first goes both ways. A box inside another takes, at every plane
/// above that node, the same single side (a box's signed-distance range
/// is monotone in the box, rounding included), so its search passes
/// through the same node and may start there; the answers are the same as
/// searching from the root. Only meaningful for the tree as built when it
/// was found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Entry(u32);

impl Entry {
    /// The root: where any search may start.
    pub const ROOT: Entry = Entry(0);
}

#[derive(Clone, Copy, Debug)]
enum Node {
    Inner { plane: Plane, front: u32, back: u32 },
    Out,
    In { fragment: u32 },
}

/// A fragment linked from in-leaves: its corners (a range of
/// `OcclusionTree::fragment_corners`) and its plane facing the eye.
#[derive(Clone, Debug)]
struct Fragment {
    corners: (u32, u32),
    plane: Plane,
    /// Where its separating axes lie in `OcclusionTree::axes`, once the
    /// first in-leaf test that needs them computed them: `(start, exact
    /// from, end)`. First the faces of conv(eye, fragment) (base, then one
    /// side per edge), then, from `exact from`, the box axes and the edge ×
    /// box-axis crosses.
    axes: Cell<Option<(u32, u32, u32)>>,
}

/// An axis (unit) and the interval a convex solid covers along it.
#[derive(Clone, Copy, Debug)]
struct Projection {
    axis: DVec3,
    lo: f64,
    hi: f64,
}

/// Appends the separating axes of conv(eye, polygon `v` with `plane`) to
/// `axes`; returns where the exact-only ones start.
fn push_axes(v: &[DVec3], plane: &Plane, eye: DVec3, axes: &mut Vec<Projection>) -> usize {
    let n = v.len();
    let project = |axis: DVec3| {
        let axis = axis.try_normalize()?;
        let e = axis.dot(eye);
        let (lo, hi) = v.iter().fold((e, e), |(l, h), p| {
            let d = axis.dot(*p);
            (l.min(d), h.max(d))
        });
        Some(Projection { axis, lo, hi })
    };
    axes.extend(
        std::iter::once(plane.normal)
            .chain((0..n).map(|i| (v[i] - eye).cross(v[(i + 1) % n] - eye)))
            .filter_map(project),
    );
    let exact_from = axes.len();
    let box_axes = [DVec3::X, DVec3::Y, DVec3::Z];
    axes.extend(box_axes.iter().filter_map(|&a| project(a)));
    let edges = (0..n).flat_map(|i| [v[(i + 1) % n] - v[i], v[i] - eye]);
    axes.extend(
        edges
            .flat_map(|e| box_axes.map(|a| e.cross(a)))
            .filter_map(project),
    );
    exact_from
}

/// A corner of a piece being filtered down the tree, with the flag of the
/// edge that starts at it: set when that edge lies in a plane already in
/// the tree (MOBSP), so it adds no shadow plane.
#[derive(Clone, Copy, Debug)]
struct Corner {
    at: DVec3,
    flag: bool,
}

/// A piece of the occluder being inserted, waiting at `node`; its corners
/// are `Scratch::corners[start..end]`.
#[derive(Clone, Copy, Debug)]
struct Piece {
    node: u32,
    start: u32,
    end: u32,
}

/// Buffers an insertion works in, kept between insertions and frames so
/// that building a tree allocates only while it grows past its largest yet.
#[derive(Clone, Debug, Default)]
struct Scratch {
    /// Corners of the pieces of the occluder being inserted (pieces only
    /// ever append; the whole is dropped when the occluder is in).
    corners: Vec<Corner>,
    pieces: Vec<Piece>,
    /// Signed distances of a piece's corners from the plane splitting it.
    distances: Vec<f64>,
    planes: Vec<Plane>,
}

/// An occlusion tree for one eye.
///
/// A tree kept from frame to frame ([`OcclusionTree::rebuild`]) reuses its
/// buffers: after the first frames, building it allocates nothing.
#[derive(Clone, Debug, Default)]
pub struct OcclusionTree {
    nodes: Vec<Node>,
    fragments: Vec<Fragment>,
    fragment_corners: Vec<DVec3>,
    axes: RefCell<Vec<Projection>>,
    scratch: Scratch,
    eye: DVec3,
    eps: f64,
    modified: bool,
}

impl OcclusionTree {
    /// Builds the tree for `eye` from occluders in (roughly) front-to-back
    /// order. `modified` builds the MOBSP (flagged edges add no planes).
    /// `eps` is the distance within which a point counts as on a plane.
    pub fn build<'a>(
        eye: DVec3,
        occluders: impl IntoIterator<Item = &'a ConvexPolygon>,
        modified: bool,
        eps: f64,
    ) -> Self {
        let mut t = OcclusionTree::default();
        t.rebuild(eye, occluders, modified, eps);
        t
    }

    /// [`OcclusionTree::build`] in place, reusing this tree's buffers.
    pub fn rebuild<'a>(
        &mut self,
        eye: DVec3,
        occluders: impl IntoIterator<Item = &'a ConvexPolygon>,
        modified: bool,
        eps: f64,
    ) {
        self.nodes.clear();
        self.nodes.push(Node::Out);
        self.fragments.clear();
        self.fragment_corners.clear();
        self.axes.get_mut().clear();
        (self.eye, self.eps, self.modified) = (eye, eps, modified);
        let mut scratch = std::mem::take(&mut self.scratch);
        for o in occluders {
            self.insert(o, &mut scratch);
        }
        self.scratch = scratch;
    }

    /// How many nodes (shadow planes and leaves).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Bytes its buffers hold on the heap.
    pub fn heap_bytes(&self) -> usize {
        use std::mem::size_of;
        let s = &self.scratch;
        self.nodes.capacity() * size_of::<Node>()
            + self.fragments.capacity() * size_of::<Fragment>()
            + self.fragment_corners.capacity() * size_of::<DVec3>()
            + self.axes.borrow().capacity() * size_of::<Projection>()
            + s.corners.capacity() * size_of::<Corner>()
            + s.pieces.capacity() * size_of::<Piece>()
            + s.distances.capacity() * size_of::<f64>()
            + s.planes.capacity() * size_of::<Plane>()
    }

    fn insert(&mut self, occluder: &ConvexPolygon, scratch: &mut Scratch) {
        let Some(plane) = occluder.plane() else {
            return;
        };
        let side = plane.signed_distance(self.eye);
        if side.abs() <= self.eps {
            return; // seen edge-on: it hides nothing
        }
        let plane = if side > 0.0 { plane } else { plane.flipped() };
        // A fragment with a degenerate shadow plane (the eye in line with an
        // edge) is refused where it would grow the tree (`grow`), so the
        // volume is never larger than the fragment's shadow.
        scratch.corners.clear();
        scratch
            .corners
            .extend(occluder.vertices.iter().map(|&at| Corner { at, flag: false }));
        scratch.pieces.clear();
        scratch.pieces.push(Piece {
            node: 0,
            start: 0,
            end: scratch.corners.len() as u32,
        });
        while let Some(piece) = scratch.pieces.pop() {
            match self.nodes[piece.node as usize] {
                Node::In { .. } => {}
                Node::Out => self.grow(piece, plane, scratch),
                Node::Inner {
                    plane: split,
                    front,
                    back,
                } => split_piece(piece, &split, [front, back], self.eps, scratch),
            }
        }
    }

    /// Replaces the out-leaf a piece reached by the piece's occlusion volume.
    fn grow(&mut self, piece: Piece, plane: Plane, scratch: &mut Scratch) {
        let corners = &scratch.corners[piece.start as usize..piece.end as usize];
        let first = self.fragment_corners.len();
        self.fragment_corners.extend(corners.iter().map(|c| c.at));
        let v = &self.fragment_corners[first..];
        // Leaving the leaf lit is always safe.
        if too_small_to_trust(v, self.eps) {
            self.fragment_corners.truncate(first);
            return;
        }
        // The shadow plane of each edge, with the piece behind it; a
        // degenerate one (the eye in line with an edge) refuses the piece.
        let inside = v.iter().copied().sum::<DVec3>() / v.len() as f64;
        scratch.planes.clear();
        for (i, c) in corners.iter().enumerate() {
            let (a, b) = (v[i], v[(i + 1) % v.len()]);
            // (a − eye) × (b − a): no cancellation when a and b are close.
            let Some(p) = Plane::from_point_normal(self.eye, (a - self.eye).cross(b - a)) else {
                self.fragment_corners.truncate(first);
                return;
            };
            if !(self.modified && c.flag) {
                let p = if p.signed_distance(inside) > 0.0 {
                    p.flipped()
                } else {
                    p
                };
                scratch.planes.push(p);
            }
        }
        let fragment = self.fragments.len() as u32;
        self.fragments.push(Fragment {
            corners: (first as u32, self.fragment_corners.len() as u32),
            plane,
            axes: Cell::new(None),
        });
        // A chain: each plane's front is lit, its back leads to the next plane,
        // the last back is the shadow.
        let mut at = piece.node;
        let count = scratch.planes.len();
        for (i, &p) in scratch.planes.iter().enumerate() {
            let out = self.push(Node::Out);
            let back = if i + 1 == count {
                self.push(Node::In { fragment })
            } else {
                self.push(Node::Out)
            };
            self.nodes[at as usize] = Node::Inner {
                plane: p,
                front: out,
                back,
            };
            at = back;
        }
        if count == 0 {
            self.nodes[piece.node as usize] = Node::In { fragment };
        }
    }

    fn push(&mut self, node: Node) -> u32 {
        self.nodes.push(node);
        (self.nodes.len() - 1) as u32
    }

    /// The modified visibility algorithm (§6.2): at a plane the box crosses,
    /// both subtrees are searched with the whole box, as in the paper.
    /// With `clip`, see [`OcclusionTree::clipped_region_visibility`].
    pub fn region_visibility(&self, b: &Aabb, leaf_test: LeafTest, clip: bool) -> Visibility {
        self.region_visibility_from(b, leaf_test, clip, Entry::ROOT).0
    }

    /// [`OcclusionTree::region_visibility`] searched from `from`, the
    /// [`Entry`] of a box holding `b` (or [`Entry::ROOT`]); also returns
    /// `b`'s own entry, from which boxes inside `b` may be searched.
    pub fn region_visibility_from(
        &self,
        b: &Aabb,
        leaf_test: LeafTest,
        clip: bool,
        from: Entry,
    ) -> (Visibility, Entry) {
        let region = Region::of(b);
        let entry = self.entry(&region, from);
        let v = if clip {
            self.clipped_region_visibility(region, entry, leaf_test)
        } else {
            self.whole_region_visibility(&region, entry, leaf_test)
        };
        (v, entry)
    }

    /// The node where the search for `r` first goes both ways (or the leaf
    /// it reaches without), walking down from `from`. Above it the search
    /// takes one side at each plane, with the whole region (unclipped), so
    /// every search for `r` passes through it.
    fn entry(&self, r: &Region, from: Entry) -> Entry {
        let mut at = from.0;
        while let Node::Inner { plane, front, back } = &self.nodes[at as usize] {
            let (lo, hi) = r.range(plane);
            at = if lo > self.eps {
                *front
            } else if hi < -self.eps {
                *back
            } else {
                break;
            };
        }
        Entry(at)
    }

    fn whole_region_visibility(&self, r: &Region, entry: Entry, leaf_test: LeafTest) -> Visibility {
        let mut result = Combined::default();
        // Called for every kd node and object a frame: keep it off the heap
        // while the tree is shallow enough, which it nearly always is.
        let mut stack = SmallStack::new();
        stack.push(entry.0);
        while let Some(n) = stack.pop() {
            let v = match &self.nodes[n as usize] {
                Node::Out => Visibility::Full,
                Node::In { fragment } => {
                    self.leaf_region(&self.fragments[*fragment as usize], r, leaf_test)
                }
                Node::Inner { plane, front, back } => {
                    let (lo, hi) = r.range(plane);
                    if lo > self.eps {
                        stack.push(*front);
                    } else if hi < -self.eps {
                        stack.push(*back);
                    } else {
                        stack.push(*back);
                        stack.push(*front);
                    }
                    continue;
                }
            };
            if result.add(v) {
                return Visibility::Partial;
            }
        }
        result.visibility()
    }

    /// The modified visibility algorithm with each side of a crossed plane
    /// searched with the bounding box of the region's part there: an
    /// in-leaf judges only what of the box can lie in its cell, so a node
    /// that reaches past a wall into the shadow of the next one is not
    /// partly visible merely for sticking out of each shadow (the paper's
    /// Fig. 8). Finds everything [`OcclusionTree::region_visibility`] finds
    /// hidden, and more, at the cost of clipping at every crossing.
    fn clipped_region_visibility(
        &self,
        region: Region,
        entry: Entry,
        leaf_test: LeafTest,
    ) -> Visibility {
        let mut result = Combined::default();
        let mut stack = SmallStack::new();
        stack.push((entry.0, region));
        while let Some((n, r)) = stack.pop() {
            let v = match &self.nodes[n as usize] {
                Node::Out => Visibility::Full,
                Node::In { fragment } => {
                    self.leaf_region(&self.fragments[*fragment as usize], &r, leaf_test)
                }
                Node::Inner { plane, front, back } => {
                    let (lo, hi) = r.range(plane);
                    if lo > self.eps {
                        stack.push((*front, r));
                    } else if hi < -self.eps {
                        stack.push((*back, r));
                    } else {
                        stack.push((*back, r.clipped(plane, -1.0, self.eps)));
                        stack.push((*front, r.clipped(plane, 1.0, self.eps)));
                    }
                    continue;
                }
            };
            if result.add(v) {
                return Visibility::Partial;
            }
        }
        result.visibility()
    }

    fn leaf_region(&self, f: &Fragment, b: &Region, leaf_test: LeafTest) -> Visibility {
        let (lo, hi) = b.range(&f.plane);
        if hi < -self.eps {
            return Visibility::Invisible;
        }
        if lo > self.eps {
            return Visibility::Full;
        }
        // Across the fragment's plane. Inside this leaf's cell (a part of the
        // pyramid from the eye through the fragment) the box is in front of
        // the plane only where it meets the pyramid between eye and fragment.
        if self.misses_pyramid(f, b, leaf_test) {
            Visibility::Invisible
        } else {
            Visibility::Partial
        }
    }

    /// Whether the box is separated from conv(eye, fragment), with a margin:
    /// by the pyramid's faces only, or (exact) by every axis that could.
    fn misses_pyramid(&self, f: &Fragment, b: &Region, leaf_test: LeafTest) -> bool {
        let c = (b.lo + b.hi) * 0.5;
        let r = (b.hi - b.lo) * 0.5;
        let (start, exact_from, end) = f.axes.get().unwrap_or_else(|| {
            let mut axes = self.axes.borrow_mut();
            let start = axes.len();
            let v = &self.fragment_corners[f.corners.0 as usize..f.corners.1 as usize];
            let exact_from = push_axes(v, &f.plane, self.eye, &mut axes);
            let range = (start as u32, exact_from as u32, axes.len() as u32);
            f.axes.set(Some(range));
            range
        });
        let end = match leaf_test {
            LeafTest::Conservative => exact_from,
            LeafTest::Exact => end,
        };
        self.axes.borrow()[start as usize..end as usize]
            .iter()
            .any(|p| {
                let (bc, br) = (p.axis.dot(c), p.axis.abs().dot(r));
                bc + br < p.lo - self.eps || bc - br > p.hi + self.eps
            })
    }

    /// Exact visibility of a box with respect to the occluders (§5.1–5.2):
    /// its faces towards the eye are filtered down the tree with splitting.
    /// Meant for the OBSP; boxes flat on an axis fall back to
    /// [`OcclusionTree::region_visibility`].
    pub fn box_visibility_exact(&self, b: &Aabb) -> Visibility {
        let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
        let e = self.eye;
        if (0..3).any(|k| hi[k] - lo[k] <= self.eps) {
            return self.region_visibility(b, LeafTest::Exact, false);
        }
        if (0..3).all(|k| e[k] >= lo[k] - self.eps && e[k] <= hi[k] + self.eps) {
            // The eye is in (or on) the box: every face turns away, yet what
            // the box holds may still be hidden. Nothing can be concluded.
            return Visibility::Partial;
        }
        let mut result = Combined::default();
        for k in 0..3 {
            let at = if e[k] < lo[k] {
                lo[k]
            } else if e[k] > hi[k] {
                hi[k]
            } else {
                continue;
            };
            let (u, w) = ((k + 1) % 3, (k + 2) % 3);
            let corner = |a: f64, c: f64| {
                let mut p = DVec3::ZERO;
                p[k] = at;
                p[u] = a;
                p[w] = c;
                p
            };
            let face = ConvexPolygon::new(vec![
                corner(lo[u], lo[w]),
                corner(hi[u], lo[w]),
                corner(hi[u], hi[w]),
                corner(lo[u], hi[w]),
            ]);
            let v = self.polygon_visibility(face);
            if result.add(v) {
                return Visibility::Partial;
            }
        }
        result.visibility()
    }

    /// Figure 4: a polygon filtered down the tree, fragments combined.
    fn polygon_visibility(&self, polygon: ConvexPolygon) -> Visibility {
        let mut result = Combined::default();
        let mut stack = vec![(0u32, polygon)];
        while let Some((n, p)) = stack.pop() {
            let v = match &self.nodes[n as usize] {
                Node::Out => Visibility::Full,
                Node::In { fragment } => {
                    let f = &self.fragments[*fragment as usize];
                    let (lo, hi) =
                        p.vertices
                            .iter()
                            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                                let d = f.plane.signed_distance(*v);
                                (l.min(d), h.max(d))
                            });
                    if hi < -self.eps {
                        Visibility::Invisible
                    } else if lo > self.eps {
                        Visibility::Full
                    } else {
                        Visibility::Partial
                    }
                }
                Node::Inner { plane, front, back } => {
                    let (lo, hi) =
                        p.vertices
                            .iter()
                            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                                let d = plane.signed_distance(*v);
                                (l.min(d), h.max(d))
                            });
                    let s = p.split(plane, self.eps);
                    // A sliver thinner than eps on one side of a polygon that
                    // lies beyond eps on the other is dropped by the split;
                    // send such a polygon whole to both subtrees instead.
                    let tiny = SLIVER_FLOOR * self.eps;
                    let sliver = (hi > tiny && hi <= self.eps && lo < -self.eps)
                        || (lo < -tiny && lo >= -self.eps && hi > self.eps);
                    if s.coplanar || sliver {
                        stack.push((*back, p.clone()));
                        stack.push((*front, p));
                    } else {
                        if let Some(b) = s.back {
                            stack.push((*back, b));
                        }
                        if let Some(f) = s.front {
                            stack.push((*front, f));
                        }
                    }
                    continue;
                }
            };
            if result.add(v) {
                return Visibility::Partial;
            }
        }
        result.visibility()
    }
}

/// Sends a piece on to the children `[front, back]` of a shadow plane,
/// split where it crosses. An edge on the plane (on or outside the part's
/// side, see [`on_or_outside`]) is flagged in that part.
fn split_piece(piece: Piece, plane: &Plane, children: [u32; 2], eps: f64, s: &mut Scratch) {
    let (start, end) = (piece.start as usize, piece.end as usize);
    s.distances.clear();
    s.distances.extend(
        s.corners[start..end]
            .iter()
            .map(|c| plane.signed_distance(c.at)),
    );
    let d = &s.distances;
    if d.iter().all(|x| x.abs() <= eps) {
        // In the plane (edge-on from the eye): it casts no shadow.
        return;
    }
    for (side, sign) in [(0, 1.0), (1, -1.0)] {
        if d.iter().all(|&x| x * sign >= -eps) {
            // Wholly on this side: flagged in place, sent on whole.
            let n = d.len();
            for i in 0..n {
                if on_or_outside(d[i], sign, eps) && on_or_outside(d[(i + 1) % n], sign, eps) {
                    s.corners[start + i].flag = true;
                }
            }
            s.pieces.push(Piece {
                node: children[side],
                ..piece
            });
            return;
        }
    }
    for (side, sign) in [(0, 1.0), (1, -1.0)] {
        if let Some(part) = clip_side(start, end, plane, sign, eps, s) {
            s.pieces.push(Piece {
                node: children[side],
                ..part
            });
        }
    }
}

/// Appends the part of the piece `corners[start..end]` on side `sign` of
/// the plane (whose distances are in `s.distances`) to `s.corners`. An
/// output corner's edge keeps the original edge's flag while it runs along
/// that edge, and is flagged where it runs along the plane.
fn clip_side(
    start: usize,
    end: usize,
    plane: &Plane,
    sign: f64,
    eps: f64,
    s: &mut Scratch,
) -> Option<Piece> {
    let n = end - start;
    let first = s.corners.len();
    for i in 0..n {
        let j = (i + 1) % n;
        let (a, b) = (s.corners[start + i], s.corners[start + j]);
        let (di, dj) = (s.distances[i], s.distances[j]);
        let (da, db) = (di * sign, dj * sign);
        let leaving = da > eps && db < -eps;
        let entering = da < -eps && db > eps;
        if da >= -eps {
            let along_edge = db >= -eps || leaving;
            s.corners.push(Corner {
                at: a.at,
                flag: along_edge && a.flag,
            });
        }
        if leaving || entering {
            s.corners.push(Corner {
                at: a.at + (b.at - a.at) * (di / (di - dj)),
                flag: entering && a.flag,
            });
        }
    }
    let m = s.corners.len() - first;
    if m < 3 {
        s.corners.truncate(first);
        return None;
    }
    // An edge whose both ends lie on the plane (or outside this side) runs
    // along it: flagged.
    let part = &mut s.corners[first..];
    let on_first = on_or_outside(plane.signed_distance(part[0].at), sign, eps);
    let mut on_next = on_first;
    for i in (0..m).rev() {
        // Walking backwards, `on_next` is corner i + 1's (corner 0's for the last).
        let on_here = on_or_outside(plane.signed_distance(part[i].at), sign, eps);
        if on_here && on_next {
            part[i].flag = true;
        }
        on_next = on_here;
    }
    Some(Piece {
        node: 0,
        start: first as u32,
        end: (first + m) as u32,
    })
}

/// Whether a point at distance `d` lies on the plane or outside the cell on
/// side `sign`, up to rounding. Only then may its edge go without a shadow
/// plane of its own: the path's plane bounds the cell at least as tightly.
/// An edge even slightly inside the cell keeps its own plane.
fn on_or_outside(d: f64, sign: f64, eps: f64) -> bool {
    d * sign <= ON_PLANE_SHARE * eps
}

/// A stack on the call stack, spilling to the heap only past 64 entries.
struct SmallStack<T> {
    inline: [T; 64],
    len: usize,
    spill: Vec<T>,
}

impl<T: Copy + Default> SmallStack<T> {
    fn new() -> Self {
        SmallStack {
            inline: [T::default(); 64],
            len: 0,
            spill: Vec::new(),
        }
    }

    fn push(&mut self, v: T) {
        if self.len < self.inline.len() {
            self.inline[self.len] = v;
            self.len += 1;
        } else {
            self.spill.push(v);
        }
    }

    fn pop(&mut self) -> Option<T> {
        if let Some(v) = self.spill.pop() {
            return Some(v);
        }
        (self.len > 0).then(|| {
            self.len -= 1;
            self.inline[self.len]
        })
    }
}

/// An axis-aligned box in `f64`: a kd node's or object's box, or the
/// bounding box of its part on one side of the shadow planes above a node.
#[derive(Clone, Copy, Debug, Default)]
struct Region {
    lo: DVec3,
    hi: DVec3,
}

impl Region {
    fn of(b: &Aabb) -> Region {
        Region {
            lo: b.min.as_dvec3(),
            hi: b.max.as_dvec3(),
        }
    }

    /// The smallest and largest signed distance of its corners, from two of
    /// them (as [`Plane::box_range`]). An empty region is `(+inf, -inf)`.
    fn range(&self, p: &Plane) -> (f64, f64) {
        if !(self.lo.cmple(self.hi).all()) {
            return (f64::INFINITY, f64::NEG_INFINITY);
        }
        let n = p.normal;
        let pick = |k: usize| {
            if n[k] >= 0.0 {
                (self.lo[k], self.hi[k])
            } else {
                (self.hi[k], self.lo[k])
            }
        };
        let (x, y, z) = (pick(0), pick(1), pick(2));
        (
            p.signed_distance(DVec3::new(x.0, y.0, z.0)),
            p.signed_distance(DVec3::new(x.1, y.1, z.1)),
        )
    }

    /// A box holding its part on side `sign` of the plane (distance ≥ 0
    /// times `sign`), grown by `eps` and kept inside the region: the corners
    /// on that side (within `eps`) and the points where its edges cross the
    /// plane bound that part exactly, and `eps` (~10⁷ roundings of these
    /// magnitudes, [`plane_tolerance`](crate::cull::occlusion::tolerance::plane_tolerance))
    /// covers the rounding of the crossings.
    fn clipped(&self, plane: &Plane, sign: f64, eps: f64) -> Region {
        let corner = |i: usize| {
            DVec3::new(
                if i & 1 == 0 { self.lo.x } else { self.hi.x },
                if i & 2 == 0 { self.lo.y } else { self.hi.y },
                if i & 4 == 0 { self.lo.z } else { self.hi.z },
            )
        };
        let corners: [DVec3; 8] = std::array::from_fn(corner);
        let d = corners.map(|c| plane.signed_distance(c) * sign);
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for i in 0..8 {
            if d[i] >= -eps {
                (lo, hi) = (lo.min(corners[i]), hi.max(corners[i]));
            }
            for bit in [1, 2, 4] {
                let j = i | bit;
                if j != i && (d[i] < 0.0) != (d[j] < 0.0) {
                    let t = d[i] / (d[i] - d[j]);
                    let p = corners[i] + (corners[j] - corners[i]) * t;
                    (lo, hi) = (lo.min(p), hi.max(p));
                }
            }
        }
        if !lo.cmple(hi).all() {
            return *self; // nothing on that side past rounding: keep it whole
        }
        Region {
            lo: (lo - DVec3::splat(eps)).max(self.lo),
            hi: (hi + DVec3::splat(eps)).min(self.hi),
        }
    }
}
