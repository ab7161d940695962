//! Frustum culling of one kd subtree: the traversal frustum culling is
//! made of, and what the occlusion methods finish a subtree with once they
//! found it fully visible (Bittner et al. §5.3).

use super::VisibleSet;
use crate::geom::{Frustum, PlaneMask, Side};
use crate::scene::Scene;
use crate::spatial::{KdTree, NodeKind};

/// Frustum culling of the subtree under `root`, whose ancestors left the
/// planes in `mask` to test; adds every object whose box touches the frustum
/// and, when asked, the leaves reached. Returns the nodes tested. Occlusion
/// methods finish a subtree they found fully visible with it.
pub(crate) fn frustum_cull_subtree(
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
            // Each object once, not once per leaf below (a ground is in most).
            (Side::Inside, NodeKind::Inner { .. }) if leaves.is_none() => {
                out.extend_from_slice(tree.node_objects(node))
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
