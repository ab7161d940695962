//! Hierarchical occlusion culling over the kd-tree (Bittner et al. §5.3–5.4),
//! shared by every object-space occlusion method.
//!
//! From the root down: a node outside the frustum is dropped; a node whose
//! cost (triangles below it) is under `min_cost` is not worth an occlusion
//! test and counts as fully visible; a node marked partially visible last
//! frame is not tested again but opened (temporal coherence); any other node
//! is classified by the method's occlusion test. Invisible: dropped. Fully
//! visible: its objects are finished by frustum culling alone. Partially
//! visible: an inner node is opened; in a leaf each object's part inside the
//! leaf is frustum-tested and then occlusion-tested on its own.
//!
//! Marks follow §5.4: an inner node found partially visible is marked; a
//! node whose visibility is found unambiguous unmarks its parent; leaves are
//! never marked.

use super::Visibility;
use crate::cull::subtree::frustum_cull_subtree;
use crate::cull::{CullCounters, InFrustum, Occludees, View, VisibleSet};
use crate::geom::{ALL_PLANES, Aabb, PlaneMask, Side};
use crate::scene::Scene;
use crate::spatial::{KdTree, NodeKind};

/// What an occlusion test is asked about, so a method can cache per target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Target {
    /// A kd node (its `bounds`).
    Node(u32),
    /// The part of an object inside a leaf's cell.
    Object(u32),
    /// A dynamic occludee (its index in the frame's list).
    Dynamic(u32),
}

/// Per kd node, what its occlusion test this frame leaves for the tests
/// below it, stamped with the frame that wrote it.
///
/// A node's bounds hold its children's and its leaves' object parts, and
/// a box's signed-distance range to a plane only narrows as the box
/// shrinks, rounding included ([`crate::geom::Plane::box_range`]). So what
/// a test found of a box through such ranges (the shadows it is clear of,
/// the planes its search passes on one side) holds for every box inside
/// it: a node starts from its nearest ancestor tested this frame (the
/// traversal may open a marked node untested).
#[derive(Default)]
pub(crate) struct AncestorNotes<T> {
    frame: u32,
    nodes: Vec<(u32, T)>,
}

impl<T: Copy + Default> AncestorNotes<T> {
    /// Forgets the last frame's notes, for a tree of `nodes` nodes.
    pub(crate) fn start_frame(&mut self, nodes: usize) {
        self.frame = self.frame.wrapping_add(1);
        self.nodes.resize(nodes, (0, T::default()));
        if self.frame == 0 {
            self.nodes.fill((0, T::default()));
            self.frame = 1;
        }
    }

    /// The note of node `n`'s nearest ancestor tested this frame.
    pub(crate) fn nearest(&self, parents: &[u32], n: u32) -> Option<T> {
        let mut at = parents[n as usize];
        while at != u32::MAX {
            let (frame, note) = self.nodes[at as usize];
            if frame == self.frame {
                return Some(note);
            }
            at = parents[at as usize];
        }
        None
    }

    /// Leaves `note` for the nodes below `n`.
    pub(crate) fn set(&mut self, n: u32, note: T) {
        self.nodes[n as usize] = (self.frame, note);
    }

    /// Bytes held on the heap.
    pub(crate) fn heap_bytes(&self) -> usize {
        self.nodes.capacity() * std::mem::size_of::<(u32, T)>()
    }
}

/// Tests dynamic occludees (avatars) with a method's occlusion `test` once
/// the hierarchy is culled: those in the frustum that the test finds
/// invisible are hidden. Occluders are real surfaces, so the test holds
/// whatever order boxes are asked in.
pub(crate) fn test_occludees(
    occludees: &mut Occludees,
    test: &mut dyn FnMut(Target, &Aabb) -> Visibility,
) {
    for i in 0..occludees.boxes().len() {
        let b = occludees.boxes()[i];
        if occludees.visible()[i] && test(Target::Dynamic(i as u32), &b) == Visibility::Invisible {
            occludees.hide(i);
        }
    }
}

/// Knobs of the traversal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct HierarchyParams {
    /// Nodes with fewer triangles below them are not occlusion-tested.
    pub min_cost: u64,
    /// Whether to skip the test of inner nodes marked last frame.
    pub temporal: bool,
}

/// Culls `view` over `tree`, asking `test` about nodes and objects.
/// `marks` holds one flag per kd node and carries across frames;
/// `visible_leaves` receives the leaves found not invisible.
#[allow(clippy::too_many_arguments)]
pub(crate) fn cull(
    tree: &KdTree,
    scene: &Scene,
    view: &View,
    params: HierarchyParams,
    marks: &mut Vec<bool>,
    test: &mut dyn FnMut(Target, &Aabb) -> Visibility,
    out: &mut VisibleSet,
    visible_leaves: &mut Vec<u32>,
) -> CullCounters {
    let nodes = tree.nodes();
    marks.resize(nodes.len(), false);
    let mut tested = 0u64;
    if nodes.is_empty() {
        return CullCounters {
            nodes_tested: 0,
            in_frustum: InFrustum::Counted(0),
        };
    }
    const NONE: u32 = u32::MAX;
    let mut stack: Vec<(u32, PlaneMask, u32)> = vec![(0, ALL_PLANES, NONE)];
    let unmark = |marks: &mut Vec<bool>, parent: u32| {
        if parent != NONE {
            marks[parent as usize] = false;
        }
    };
    while let Some((i, mask, parent)) = stack.pop() {
        let node = &nodes[i as usize];
        tested += 1;
        let (side, mask) = view.frustum().classify(&node.bounds, mask);
        if side == Side::Outside {
            marks[i as usize] = false;
            unmark(marks, parent);
            continue;
        }
        let inner = node.kind != NodeKind::Leaf;
        let visibility = if node.cost < params.min_cost {
            Visibility::Full
        } else if params.temporal && inner && marks[i as usize] {
            Visibility::Partial
        } else {
            test(Target::Node(i), &node.bounds)
        };
        match visibility {
            Visibility::Invisible => {
                marks[i as usize] = false;
                unmark(marks, parent);
            }
            Visibility::Full => {
                marks[i as usize] = false;
                unmark(marks, parent);
                tested += frustum_cull_subtree(
                    tree,
                    scene,
                    view.frustum(),
                    i,
                    mask,
                    out,
                    Some(visible_leaves),
                );
            }
            Visibility::Partial => match node.kind {
                NodeKind::Inner { children, .. } => {
                    marks[i as usize] = true;
                    stack.push((children[1], mask, i));
                    stack.push((children[0], mask, i));
                }
                NodeKind::Leaf => {
                    marks[i as usize] = false;
                    visible_leaves.push(i);
                    for &id in tree.node_refs(node) {
                        if out.contains(id) {
                            // Accepted through another leaf: no test can
                            // take it back.
                            continue;
                        }
                        let part = scene.objects()[id as usize].bounds.clipped(&node.cell);
                        if view.frustum().classify_exact(&part, mask).0 != Side::Outside
                            && test(Target::Object(id), &part) != Visibility::Invisible
                        {
                            out.push(id);
                        }
                    }
                }
            },
        }
    }
    CullCounters {
        nodes_tested: tested,
        in_frustum: InFrustum::Unknown,
    }
}
