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

use crate::cull::{
    CullCounters, CullMethod, InFrustum, MethodError, MethodOptions, View, VisibleSet,
};
use crate::geom::{ALL_PLANES, Frustum, PlaneMask, Side};
use crate::scene::Scene;
use crate::spatial::{KdTree, NodeKind};

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

    fn is_cheap(&self) -> bool {
        true
    }

    fn cull(&self, view: &View, _: &mut (), out: &mut VisibleSet) -> CullCounters {
        if self.tree.nodes().is_empty() {
            return CullCounters::default();
        }
        let tested = cull_subtree(
            &self.tree,
            &self.scene,
            &view.frustum,
            0,
            ALL_PLANES,
            out,
            None,
        );
        CullCounters {
            nodes_tested: tested,
            in_frustum: InFrustum::Answer,
        }
    }
}

/// Frustum culling of the subtree under `root`, whose ancestors left the
/// planes in `mask` to test; adds every object whose box touches the frustum
/// and, when asked, the leaves reached. Returns the nodes tested. Occlusion
/// methods finish a subtree they found fully visible with it.
pub(crate) fn cull_subtree(
    tree: &KdTree,
    scene: &Scene,
    frustum: &Frustum,
    root: u32,
    mask: PlaneMask,
    out: &mut VisibleSet,
    mut leaves: Option<&mut Vec<u32>>,
) -> u64 {
    let (nodes, objects) = (tree.nodes(), scene.objects());
    let mut tested = 0u64;
    // Depth is bounded by the build's limit, so the stack stays small.
    let mut stack: Vec<(u32, PlaneMask)> = Vec::with_capacity(64);
    stack.push((root, mask));
    while let Some((i, mask)) = stack.pop() {
        let node = &nodes[i as usize];
        tested += 1;
        let (side, mask) = frustum.classify(&node.bounds, mask);
        if side != Side::Outside && node.kind == NodeKind::Leaf {
            if let Some(l) = leaves.as_deref_mut() {
                l.push(i);
            }
        }
        match (side, node.kind) {
            (Side::Outside, _) => {}
            (Side::Inside, NodeKind::Leaf) => out.extend_from_slice(tree.node_refs(node)),
            (Side::Inside, NodeKind::Inner { .. }) if leaves.is_none() => {
                out.extend_from_slice(tree.node_refs(node))
            }
            (_, NodeKind::Inner { children, .. }) => {
                stack.push((children[1], mask));
                stack.push((children[0], mask));
            }
            (Side::Intersecting, NodeKind::Leaf) => {
                for &id in tree.node_refs(node) {
                    if out.contains(id) {
                        // Accepted through another leaf (a ground is in most).
                        continue;
                    }
                    // Only the part inside this leaf's cell: the rest of the
                    // box lies in other leaves, which test their own part.
                    let part = objects[id as usize].bounds.clipped(&node.cell);
                    if frustum.classify_exact(&part, mask).0 != Side::Outside {
                        out.push(id);
                    }
                }
            }
        }
    }
    tested
}
