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

#[derive(Clone, Debug)]
enum Node {
    Inner { plane: Plane, front: u32, back: u32 },
    Out,
    In { fragment: u32 },
}

/// A fragment linked from in-leaves: its polygon, its plane facing the eye.
#[derive(Clone, Debug)]
struct Fragment {
    polygon: ConvexPolygon,
    plane: Plane,
    /// Separating axes of conv(eye, fragment) with its extent on each
    /// (computed at the first in-leaf test that needs them): first its faces
    /// (base, then one side per edge), then the box axes and the edge ×
    /// box-axis crosses, from index `.1` on.
    axes: std::cell::OnceCell<(Vec<Projection>, usize)>,
}

/// An axis (unit) and the interval a convex solid covers along it.
#[derive(Clone, Copy, Debug)]
struct Projection {
    axis: DVec3,
    lo: f64,
    hi: f64,
}

impl Fragment {
    fn new(polygon: ConvexPolygon, plane: Plane) -> Fragment {
        Fragment {
            polygon,
            plane,
            axes: std::cell::OnceCell::new(),
        }
    }

    /// The separating axes and where the exact-only ones start.
    fn axes(&self, eye: DVec3) -> &(Vec<Projection>, usize) {
        self.axes.get_or_init(|| self.compute_axes(eye))
    }

    fn compute_axes(&self, eye: DVec3) -> (Vec<Projection>, usize) {
        let (polygon, plane) = (&self.polygon, &self.plane);
        let v = &polygon.vertices;
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
        let mut axes: Vec<Projection> = std::iter::once(plane.normal)
            .chain((0..n).map(|i| (v[i] - eye).cross(v[(i + 1) % n] - eye)))
            .filter_map(project)
            .collect();
        let exact_from = axes.len();
        let box_axes = [DVec3::X, DVec3::Y, DVec3::Z];
        axes.extend(box_axes.iter().filter_map(|&a| project(a)));
        let edges = (0..n).flat_map(|i| [v[(i + 1) % n] - v[i], v[i] - eye]);
        axes.extend(
            edges
                .flat_map(|e| box_axes.map(|a| e.cross(a)))
                .filter_map(project),
        );
        (axes, exact_from)
    }
}

/// A polygon whose edges may be flagged as lying in a plane already in the
/// tree (MOBSP). `flags[i]` belongs to the edge from vertex `i` to `i + 1`.
#[derive(Clone, Debug)]
struct Flagged {
    vertices: Vec<DVec3>,
    flags: Vec<bool>,
}

