//! `supporting_planes`: occlusion culling with large occluders after Coorg &
//! Teller (I3D 1997).
//!
//! A box is hidden by a convex occluder exactly when the eye lies beyond all
//! *supporting planes* of the pair (planes through an occluder edge and a box
//! corner with both on one side); it is fully clear of it when the eye lies
//! beyond a *separating plane* (occluder and box on opposite sides). We test
//! the equivalent form that needs no plane per (box, occluder) pair: the box
//! lies inside the occluder's shadow (behind its plane, inside the plane
//! through the eye and each edge), or outside it (in front of its plane, or
//! outside one edge plane). Two occluders sharing an edge that is not on the
//! silhouette from the eye hide together what neither hides alone: the box is
//! split by the plane through the eye and the shared edge, and each half
//! must lie in its own occluder's shadow, that plane ignored.
//!
//! Occluders are picked per view by area-angle as for `occlusion_tree`; the
//! kd-tree is traversed by [`super::occlusion::hierarchy`]. The temporal cache keeps,
//! per kd node, the occluder that hid it last frame and tries it first.
//! Every object is tested with its whole box (its part in a leaf), never
//! from its centre only.

use rustc_hash::FxHashMap;
use std::sync::Arc;

use glam::DVec3;

use super::occlusion::hierarchy::{AncestorNotes, Target};
use super::occlusion::tolerance::{plane_tolerance, too_small_to_trust};
use super::occlusion::{OccluderScene, Selection, SelectionOptions, Visibility, visible_parts};
use super::{
    CullCounters, CullError, CullMethod, Culler, MethodEntry, MethodError, MethodOptions,
    Occludees, Preparation, View, VisibleSet,
};
use crate::geom::{Aabb, ConvexPolygon, Plane};

/// The method's registry entry.
pub const ENTRY: MethodEntry = MethodEntry {
    name: "supporting_planes",
    purpose: "supporting and separating planes against large occluders, cached between frames (Coorg & Teller)",
    options: &SelectionOptions::KEYS,
    checked_with: &["k=8:temporal=false:min_cost=0"],
    regions: None,
    build,
};

fn build(p: &Preparation<'_>) -> Result<Arc<dyn Culler>, String> {
    Ok(Arc::new(SupportingPlanesCulling::new(
        OccluderScene::prepared(p)?,
    )))
}

/// Supporting and separating planes against the selected occluders.
pub struct SupportingPlanesCulling {
    world: OccluderScene,
    /// Per occluder: the occluders it shares an edge with, and that edge.
    neighbours: Vec<Vec<(u32, [DVec3; 2])>>,
}

/// A client's state: options, marks, next occluders, and per kd node the
/// occluder that hid it last frame.
pub struct SupportingPlanesState {
    selection: Selection,
    hidden_by: FxHashMap<u32, u32>,
    /// Per kd node tested this frame, the shadows (bit i: the frame's
    /// i-th, up to 64) its bounds were found not clear of: a shadow an
    /// ancestor is clear of is one every box below is clear of, so those
    /// below test only the rest ([`AncestorNotes`]). The answers are the
    /// same as testing every shadow, in less time.
    masks: AncestorNotes<u64>,
}

/// One occluder seen from this frame's eye.
struct Shadow {
    index: u32,
    /// The occluder's plane, eye on the positive side.
    plane: Plane,
    /// Planes through the eye and each edge, the occluder on the negative side.
    edges: Vec<Plane>,
    /// The edges' end points, to find the shared one of a pair.
    corners: Vec<DVec3>,
}

impl SupportingPlanesCulling {
    /// The method over the scene's occluders.
    fn new(world: OccluderScene) -> Self {
        let occluders = &world.occluders;
        let key = |v: DVec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
        let mut by_edge: FxHashMap<([u64; 3], [u64; 3]), Vec<u32>> = FxHashMap::default();
        for (i, o) in occluders.all().iter().enumerate() {
            let v = &o.polygon.vertices;
            for e in 0..v.len() {
                let (a, b) = (key(v[e]), key(v[(e + 1) % v.len()]));
                by_edge
                    .entry(if a < b { (a, b) } else { (b, a) })
                    .or_default()
                    .push(i as u32);
            }
        }
        let mut neighbours = vec![Vec::new(); occluders.all().len()];
        for (i, o) in occluders.all().iter().enumerate() {
            let v = &o.polygon.vertices;
            for e in 0..v.len() {
                let (a, b) = (v[e], v[(e + 1) % v.len()]);
                let (ka, kb) = (key(a), key(b));
                for &j in &by_edge[&if ka < kb { (ka, kb) } else { (kb, ka) }] {
                    if j as usize != i {
                        neighbours[i].push((j, [a, b]));
                    }
                }
            }
        }
        SupportingPlanesCulling { world, neighbours }
    }

