//! `occlusion_tree`: hierarchical visibility culling with occlusion trees
//! (Bittner, Havran, Slavík 1998).
//!
//! Per view: pick `k` occluders by area-angle from the kd leaves within `λ`
//! of the eye (§3; in a session, those picked from frame i's visible leaves
//! serve frame i+1, as the paper does); build the occlusion tree over them in
//! front-to-back order (§4–5, [`OcclusionTree`]); traverse the kd-tree with
//! it ([`super::occlusion::hierarchy`]: node-cost threshold, temporal marks).
//!
//! Variants (Table 2; `variant=`):
//! - `fme` (default): MOBSP, region algorithm, exact in-leaf test;
//! - `fmc`: MOBSP, region algorithm, conservative in-leaf test (planes only);
//! - `fse`: OBSP, exact polygon-splitting visibility of each box's faces.
//!
//! All three are conservative: no visible object is ever dropped.
//!
//! `clip=true` (fme, fmc): where a region crosses a shadow plane, each side
//! gets the bounding box of the region's part there instead of the whole
//! region, so a kd node reaching past a wall into the shadow of the next
//! occluder is found hidden (the paper's Fig. 8, which it names the
//! region algorithm's imprecision). On the office random walk it takes the
//! mean PVS from 25.2 to 24.5 at ~1.4× the time; on the 1k city street
//! walk it changes nothing at ~2.8× (docs/occlusion-speed.md): off by
//! default.

mod tree;

use std::sync::Arc;

pub use tree::{Entry, LeafTest, OcclusionTree};

use super::occlusion::hierarchy::{AncestorNotes, Target};
use super::occlusion::tolerance::plane_tolerance;
use super::occlusion::{OccluderScene, Selection, SelectionOptions, visible_parts};
use super::{
    CullCounters, CullError, CullMethod, Culler, MethodEntry, MethodError, MethodOptions,
    Occludees, Preparation, View, VisibleSet,
};
use glam::DVec3;

use crate::geom::{Aabb, Plane, Region};

/// The method's registry entry; the table checks every variant and a
/// small, history-free pick.
pub const ENTRY: MethodEntry = MethodEntry {
    name: "occlusion_tree",
    purpose: "occlusion trees over k occluders picked per view (Bittner et al.): interiors and cities with large walls",
    options: &OPTIONS,
    checked_with: &[
        "variant=fse",
        "variant=fmc",
        "k=8:temporal=false:min_cost=0",
        "clip=true",
    ],
    regions: None,
    build,
};

fn build(p: &Preparation<'_>) -> Result<Arc<dyn Culler>, String> {
    Ok(Arc::new(OcclusionTreeCulling {
        world: OccluderScene::prepared(p)?,
    }))
}

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

/// Hierarchical culling with occlusion trees; see the module docs.
pub struct OcclusionTreeCulling {
    world: OccluderScene,
}

/// A client's state: options, temporal marks, next frame's occluders.
pub struct OcclusionTreeState {
    variant: Variant,
    /// Whether regions are clipped at the shadow planes they cross.
    clip: bool,
    selection: Selection,
    /// Rebuilt each frame in the same buffers.
    tree: OcclusionTree,
    /// What `tree` was built for: the eye, the near plane, the region (its
    /// occluders are shrunk for it) and the picked occluders. Shadow planes
    /// pass through the eye and occluders are cut at the near plane, so a
    /// tree serves again only a frame with all four unchanged (a camera standing still, or turning about an axis
    /// that keeps its near plane); then it is not rebuilt.
    built_for: Option<(DVec3, Plane, Region, Vec<u32>)>,
    /// Per kd node tested this frame, where its search of `tree` went both
    /// ways first: the nodes below start there ([`Entry`]).
    entries: AncestorNotes<Entry>,
}

/// The variants, in `variant=` spelling; the first is the default.
const VARIANTS: [&str; 3] = ["fme", "fmc", "fse"];

/// `clip=true`: a region crossing a shadow plane goes down each side as
/// the bounding box of its part there (the paper's Fig. 8 case answered);
/// tighter, and slower (see the module docs).
const CLIP: &str = "clip";

const OPTIONS: [&str; 6] = {
    let [k, lambda, min_cost, temporal] = SelectionOptions::KEYS;
    [k, lambda, min_cost, temporal, "variant", CLIP]
};

impl CullMethod for OcclusionTreeCulling {
    type State = OcclusionTreeState;

    fn name(&self) -> &'static str {
        "occlusion_tree"
    }

    fn new_state(&self, options: &MethodOptions) -> Result<Self::State, MethodError> {
        let r = options.reader("occlusion_tree", &OPTIONS);
        let variant = match r.choice("variant", &VARIANTS)? {
            "fse" => Variant::Fse,
            "fmc" => Variant::Fmc,
            _ => Variant::Fme,
        };
        let clip = r.flag(CLIP, false)?;
        let selection = Selection::new(SelectionOptions::read(&r)?);
        r.finish()?;
        Ok(OcclusionTreeState {
            variant,
            clip,
            selection,
            tree: OcclusionTree::default(),
            built_for: None,
            entries: AncestorNotes::default(),
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
        let picked = state.selection.occluders_for(&self.world, view);
        let eye = view.eye();
        let near = view.frustum().planes()[0];
        let (variant, clip) = (state.variant, state.clip);
        let occlusion = &mut state.tree;
        let same = state
            .built_for
            .as_ref()
            .is_some_and(|(e, n, r, p)| *e == eye && *n == near && *r == view.region() && *p == picked);
        if !same {
            let mut order: Vec<(f64, u32)> = picked
                .iter()
                .map(|&i| {
                    let p = &self.world.occluders.all()[i as usize].polygon;
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
            let eps = plane_tolerance(&self.world.scene, eye);
            let polygons = visible_parts(
                &self.world.occluders,
                order.iter().map(|&(_, i)| i),
                view,
                eps,
            );
            occlusion.rebuild(
                eye,
                polygons.iter().map(|(_, p)| p),
                variant != Variant::Fse,
                eps,
            );
            state.built_for = Some((eye, near, view.region(), picked));
        }
        let occlusion = &*occlusion;
        let entries = &mut state.entries;
        entries.start_frame(self.world.parents.len());
        // Objects are tested right after their leaf: they start from its entry.
        let mut leaf_entry = Entry::ROOT;
        let mut test = |target: Target, b: &Aabb| {
            let leaf_test = match variant {
                Variant::Fse => return occlusion.box_visibility_exact(b),
                Variant::Fme => LeafTest::Exact,
                Variant::Fmc => LeafTest::Conservative,
            };
            let from = match target {
                Target::Node(n) => entries.nearest(&self.world.parents, n),
                Target::Object(_) => Some(leaf_entry),
                Target::Dynamic(_) => None,
            };
            let (visibility, entry) =
                occlusion.region_visibility_from(b, leaf_test, clip, from.unwrap_or(Entry::ROOT));
            if let Target::Node(n) = target {
                entries.set(n, entry);
                leaf_entry = entry;
            }
            visibility
        };
        Ok(state
            .selection
            .cull(&self.world, view, &mut test, out, occludees))
    }

    fn state_bytes(&self, state: &Self::State) -> usize {
        std::mem::size_of::<Self::State>()
            + state.selection.heap_bytes()
            + state.tree.heap_bytes()
            + state.entries.heap_bytes()
            + state
                .built_for
                .as_ref()
                .map_or(0, |b| b.3.capacity() * std::mem::size_of::<u32>())
    }
}
