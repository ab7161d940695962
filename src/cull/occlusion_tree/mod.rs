//! `occlusion_tree`: hierarchical visibility culling with occlusion trees
//! (Bittner, Havran, Slavík 1998).
//!
//! Per view: pick `k` occluders by area-angle from the kd leaves within `λ`
//! of the eye (§3; in a session, those picked from frame i's visible leaves
//! serve frame i+1, as the paper does); build the occlusion tree over them in
//! front-to-back order (§4–5, [`OcclusionTree`]); traverse the kd-tree with
//! it ([`super::hierarchy`]: node-cost threshold, temporal marks).
//!
//! Variants (Table 2; `variant=`):
//! - `fme` (default): MOBSP, region algorithm, exact in-leaf test;
//! - `fmc`: MOBSP, region algorithm, conservative in-leaf test (planes only);
//! - `fse`: OBSP, exact polygon-splitting visibility of each box's faces.
//!
//! All three are conservative: no visible object is ever dropped.

mod tree;

use std::sync::Arc;

use glam::DVec3;

pub use tree::{LeafTest, OcclusionTree, Visibility};

use super::hierarchy::{self, HierarchyParams};
use super::occluder::Occluders;
use super::{CullCounters, CullMethod, MethodError, MethodOptions, View, VisibleSet};
use crate::geom::{ALL_PLANES, Aabb, Side};
use crate::scene::Scene;
use crate::spatial::{KdTree, NodeKind};