    /// The shadow of `part`, the visible part of occluder `index`.
    fn shadow(&self, index: u32, part: &ConvexPolygon, eye: DVec3, eps: f64) -> Option<Shadow> {
        let o = &self.world.occluders.all()[index as usize];
        let side = o.plane.signed_distance(eye);
        if side.abs() <= eps {
            return None;
        }
        let plane = if side > 0.0 {
            o.plane
        } else {
            o.plane.flipped()
        };
        let v = &part.vertices;
        if too_small_to_trust(v, eps) {
            return None;
        }
        let inner = part.centroid();
        let edges = (0..v.len())
            .map(|e| {
                let p =
                    Plane::from_point_normal(eye, (v[e] - eye).cross(v[(e + 1) % v.len()] - v[e]))?;
                Some(if p.signed_distance(inner) > 0.0 {
                    p.flipped()
                } else {
                    p
                })
            })
            .collect::<Option<Vec<_>>>()?;
        Some(Shadow {
            index,
            plane,
            edges,
            corners: v.clone(),
        })
    }
}

/// The index of the edge of `corners` joining `a` and `b`, either way round.
fn edge_index(corners: &[DVec3], a: DVec3, b: DVec3) -> Option<usize> {
    let n = corners.len();
    (0..n).find(|&e| {
        let (p, q) = (corners[e], corners[(e + 1) % n]);
        (p == a && q == b) || (p == b && q == a)
    })
}

/// Smallest and largest signed distance of a set of points to a plane.
fn range(plane: &Plane, pts: &[DVec3]) -> (f64, f64) {
    pts.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
            let d = plane.signed_distance(*p);
            (l.min(d), h.max(d))
        })
}

/// Whether every point lies inside the shadow, `skip` (a shared edge's
/// plane) not counted.
fn inside(s: &Shadow, pts: &[DVec3], skip: Option<usize>, eps: f64) -> bool {
    !pts.is_empty()
        && range(&s.plane, pts).1 < -eps
        && s.edges
            .iter()
            .enumerate()
            .all(|(e, p)| Some(e) == skip || range(p, pts).1 < -eps)
}

/// Where a box lies with respect to one shadow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Placement {
    /// Behind the occluder's plane and inside every edge plane: hidden.
    Inside,
    /// In front of the occluder's plane or outside an edge plane: clear of
    /// the occluder.
    Clear,
    /// Neither, as far as these planes tell.
    Across,
}

/// The box's [`Placement`], from two corners a plane, each plane's far
/// corner computed only while the box may still be inside. An empty box is
/// clear of everything.
fn place(s: &Shadow, b: &Aabb, eps: f64) -> Placement {
    let (lo, hi) = s.plane.box_range(b);
    if lo > eps {
        return Placement::Clear;
    }
    let mut inside = hi < -eps;
    for p in &s.edges {
        if inside {
            let (lo, hi) = p.box_range(b);
            if lo > eps {
                return Placement::Clear;
            }
            inside = hi < -eps;
        } else if p.box_min(b) > eps {
            return Placement::Clear;
        }
    }
    if inside {
        Placement::Inside
    } else {
        Placement::Across
    }
}

/// The points spanning the part of a box on one side of a plane: its
/// corners there and where its edges cross the plane, at most 8 + 12.
/// Kept on the stack: it is formed for every pair a box is tested against,
/// and the `Vec` it was had the allocator as the method's largest cost.
struct BoxPart {
    points: [DVec3; 20],
    len: usize,
}

impl BoxPart {
    /// The part of the box with `corners` on the negative side of `plane`.
    fn clipped(corners: &[DVec3; 8], plane: &Plane) -> BoxPart {
        let d = corners.map(|c| plane.signed_distance(c));
        let mut part = BoxPart {
            points: [DVec3::ZERO; 20],
            len: 0,
        };
        for (&c, &dc) in corners.iter().zip(&d) {
            if dc <= 0.0 {
                part.push(c);
            }
        }
        for i in 0..8 {
            for bit in [1, 2, 4] {
                let j = i | bit;
                if j != i && (d[i] < 0.0) != (d[j] < 0.0) && d[i] != d[j] {
                    part.push(corners[i] + (corners[j] - corners[i]) * (d[i] / (d[i] - d[j])));
                }
            }
        }
        part
    }

    fn push(&mut self, p: DVec3) {
        self.points[self.len] = p;
        self.len += 1;
    }

    fn points(&self) -> &[DVec3] {
        &self.points[..self.len]
    }
}

impl CullMethod for SupportingPlanesCulling {
    type State = SupportingPlanesState;

