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
use crate::spatial::KdTree;

/// What an object-space occlusion method culls over: the scene, its
/// kd-tree and its large planar occluders, shared with every other method
/// of the scene.
pub(crate) struct OccluderScene {
    pub scene: Arc<Scene>,
    pub tree: Arc<KdTree>,
    pub occluders: Arc<Occluders>,
}

impl OccluderScene {
    /// The scene's, from its preparation; the reason when it has no
    /// occluders large enough to be worth testing against.
    pub(crate) fn prepared(p: &Preparation<'_>) -> Result<OccluderScene, String> {
        Ok(OccluderScene {
            scene: p.scene().clone(),
            tree: p.kd_tree(),
            occluders: p.require_occluders()?,
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
pub(crate) fn visible_parts(
    occluders: &Occluders,
    picked: impl IntoIterator<Item = u32>,
    view: &View,
    eps: f64,
) -> Vec<(u32, ConvexPolygon)> {
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
