//! `frustum`: hierarchical view-frustum culling over the kd-tree with plane
//! masks (Bittner et al. §5.3, the "F" method of their Table 2, and the
//! reference every other method is compared against).
//!
//! Each node's `bounds` (the boxes below it clipped to its cell) is tested
//! against the planes still in the mask. A node outside one plane is dropped
//! with its subtree; a plane it lies inside is dropped from the mask for its
//! subtree; a node inside every plane has all its objects accepted untested
//! (each has a part inside the frustum). In a leaf, the part of each
//! object's box inside the leaf's cell gets the exact test
//! ([`Frustum::classify_exact`]). Every point of an object's box lies in
//! such a part, so this returns exactly the objects whose box touches the
//! frustum: the brute-force answer [`FrustumCulling::reference`] gives.

use std::sync::Arc;

use super::subtree::frustum_cull_subtree;
use super::{
    CullCounters, CullError, CullMethod, Culler, Execution, InFrustum, MethodEntry, MethodError,
    MethodOptions, Occludees, Preparation, View, VisibleSet,
};
use crate::geom::{ALL_PLANES, Frustum};
use crate::scene::Scene;
use crate::spatial::KdTree;

/// The method's registry entry.
pub const ENTRY: MethodEntry = MethodEntry {
    name: "frustum",
    purpose: "view-frustum culling over the kd-tree; the exact in-frustum set, and the fallback of every other method",
    options: &[],
    checked_with: &[],
    regions: None,
    build,
};

fn build(p: &Preparation<'_>) -> Result<Arc<dyn Culler>, String> {
    Ok(Arc::new(FrustumCulling::new(
        p.scene().clone(),
        p.kd_tree(),
    )))
}

/// Hierarchical frustum culling; stateless, conservative, no options.
pub struct FrustumCulling {
    scene: Arc<Scene>,
    tree: Arc<KdTree>,
}

impl FrustumCulling {
    /// The method over `tree`, which must be built over `scene`.
    pub fn new(scene: Arc<Scene>, tree: Arc<KdTree>) -> Self {
        FrustumCulling { scene, tree }
    }

    /// Brute force: every object whose box touches the frustum
    /// ([`Frustum::intersects`]), ascending. Tests compare the hierarchical
    /// answer with it.
    pub fn reference(scene: &Scene, frustum: &Frustum) -> Vec<u32> {
        scene
            .objects()
            .iter()
            .filter(|o| frustum.intersects(&o.bounds))
            .map(|o| o.id)
            .collect()
    }
}

impl CullMethod for FrustumCulling {
    type State = ();

    fn name(&self) -> &'static str {
        "frustum"
    }

    fn new_state(&self, options: &MethodOptions) -> Result<(), MethodError> {
        options.reader("frustum", &[]).finish()
    }

    fn is_conservative(&self, _: &()) -> bool {
        true
    }

    /// Microseconds a view: less than handing it to another thread.
    fn execution(&self) -> Execution {
        Execution::Inline
    }

    /// Occludees keep the frustum's answer they arrive with.
    fn cull(
        &self,
        view: &View,
        _: &mut (),
        out: &mut VisibleSet,
        _: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        if self.tree.nodes().is_empty() {
            return Ok(CullCounters::default());
        }
        let tested = frustum_cull_subtree(
            &self.tree,
            &self.scene,
            view.frustum(),
            0,
            ALL_PLANES,
            out,
            None,
        );
        Ok(CullCounters {
            nodes_tested: tested,
            in_frustum: InFrustum::Answer,
        })
    }
}