/// An occlusion tree for one eye.
#[derive(Clone, Debug)]
pub struct OcclusionTree {
    nodes: Vec<Node>,
    fragments: Vec<Fragment>,
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
        let mut t = OcclusionTree {
            nodes: vec![Node::Out],
            fragments: Vec::new(),
            eye,
            eps,
            modified,
        };
        for o in occluders {
            t.insert(o);
        }
        t
    }

    /// How many nodes (shadow planes and leaves).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    fn insert(&mut self, occluder: &ConvexPolygon) {
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
        let mut stack = vec![(
            0u32,
            Flagged {
                flags: vec![false; occluder.vertices.len()],
                vertices: occluder.vertices.clone(),
            },
        )];
        while let Some((n, poly)) = stack.pop() {
            match self.nodes[n as usize].clone() {
                Node::In { .. } => {}
                Node::Out => self.grow(n, poly, plane),
                Node::Inner {
                    plane: split,
                    front,
                    back,
                } => {
                    let (f, b) = split_flagged(&poly, &split, self.eps);
                    if let Some(f) = f {
                        stack.push((front, f));
                    }
                    if let Some(b) = b {
                        stack.push((back, b));
                    }
                }
            }
        }
    }

    /// The shadow planes of a polygon's edges, each with the polygon behind
    /// it; `None` if one degenerates (the eye in line with an edge).
    fn shadow_planes(&self, v: &[DVec3], plane: &Plane) -> Option<Vec<Plane>> {
        let inside = v.iter().copied().sum::<DVec3>() / v.len() as f64;
        (0..v.len())
            .map(|i| {
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                // (a − eye) × (b − a): no cancellation when a and b are close.
                let n = (a - self.eye).cross(b - a);
                let p = Plane::from_point_normal(self.eye, n)?;
                let p = if p.signed_distance(inside) > 0.0 {
                    p.flipped()
                } else {
                    p
                };
                // The eye must see the polygon's face, not an edge of it.
                (plane.signed_distance(self.eye) > 0.0).then_some(p)
            })
            .collect()
    }

    /// Replaces out-leaf `n` by the occlusion volume of `poly`.
    fn grow(&mut self, n: u32, poly: Flagged, plane: Plane) {
        // Leaving the leaf lit is always safe.
        if too_small_to_trust(&poly.vertices, self.eps) {
            return;
        }
        let Some(planes) = self.shadow_planes(&poly.vertices, &plane) else {
            return;
        };
        let fragment = self.fragments.len() as u32;
        self.fragments.push(Fragment::new(
            ConvexPolygon::new(poly.vertices.clone()),
            plane,
        ));
        let planes: Vec<Plane> = planes
            .into_iter()
            .zip(&poly.flags)
            .filter(|&(_, flagged)| !(self.modified && *flagged))
            .map(|(p, _)| p)
            .collect();
        // A chain: each plane's front is lit, its back leads to the next plane,
        // the last back is the shadow.
        let mut at = n;
        for (i, p) in planes.iter().enumerate() {
            let out = self.push(Node::Out);
            let back = if i + 1 == planes.len() {
                self.push(Node::In { fragment })
            } else {
                self.push(Node::Out)
            };
            self.nodes[at as usize] = Node::Inner {
                plane: *p,
                front: out,
                back,
            };
            at = back;
        }
        if planes.is_empty() {
            self.nodes[n as usize] = Node::In { fragment };
        }
    }

    fn push(&mut self, node: Node) -> u32 {
        self.nodes.push(node);
        (self.nodes.len() - 1) as u32
    }

    /// The modified visibility algorithm (§6.2): the box is never split; at
    /// a plane it crosses, both subtrees are searched.
    pub fn region_visibility(&self, b: &Aabb, leaf_test: LeafTest) -> Visibility {
        let mut result = Combined::default();
        // Called for every kd node and object a frame: keep it off the heap
        // while the tree is shallow enough, which it nearly always is.
        let mut stack = SmallStack::new();
        stack.push(0);
        while let Some(n) = stack.pop() {
            let v = match &self.nodes[n as usize] {
                Node::Out => Visibility::Full,
                Node::In { fragment } => {
                    self.leaf_region(&self.fragments[*fragment as usize], b, leaf_test)
                }
                Node::Inner { plane, front, back } => {
                    let (lo, hi) = plane.box_range(b);
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

    fn leaf_region(&self, f: &Fragment, b: &Aabb, leaf_test: LeafTest) -> Visibility {
        let (lo, hi) = f.plane.box_range(b);
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
    fn misses_pyramid(&self, f: &Fragment, b: &Aabb, leaf_test: LeafTest) -> bool {
        let c = (b.min.as_dvec3() + b.max.as_dvec3()) * 0.5;
        // Half-extents in f64: an f32 difference of far-apart bounds rounds.
        let r = (b.max.as_dvec3() - b.min.as_dvec3()) * 0.5;
        let (all, exact_from) = f.axes(self.eye);
        let axes = match leaf_test {
            LeafTest::Conservative => &all[..*exact_from],
            LeafTest::Exact => &all[..],
        };
        axes.iter().any(|p| {
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
            return self.region_visibility(b, LeafTest::Exact);
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

/// Splits a flagged polygon by a shadow plane. An edge on the plane (on or
/// outside the part's side, see [`on_or_outside`]) is flagged in that part.
fn split_flagged(p: &Flagged, plane: &Plane, eps: f64) -> (Option<Flagged>, Option<Flagged>) {
    let d: Vec<f64> = p
        .vertices
        .iter()
        .map(|&v| plane.signed_distance(v))
        .collect();
    if d.iter().all(|x| x.abs() <= eps) {
        // In the plane (edge-on from the eye): it casts no shadow.
        return (None, None);
    }
    if d.iter().all(|&x| x >= -eps) {
        return (Some(flag_on_plane(p, &d, 1.0, eps)), None);
    }
    if d.iter().all(|&x| x <= eps) {
        return (None, Some(flag_on_plane(p, &d, -1.0, eps)));
    }
    (
        clip_side(p, plane, &d, 1.0, eps),
        clip_side(p, plane, &d, -1.0, eps),
    )
}

/// The part of `p` on side `sign` of the plane whose vertex distances are `d`.
/// An output vertex's edge keeps the original edge's flag while it runs
/// along that edge, and is flagged where it runs along the plane.
fn clip_side(p: &Flagged, plane: &Plane, d: &[f64], sign: f64, eps: f64) -> Option<Flagged> {
    let n = p.vertices.len();
    let mut out = Flagged {
        vertices: Vec::with_capacity(n + 1),
        flags: Vec::with_capacity(n + 1),
    };
    for i in 0..n {
        let j = (i + 1) % n;
        let (a, b) = (p.vertices[i], p.vertices[j]);
        let (da, db) = (d[i] * sign, d[j] * sign);
        let leaving = da > eps && db < -eps;
        let entering = da < -eps && db > eps;
        if da >= -eps {
            let along_edge = db >= -eps || leaving;
            out.vertices.push(a);
            out.flags.push(along_edge && p.flags[i]);
        }
        if leaving || entering {
            out.vertices.push(a + (b - a) * (d[i] / (d[i] - d[j])));
            out.flags.push(entering && p.flags[i]);
        }
    }
    if out.vertices.len() < 3 {
        return None;
    }
    let m = out.vertices.len();
    for i in 0..m {
        let (a, b) = (out.vertices[i], out.vertices[(i + 1) % m]);
        if on_or_outside(plane.signed_distance(a), sign, eps)
            && on_or_outside(plane.signed_distance(b), sign, eps)
        {
            out.flags[i] = true;
        }
    }
    Some(out)
}

/// The polygon with every edge that lies on `plane` (distances `d`), on or
/// outside side `sign`, flagged.
fn flag_on_plane(p: &Flagged, d: &[f64], sign: f64, eps: f64) -> Flagged {
    let n = p.vertices.len();
    let mut out = p.clone();
    for i in 0..n {
        if on_or_outside(d[i], sign, eps) && on_or_outside(d[(i + 1) % n], sign, eps) {
            out.flags[i] = true;
        }
    }
    out
}

/// Whether a point at distance `d` lies on the plane or outside the cell on
/// side `sign`, up to rounding. Only then may its edge go without a shadow
/// plane of its own: the path's plane bounds the cell at least as tightly.
/// An edge even slightly inside the cell keeps its own plane.
fn on_or_outside(d: f64, sign: f64, eps: f64) -> bool {
    d * sign <= ON_PLANE_SHARE * eps
}

/// A stack of node indices on the call stack, spilling to the heap only
/// past 64 entries.
struct SmallStack {
    inline: [u32; 64],
    len: usize,
    spill: Vec<u32>,
}

impl SmallStack {
    fn new() -> Self {
        SmallStack {
            inline: [0; 64],
            len: 0,
            spill: Vec::new(),
        }
    }

    fn push(&mut self, v: u32) {
        if self.len < self.inline.len() {
            self.inline[self.len] = v;
            self.len += 1;
        } else {
            self.spill.push(v);
        }
    }

    fn pop(&mut self) -> Option<u32> {
        if let Some(v) = self.spill.pop() {
            return Some(v);
        }
        (self.len > 0).then(|| {
            self.len -= 1;
            self.inline[self.len]
        })
    }
}