    fn name(&self) -> &'static str {
        "supporting_planes"
    }

    fn new_state(&self, options: &MethodOptions) -> Result<Self::State, MethodError> {
        let r = options.reader("supporting_planes", &SelectionOptions::KEYS);
        let selection = Selection::new(SelectionOptions::read(&r)?);
        r.finish()?;
        Ok(SupportingPlanesState {
            selection,
            hidden_by: FxHashMap::default(),
            masks: AncestorNotes::default(),
        })
    }

    fn is_conservative(&self, _: &Self::State) -> bool {
        true
    }

    fn cull(
        &self,
        view: &View,
        state: &mut Self::State,
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        let eye = view.eye();
        let eps = plane_tolerance(&self.world.scene, eye);
        let picked = state.selection.occluders_for(&self.world, view);
        // Only what lies beyond the near plane can hide anything.
        let shadows: Vec<Shadow> = visible_parts(&self.world.occluders, picked, view, eps)
            .iter()
            .filter_map(|(i, part)| self.shadow(*i, part, eye, eps))
            .collect();
        let slot: FxHashMap<u32, usize> = shadows
            .iter()
            .enumerate()
            .map(|(s, sh)| (sh.index, s))
            .collect();
        // Connected pairs among the picked: the shared edge's plane must have
        // the two occluders on opposite sides (not a silhouette edge).
        let mut pairs: Vec<(usize, usize, usize, usize, Plane)> = Vec::new();
        for (s, sh) in shadows.iter().enumerate() {
            for &(j, [a, b]) in &self.neighbours[sh.index as usize] {
                let Some(&t) = slot.get(&j) else { continue };
                if t <= s {
                    continue;
                }
                let (Some(ea), Some(eb)) = (
                    edge_index(&sh.corners, a, b),
                    edge_index(&shadows[t].corners, a, b),
                ) else {
                    continue;
                };
                let Some(cut) = Plane::from_point_normal(eye, (a - eye).cross(b - eye)) else {
                    continue;
                };
                // Orient the plane with `sh` behind it; the pair hides jointly
                // only if the other occluder lies in front (the shared edge is
                // then not on the silhouette).
                let (lo, hi) = range(&cut, &sh.corners);
                let cut = if hi <= eps {
                    cut
                } else if lo >= -eps {
                    cut.flipped()
                } else {
                    continue;
                };
                if range(&cut, &shadows[t].corners).0 >= -eps {
                    pairs.push((s, ea, t, eb, cut));
                }
            }
        }
        let hidden_by = &mut state.hidden_by;
        let masks = &mut state.masks;
        masks.start_frame(self.world.parents.len());
        // With more shadows than bits, every box tests them all.
        let masked = shadows.len() <= 64;
        let all = if shadows.len() >= 64 {
            u64::MAX
        } else {
            (1u64 << shadows.len()) - 1
        };
        // Objects are tested right after their leaf: they start from its mask.
        let mut leaf_mask = all;
        let mut clear: Vec<bool> = Vec::with_capacity(shadows.len());
        let mut test = |target: Target, b: &Aabb| {
            if let Target::Node(n) = target {
                if let Some(&s) = hidden_by.get(&n).and_then(|o| slot.get(o)) {
                    if place(&shadows[s], b, eps) == Placement::Inside {
                        return Visibility::Invisible;
                    }
                }
            }
            let active = match target {
                Target::Node(n) if masked => masks.nearest(&self.world.parents, n).unwrap_or(all),
                Target::Object(_) if masked => leaf_mask,
                _ => all,
            };
            // Which shadows the box is wholly clear of: all of them is "fully
            // visible"; a pair with one of them cannot hide the box either
            // (its part on that side would have to be in that shadow).
            clear.clear();
            let mut across = 0u64;
            for (i, s) in shadows.iter().enumerate() {
                let placement = if !masked || active & (1 << i) != 0 {
                    place(s, b, eps)
                } else {
                    Placement::Clear
                };
                match placement {
                    Placement::Inside => {
                        if let Target::Node(n) = target {
                            hidden_by.insert(n, s.index);
                        }
                        return Visibility::Invisible;
                    }
                    Placement::Clear => clear.push(true),
                    Placement::Across => {
                        clear.push(false);
                        across |= 1u64.checked_shl(i as u32).unwrap_or(0);
                    }
                }
            }
            if let Target::Node(n) = target {
                masks.set(n, across);
                leaf_mask = across;
            }
            if clear.iter().all(|&c| c) {
                return Visibility::Full;
            }
            let corners = b.corners().map(|c| c.as_dvec3());
            for &(s, ea, t, eb, cut) in &pairs {
                if clear[s] || clear[t] {
                    continue;
                }
                // The box's part on each occluder's side of the shared edge's
                // plane must be in that occluder's shadow.
                let near = BoxPart::clipped(&corners, &cut);
                if inside(&shadows[s], near.points(), Some(ea), eps)
                    && inside(
                        &shadows[t],
                        BoxPart::clipped(&corners, &cut.flipped()).points(),
                        Some(eb),
                        eps,
                    )
                {
                    return Visibility::Invisible;
                }
            }
            Visibility::Partial
        };
        Ok(state
            .selection
            .cull(&self.world, view, &mut test, out, occludees))
    }

    fn state_bytes(&self, state: &Self::State) -> usize {
        std::mem::size_of::<Self::State>()
            + state.selection.heap_bytes()
            + state.hidden_by.capacity() * 3 * std::mem::size_of::<u32>()
            + state.masks.heap_bytes()
    }
}