/// Which of Table 2's methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variant {
    /// OBSP + exact (splitting) visibility.
    Fse,
    /// MOBSP + region visibility + exact in-leaf test.
    Fme,
    /// MOBSP + region visibility + conservative in-leaf test.
    Fmc,
}

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
    /// Reads `k`, `lambda`, `min_cost` and `temporal`.
    pub(crate) fn read(r: &super::OptionReader<'_>) -> Result<Self, MethodError> {
        let k: usize = r.get("k", 32, "a whole number from 1 to 1024")?;
        let lambda: f64 = r.get("lambda", 100.0, "a distance > 0")?;
        let min_cost: u64 = r.get("min_cost", 50, "a whole number of triangles")?;
        let temporal: bool = r.get("temporal", true, "true or false")?;
        let bad = |option: &str, value: String, expected: &str| MethodError::InvalidOption {
            method: r.method().into(),
            option: option.into(),
            value,
            expected: expected.into(),
        };
        if !(1..=1024).contains(&k) {
            return Err(bad("k", k.to_string(), "a whole number from 1 to 1024"));
        }
        if !(lambda > 0.0 && lambda.is_finite()) {
            return Err(bad("lambda", lambda.to_string(), "a distance > 0"));
        }
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
    pub(crate) fn occluders_for(
        &mut self,
        tree: &KdTree,
        occluders: &Occluders,
        view: &View,
    ) -> Vec<u32> {
        if let Some(next) = self.next.take() {
            return next;
        }
        let mut near = Vec::new();
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let node = &tree.nodes()[n as usize];
            if distance_to_box(view.eye, &node.cell) > self.options.lambda
                || view.frustum.classify(&node.bounds, ALL_PLANES).0 == Side::Outside
            {
                continue;
            }
            match node.kind {
                NodeKind::Leaf => near.push(n),
                NodeKind::Inner { children, .. } => stack.extend(children),
            }
        }
        self.pick(tree, occluders, view.eye, &near)
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
            if cell.center().as_dvec3().distance(eye) > lambda && distance_to_box(eye, cell) > 0.0 {
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
    /// test), then picks the next frame's occluders from the leaves it saw.
    pub(crate) fn cull(
        &mut self,
        tree: &KdTree,
        scene: &Scene,
        occluders: &Occluders,
        view: &View,
        test: &mut dyn FnMut(hierarchy::Target, &crate::geom::Aabb) -> Visibility,
        out: &mut VisibleSet,
    ) -> CullCounters {
        let counters = hierarchy::cull(
            tree,
            scene,
            view,
            self.options.hierarchy,
            &mut self.marks,
            test,
            out,
            &mut self.leaves,
        );
        self.remember(tree, occluders, view.eye);
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

/// Distance from a point to a box (0 inside).
pub(crate) fn distance_to_box(p: DVec3, b: &crate::geom::Aabb) -> f64 {
    let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
    (lo - p).max(p - hi).max(DVec3::ZERO).length()
}

/// The parts of occluders that can hide anything in this view: what lies
/// beyond the near plane (by `eps`, so rounding only shrinks them). Nearer
/// than the near plane nothing is drawn, so nothing there hides anything.
pub(crate) fn visible_parts(
    occluders: &Occluders,
    picked: impl IntoIterator<Item = u32>,
    view: &View,
    eps: f64,
) -> Vec<(u32, crate::geom::ConvexPolygon)> {
    let near = view.frustum.planes()[0];
    let beyond = crate::geom::Plane {
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

/// The rounding allowance for plane tests around `eye` in `scene`.
pub(crate) fn plane_eps(scene: &Scene, eye: DVec3) -> f64 {
    1e-9 * (scene.bounds().extent().length() as f64 + eye.length()) + 1e-12
}

/// Hierarchical culling with occlusion trees; see the module docs.
pub struct OcclusionTreeCulling {
    scene: Arc<Scene>,
    tree: Arc<KdTree>,
    occluders: Arc<Occluders>,
}

/// A client's state: options, temporal marks, next frame's occluders.
pub struct OcclusionTreeState {
    variant: Variant,
    selection: Selection,
}

impl OcclusionTreeCulling {
    /// The method over `tree` with the scene's `occluders`.
    pub fn new(scene: Arc<Scene>, tree: Arc<KdTree>, occluders: Arc<Occluders>) -> Self {
        OcclusionTreeCulling {
            scene,
            tree,
            occluders,
        }
    }
}

const OPTIONS: &[&str] = &["k", "lambda", "min_cost", "temporal", "variant"];

impl CullMethod for OcclusionTreeCulling {
    type State = OcclusionTreeState;

    fn name(&self) -> &'static str {
        "occlusion_tree"
    }

    fn new_state(&self, options: &MethodOptions) -> Result<Self::State, MethodError> {
        let r = options.reader("occlusion_tree", OPTIONS);
        let variant = match r
            .get::<String>("variant", "fme".into(), "fse, fme or fmc")?
            .as_str()
        {
            "fse" => Variant::Fse,
            "fme" => Variant::Fme,
            "fmc" => Variant::Fmc,
            other => {
                return Err(MethodError::InvalidOption {
                    method: "occlusion_tree".into(),
                    option: "variant".into(),
                    value: other.into(),
                    expected: "fse, fme or fmc".into(),
                });
            }
        };
        let selection = Selection::new(SelectionOptions::read(&r)?);
        r.finish()?;
        Ok(OcclusionTreeState { variant, selection })
    }

    fn is_conservative(&self, _: &Self::State) -> bool {
        true
    }

    fn cull(&self, view: &View, state: &mut Self::State, out: &mut VisibleSet) -> CullCounters {
        self.cull_dynamic(view, state, out, &[], &mut Vec::new())
    }

    fn cull_dynamic(
        &self,
        view: &View,
        state: &mut Self::State,
        out: &mut VisibleSet,
        dynamic: &[Aabb],
        visible: &mut Vec<bool>,
    ) -> CullCounters {
        let picked = state
            .selection
            .occluders_for(&self.tree, &self.occluders, view);
        let eye = view.eye;
        let mut order: Vec<(f64, u32)> = picked
            .iter()
            .map(|&i| {
                let p = &self.occluders.all()[i as usize].polygon;
                (
                    p.vertices
                        .iter()
                        .map(|v| v.distance_squared(eye))
                        .fold(f64::INFINITY, f64::min),
                    i,
                )
            })
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        let eps = plane_eps(&self.scene, eye);
        let polygons = visible_parts(&self.occluders, order.iter().map(|&(_, i)| i), view, eps);
        let variant = state.variant;
        let occlusion = OcclusionTree::build(
            eye,
            polygons.iter().map(|(_, p)| p),
            variant != Variant::Fse,
            eps,
        );
        let mut test = |_: hierarchy::Target, b: &Aabb| match variant {
            Variant::Fse => occlusion.box_visibility_exact(b),
            Variant::Fme => occlusion.region_visibility(b, LeafTest::Exact),
            Variant::Fmc => occlusion.region_visibility(b, LeafTest::Conservative),
        };
        let counters = state.selection.cull(
            &self.tree,
            &self.scene,
            &self.occluders,
            view,
            &mut test,
            out,
        );
        hierarchy::cull_dynamic(view, dynamic, &mut test, visible);
        counters
    }

    fn state_bytes(&self, state: &Self::State) -> usize {
        std::mem::size_of::<Self::State>() + state.selection.heap_bytes()
    }
}
