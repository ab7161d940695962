//! Occluders picked per view (Bittner et al. §3), and the per-client state
//! the object-space occlusion methods keep between frames: the options,
//! the kd nodes' temporal marks (§5.4), and the occluders picked from the
//! last frame's visible leaves for the next.

use glam::DVec3;

use super::hierarchy::{self, HierarchyParams};
use super::{OccluderScene, Visibility};
use crate::cull::occluder::Occluders;
use crate::cull::{CullCounters, MethodError, Occludees, OptionReader, Ranged, View, VisibleSet};
use crate::geom::{ALL_PLANES, Aabb, Side};
use crate::spatial::{KdTree, NodeKind};

/// Occluders per view.
pub(crate) const K: Ranged<usize> = Ranged {
    key: "k",
    noun: "a whole number",
    default: 32,
    min: 1,
    max: 1024,
};

/// Occluders come from kd leaves whose cells lie within this distance of
/// the eye (scene units).
pub(crate) const LAMBDA: Ranged<f64> = Ranged {
    key: "lambda",
    noun: "a distance",
    default: 100.0,
    min: 0.001,
    max: 1e9,
};

/// Nodes with fewer triangles below them are not occlusion-tested.
pub(crate) const MIN_COST: Ranged<u64> = Ranged {
    key: "min_cost",
    noun: "a whole number of triangles",
    default: 50,
    min: 0,
    max: 1_000_000_000,
};

/// Whether inner nodes found partially visible last frame are opened
/// without a test (§5.4).
pub(crate) const TEMPORAL: &str = "temporal";

/// Options every object-space occlusion method shares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct SelectionOptions {
    /// Occluders per view.
    pub k: usize,
    /// Occluders come from leaves whose cells lie within this distance.
    pub lambda: f64,
    /// Traversal knobs.
    pub hierarchy: HierarchyParams,
}

impl SelectionOptions {
    /// The keys [`SelectionOptions::read`] takes.
    pub(crate) const KEYS: [&'static str; 4] = [K.key, LAMBDA.key, MIN_COST.key, TEMPORAL];

    /// Reads `k`, `lambda`, `min_cost` and `temporal`.
    pub(crate) fn read(r: &OptionReader<'_>) -> Result<Self, MethodError> {
        let k = r.ranged(&K)?;
        let lambda = r.ranged(&LAMBDA)?;
        let min_cost = r.ranged(&MIN_COST)?;
        let temporal = r.flag(TEMPORAL, true)?;
        Ok(SelectionOptions {
            k,
            lambda,
            hierarchy: HierarchyParams { min_cost, temporal },
        })
    }
}

/// Per-client state shared by the occlusion methods: options, the temporal
/// marks of the kd nodes, and the occluders picked for the next frame.
#[derive(Clone, Debug)]
pub(crate) struct Selection {
    pub options: SelectionOptions,
    pub marks: Vec<bool>,
    /// Occluders picked from the last frame's visible leaves (`None` before the first frame).
    pub next: Option<Vec<u32>>,
    pub leaves: Vec<u32>,
    /// Per occluder, the last pick that counted it, so each is scored once.
    stamps: Vec<u32>,
    pick: u32,
}

impl Selection {
    /// Bytes its per-node and per-occluder vectors take on the heap.
    pub(crate) fn heap_bytes(&self) -> usize {
        self.marks.capacity()
            + (self.next.as_ref().map_or(0, Vec::capacity)
                + self.leaves.capacity()
                + self.stamps.capacity())
                * std::mem::size_of::<u32>()
    }

    pub(crate) fn new(options: SelectionOptions) -> Self {
        Selection {
            options,
            marks: Vec::new(),
            next: None,
            leaves: Vec::new(),
            stamps: Vec::new(),
            pick: 0,
        }
    }

    /// The occluders for this view: last frame's pick, or (first frame,
    /// stateless request) a pick from the leaves near the eye in the frustum.
    pub(crate) fn occluders_for(&mut self, world: &OccluderScene, view: &View) -> Vec<u32> {
        let tree = &*world.tree;
        if let Some(next) = self.next.take() {
            return next;
        }
        let mut near = Vec::new();
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let node = &tree.nodes()[n as usize];
            if node.cell.distance_to(view.eye()) > self.options.lambda
                || view.frustum().classify(&node.bounds, ALL_PLANES).0 == Side::Outside
            {
                continue;
            }
            match node.kind {
                NodeKind::Leaf => near.push(n),
                NodeKind::Inner { children, .. } => stack.extend(children),
            }
        }
        self.pick(tree, &world.occluders, view.eye(), &near)
    }

    /// §3: the k best occluders of the given leaves whose centres lie within λ.
    pub(crate) fn pick(
        &mut self,
        tree: &KdTree,
        occluders: &Occluders,
        eye: DVec3,
        leaves: &[u32],
    ) -> Vec<u32> {
        let lambda = self.options.lambda;
        self.stamps.resize(occluders.all().len(), 0);
        self.pick = self.pick.wrapping_add(1);
        if self.pick == 0 {
            self.stamps.fill(0);
            self.pick = 1;
        }
        let mut candidates = Vec::new();
        for &l in leaves {
            let cell = &tree.nodes()[l as usize].cell;
            if cell.center().as_dvec3().distance(eye) > lambda && cell.distance_to(eye) > 0.0 {
                continue;
            }
            for &o in occluders.in_leaf(l as usize) {
                if self.stamps[o as usize] != self.pick {
                    self.stamps[o as usize] = self.pick;
                    candidates.push(o);
                }
            }
        }
        let mut out = Vec::new();
        occluders.select(eye, &candidates, self.options.k, &mut out);
        out
    }

    /// Culls `view` over the kd-tree with `test` (the method's occlusion
    /// test), tests the dynamic `occludees` with it too, then picks the
    /// next frame's occluders from the leaves it saw.
    pub(crate) fn cull(
        &mut self,
        world: &OccluderScene,
        view: &View,
        test: &mut dyn FnMut(hierarchy::Target, &Aabb) -> Visibility,
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> CullCounters {
        let counters = hierarchy::cull(
            &world.tree,
            &world.scene,
            view,
            self.options.hierarchy,
            &mut self.marks,
            test,
            out,
            &mut self.leaves,
        );
        hierarchy::test_occludees(occludees, test);
        self.remember(&world.tree, &world.occluders, view.eye());
        counters
    }

    /// After a frame: pick the next frame's occluders from its visible leaves.
    pub(crate) fn remember(&mut self, tree: &KdTree, occluders: &Occluders, eye: DVec3) {
        let leaves = std::mem::take(&mut self.leaves);
        self.next = Some(self.pick(tree, occluders, eye, &leaves));
        self.leaves = leaves;
        self.leaves.clear();
    }
}
