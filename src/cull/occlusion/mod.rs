//! What the object-space occlusion methods share (`occlusion_tree`,
//! `supporting_planes`, and the coming `ddo`): the visibility classes of
//! Bittner et al. (Table 1), per-view occluder selection (§3), the
//! hierarchical traversal of the kd-tree (§5.3–5.4), and the tolerances
//! their conservativeness rests on. A method uses these; no method imports
//! from another method's folder.

pub(crate) mod hierarchy;
mod selection;
pub mod tolerance;

pub(crate) use selection::{Selection, SelectionOptions};

use std::sync::Arc;

use super::occluder::Occluders;
use super::{Preparation, View};
use crate::geom::{ConvexPolygon, Plane};
use crate::scene::Scene;
use crate::spatial::{KdTree, NodeKind};

/// What an object-space occlusion method culls over: the scene, its
/// kd-tree and its large planar occluders, shared with every other method
/// of the scene.
pub(crate) struct OccluderScene {
    pub scene: Arc<Scene>,
    pub tree: Arc<KdTree>,
    pub occluders: Arc<Occluders>,
    /// Per kd node, its parent (`u32::MAX` for the root): where
    /// [`hierarchy::AncestorNotes`] look up what a node's ancestors found.
    pub parents: Vec<u32>,
}

impl OccluderScene {
    /// The scene's, from its preparation; the reason when it has no
    /// occluders large enough to be worth testing against.
    pub(crate) fn prepared(p: &Preparation<'_>) -> Result<OccluderScene, String> {
        let tree = p.kd_tree();
        let mut parents = vec![u32::MAX; tree.nodes().len()];
        for (i, node) in tree.nodes().iter().enumerate() {
            if let NodeKind::Inner { children, .. } = node.kind {
                for c in children {
                    parents[c as usize] = i as u32;
                }
            }
        }
        Ok(OccluderScene {
            scene: p.scene().clone(),
            tree,
            occluders: p.require_occluders()?,
            parents,
        })
    }
}

/// Visibility of a region or polygon with respect to a view's occluders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Visibility {
    /// Hidden by the occluders.
    Invisible,
    /// Partly hidden, partly not (or not known to be either).
    Partial,
    /// Not hidden at all.
    Full,
}

impl Visibility {
    /// The visibility of a union (Table 1).
    pub fn combine(self, other: Visibility) -> Visibility {
        if self == other {
            self
        } else {
            Visibility::Partial
        }
    }
}

/// The parts of occluders that can hide anything in this view: what lies
/// beyond the near plane (by `eps`, so rounding only shrinks them). Nearer
/// than the near plane nothing is drawn, so nothing there hides anything.
///
/// For a region view ([`crate::geom::Region`]) each part is also shrunk so
/// that what it hides from the region's centre is hidden by the whole
/// occluder from every eye of the region ([`shrunk_for_region`]).
pub(crate) fn visible_parts(
    occluders: &Occluders,
    picked: impl IntoIterator<Item = u32>,
    view: &View,
    eps: f64,
) -> Vec<(u32, ConvexPolygon)> {
    if !view.region().is_point() {
        return picked
            .into_iter()
            .filter_map(|i| {
                let polygon = &occluders.all()[i as usize].polygon;
                Some((i, shrunk_for_region(polygon, view, eps)?))
            })
            .collect();
    }
    let near = view.frustum().planes()[0];
    let beyond = Plane {
        normal: near.normal,
        d: near.d - eps,
    };
    picked
        .into_iter()
        .filter_map(|i| {
            Some((
                i,
                occluders.all()[i as usize].polygon.clipped(&beyond, 0.0)?,
            ))
        })
        .collect()
}

/// The part of an occluder that hides from a region's centre `c` only what
/// the whole occluder hides from every eye of the region (Wonka et al.
/// 2000's occluder shrinking, made exact for a planar polygon):
///
/// 1. **Near.** A point `q` of the occluder is drawn from an eye `c'` of
///    the ball, on a ray of its frustum, when `|q − c'| ≥ near · L` with
///    `L = √(1 + tan²θx + tan²θy)` (a ray of the frustum makes at most the
///    corner angle with its axis, whatever the rotation). Keeping only the
///    part with `f · (q − c) ≥ r + near · L` (`f` the centre's forward)
///    keeps only points drawn from every eye.
/// 2. **Shrink.** Let the part lie at distance `h > r` from `c` (the ball
///    on one side) and within `D` of `c`. Where the ray from an eye `e` to
///    a point `p` behind the plane crosses it moves, as `e` moves by `v`,
///    by at most `|v| / cos α`, `α` the ray's angle to the normal; while
///    the crossing is on the part, `cos α ≥ (h − r) / (D + r)`. So moving
///    the eye from `c` anywhere in the ball moves the crossing by at most
///    `δ = r (D + r) / (h − r)`, and a crossing `δ` inside the part's edges
///    stays on it: the part inset by `δ` hides from `c` only points hidden
///    from the whole ball. A part with `h ≤ r` (the ball touches its
///    plane) is dropped.
///
/// The `angle` needs nothing here: what a point eye's occluder hides does
/// not depend on where it looks. Every bound is rounded outwards by `eps`.
pub(crate) fn shrunk_for_region(
    polygon: &ConvexPolygon,
    view: &View,
    eps: f64,
) -> Option<ConvexPolygon> {
    let (c, f) = (view.eye(), view.basis().forward);
    let r = view.region().radius();
    let camera = view.camera();
    let (tx, ty) = camera.half_tangents();
    let reach = r + camera.near * (1.0 + tx * tx + ty * ty).sqrt();
    let beyond = Plane {
        normal: f,
        d: -f.dot(c) - reach - eps,
    };
    let part = polygon.clipped(&beyond, 0.0)?;
    if r == 0.0 {
        return Some(part);
    }
    let h = part.plane()?.signed_distance(c).abs();
    if h <= r + eps {
        return None;
    }
    let d = part
        .vertices
        .iter()
        .map(|v| v.distance(c))
        .fold(0.0, f64::max);
    let by = r * (d + r) / (h - r - eps) * (1.0 + 1e-9) + eps;
    part.inset(by)
}
