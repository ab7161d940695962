//! Culling: the one trait every method implements, and the methods.
//!
//! A method is built once per scene ([`CullMethod`]) and answers views. Its
//! per-client temporal state (occluders chosen last frame, node marks, cached
//! plane relations) is a typed [`CullMethod::State`] that the *caller* keeps
//! between frames: a session keeps one, a stateless request makes a fresh
//! one. Callers that do not know the method (the server, eval) go through the
//! object-safe [`Culler`], which every `CullMethod` is, and hold the state as
//! an opaque [`ClientCache`].
//!
//! **Invariant:** culling never mutates a scene; a conservative method never
//! drops an object whose box-and-triangles could show a pixel.

pub mod frustum;
mod hierarchy;
pub mod horizon;
pub mod occluder;
pub mod occlusion_tree;
mod spec;
pub mod supporting_planes;

use std::any::Any;
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;

pub use spec::{METHOD_NAMES, MethodError, MethodOptions, MethodSpec, OptionReader};

use crate::geom::{Aabb, Camera, CameraError, Frustum};
use crate::scene::Scene;
use crate::spatial::{KdTree, KdTreeParams};

/// A validated camera, with its frustum in the scene's local coordinates.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// The camera as the client sent it (world coordinates).
    pub camera: Camera,
    /// Its frustum, relative to the scene origin.
    pub frustum: Frustum,
    /// The eye relative to the scene origin, in `f64`.
    pub eye: DVec3,
}

impl View {
    /// Validates `camera` and sets it up relative to `scene`'s origin.
    pub fn new(camera: Camera, scene: &Scene) -> Result<View, CameraError> {
        let frustum = Frustum::from_camera(&camera, scene.origin)?;
        Ok(View {
            camera,
            frustum,
            eye: camera.eye - scene.origin,
        })
    }
}

/// The ids a method found possibly visible; sorted ascending once finished.
///
/// Membership is kept in a bitset beside the ids, so an id pushed twice is
/// stored once and [`VisibleSet::contains`] answers in O(1): a method can
/// skip the tests of an object that another kd leaf already accepted (the
/// ground of a city lies in most leaves). Finishing a large set reads the
/// ids back off the bitset in order instead of sorting them: O(ids + max
/// id / 64), where sorting a street view of a 10k city was most of a
/// frame's cost.
///
/// A method that estimates screen areas (the horizon's LOD option) adds
/// each id with [`VisibleSet::push_with_area`]; then [`VisibleSet::areas`]
/// holds one bound per id, in the same order.
#[derive(Clone, Debug, Default)]
pub struct VisibleSet {
    /// Each id once, in the order first pushed; ascending once finished.
    ids: Vec<u32>,
    /// Bit `id` is set for each id in `ids`; grows to the largest id seen
    /// and is kept (all zero) across [`VisibleSet::clear`].
    members: Vec<u64>,
    /// Pixel bounds as pushed, repeats included until finished.
    areas: Vec<(u32, f64)>,
}

impl PartialEq for VisibleSet {
    fn eq(&self, other: &Self) -> bool {
        // `members` is derived from `ids`; its length is history.
        self.ids == other.ids && self.areas == other.areas
    }
}

impl VisibleSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Empties the set, keeping its allocations for the next frame.
    pub fn clear(&mut self) {
        if self.ids.len() * 4 < self.members.len() {
            for &id in &self.ids {
                self.members[id as usize >> 6] = 0;
            }
        } else {
            self.members.fill(0);
        }
        self.ids.clear();
        self.areas.clear();
    }

    /// Whether `id` was pushed.
    #[inline]
    pub fn contains(&self, id: u32) -> bool {
        self.members
            .get(id as usize >> 6)
            .is_some_and(|w| w & (1 << (id & 63)) != 0)
    }

    /// Adds an id; a repeat changes nothing.
    #[inline]
    pub fn push(&mut self, id: u32) {
        let word = id as usize >> 6;
        if word >= self.members.len() {
            self.members.resize(word + 1, 0);
        }
        let bit = 1u64 << (id & 63);
        if self.members[word] & bit == 0 {
            self.members[word] |= bit;
            self.ids.push(id);
        }
    }

    /// Adds an id with an upper bound of the pixels it covers (of repeats,
    /// the largest bound is kept).
    pub fn push_with_area(&mut self, id: u32, pixels: f64) {
        self.push(id);
        self.areas.push((id, pixels));
    }

    /// Adds ids; repeats change nothing.
    pub fn extend_from_slice(&mut self, ids: &[u32]) {
        // Whole subtrees of a kd-tree come here, many of their ids repeats:
        // write every id and advance past the new ones only, so a repeat
        // costs no mispredicted branch (growing is rare and predicted).
        let mut len = self.ids.len();
        self.ids.resize(len + ids.len(), 0);
        for &id in ids {
            let w = id as usize >> 6;
            if w >= self.members.len() {
                self.members.resize(w + 1, 0);
            }
            let word = &mut self.members[w];
            let bit = 1u64 << (id & 63);
            let new = *word & bit == 0;
            *word |= bit;
            self.ids[len] = id;
            len += usize::from(new);
        }
        self.ids.truncate(len);
    }

    /// Keeps only the ids `keep` accepts (aggressive methods drop objects this way).
    pub fn retain(&mut self, mut keep: impl FnMut(&u32) -> bool) {
        let members = &mut self.members;
        self.ids.retain(|id| {
            let kept = keep(id);
            if !kept {
                members[*id as usize >> 6] &= !(1 << (id & 63));
            }
            kept
        });
        let members = &self.members;
        self.areas
            .retain(|(id, _)| members[*id as usize >> 6] & (1 << (id & 63)) != 0);
    }

    /// Sorts the ids ascending.
    pub fn finish(&mut self) {
        // Reading the bitset costs a word per 64 ids of range; sorting,
        // about log2(n) steps per id. Read it when that is cheaper.
        if self.ids.len() * 8 >= self.members.len() {
            self.ids.clear();
            for (w, &word) in self.members.iter().enumerate() {
                let mut bits = word;
                while bits != 0 {
                    self.ids.push(((w as u32) << 6) | bits.trailing_zeros());
                    bits &= bits - 1;
                }
            }
        } else {
            self.ids.sort_unstable();
        }
        if !self.areas.is_empty() {
            // One bound per id: the largest of its repeats.
            self.areas
                .sort_unstable_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)));
            self.areas.dedup_by_key(|a| a.0);
            debug_assert_eq!(self.areas.len(), self.ids.len());
        }
    }

    /// Pixel bounds, one per id in [`VisibleSet::ids`] order, when the
    /// method gave them (finished sets only).
    pub fn areas(&self) -> Option<Vec<f64>> {
        (!self.areas.is_empty() && self.areas.len() == self.ids.len())
            .then(|| self.areas.iter().map(|a| a.1).collect())
    }

    /// The ids (sorted once finished).
    pub fn ids(&self) -> &[u32] {
        &self.ids
    }

    /// Bytes its buffers hold on the heap.
    pub fn heap_bytes(&self) -> usize {
        self.ids.capacity() * std::mem::size_of::<u32>()
            + self.members.capacity() * std::mem::size_of::<u64>()
            + self.areas.capacity() * std::mem::size_of::<(u32, f64)>()
    }

    /// How many ids.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

/// What a method knows of the objects inside the frustum.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum InFrustum {
    /// Its answer is the in-frustum set (frustum culling).
    #[default]
    Answer,
    /// It counted them on the way.
    Counted(u64),
    /// It does not know: an occlusion method drops hidden subtrees without
    /// counting what of them is in the frustum.
    Unknown,
}

/// What a method counted while culling one view.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CullCounters {
    /// Hierarchy nodes whose box was tested.
    pub nodes_tested: u64,
    /// Objects inside the frustum, as far as the method knows.
    pub in_frustum: InFrustum,
}

/// What one culled view cost and found (DESIGN: the answer's `stats`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CullStats {
    /// The method that answered (`auto` resolved to a real one).
    pub method: &'static str,
    /// Wall time of the cull, microseconds, including sorting the answer.
    pub cull_us: f64,
    /// Hierarchy nodes tested.
    pub nodes_tested: u64,
    /// Objects inside the frustum; `None` when the method does not count them.
    pub in_frustum: Option<u64>,
    /// Objects in the answer.
    pub visible: u64,
}

/// A culling method built for one scene. Implement this; call [`Culler`].
pub trait CullMethod: Send + Sync + 'static {
    /// Per-client state: the options it was made with and whatever the
    /// method carries from frame to frame.
    type State: Send + 'static;

    /// The method's name, one of [`METHOD_NAMES`].
    fn name(&self) -> &'static str;

    /// A fresh state for a client, from the request's options; unknown or
    /// invalid options are refused by name.
    fn new_state(&self, options: &MethodOptions) -> Result<Self::State, MethodError>;

    /// Whether, with this state's options, the method never drops a visible object.
    fn is_conservative(&self, state: &Self::State) -> bool;

    /// Whether a view costs well under ~100 µs, so a server may cull it on
    /// an async worker; anything else belongs on a blocking thread.
    fn is_cheap(&self) -> bool {
        false
    }

    /// Adds the possibly visible objects of `view` to `out` (in any order, repeats allowed).
    fn cull(&self, view: &View, state: &mut Self::State, out: &mut VisibleSet) -> CullCounters;

    /// [`CullMethod::cull`], and also tests boxes that are not part of the
    /// scene and move between frames (dynamic occludees: the avatars of a
    /// walkthrough's other users), in the scene's local coordinates.
    /// `visible[i]` is set false only when `dynamic[i]` certainly shows no
    /// pixel; dynamic boxes never hide anything.
    ///
    /// The default tests them against the frustum alone, which is
    /// conservative for every method; a method overrides it to test them
    /// with its own occlusion as well.
    fn cull_dynamic(
        &self,
        view: &View,
        state: &mut Self::State,
        out: &mut VisibleSet,
        dynamic: &[Aabb],
        visible: &mut Vec<bool>,
    ) -> CullCounters {
        visible.clear();
        visible.extend(dynamic.iter().map(|b| view.frustum.intersects(b)));
        self.cull(view, state, out)
    }

    /// About how many bytes a client's state holds (for the server's cache
    /// budget); the default counts the state itself, no heap.
    fn state_bytes(&self, state: &Self::State) -> usize {
        let _ = state;
        std::mem::size_of::<Self::State>()
    }
}

/// A client's state for one method, opaque to everyone but that method.
pub struct ClientCache {
    method: &'static str,
    conservative: bool,
    state: Box<dyn Any + Send>,
}

impl ClientCache {
    /// The method whose state this is.
    pub fn method(&self) -> &'static str {
        self.method
    }

    /// Whether the method, with these options, is conservative.
    pub fn is_conservative(&self) -> bool {
        self.conservative
    }
}

impl std::fmt::Debug for ClientCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClientCache")
            .field("method", &self.method)
            .finish_non_exhaustive()
    }
}

/// The object-safe face of every [`CullMethod`]: what the server and eval use.
pub trait Culler: Send + Sync {
    /// The method's name.
    fn name(&self) -> &'static str;
    /// A fresh client cache for these options.
    fn new_cache(&self, options: &MethodOptions) -> Result<ClientCache, MethodError>;
    /// Culls `view` into `out` (cleared first, sorted after) with the client's cache.
    ///
    /// # Panics
    /// When `cache` was made by another method: a caller bug, not bad input.
    fn cull(&self, view: &View, cache: &mut ClientCache, out: &mut VisibleSet) -> CullStats {
        self.cull_dynamic(view, cache, out, &[], &mut Vec::new())
    }
    /// [`Culler::cull`], also testing the boxes `dynamic` into `visible`
    /// ([`CullMethod::cull_dynamic`]).
    ///
    /// # Panics
    /// When `cache` was made by another method.
    fn cull_dynamic(
        &self,
        view: &View,
        cache: &mut ClientCache,
        out: &mut VisibleSet,
        dynamic: &[Aabb],
        visible: &mut Vec<bool>,
    ) -> CullStats;
    /// About how many bytes `cache` holds ([`CullMethod::state_bytes`]).
    ///
    /// # Panics
    /// When `cache` was made by another method.
    fn cache_bytes(&self, cache: &ClientCache) -> usize;
    /// Whether a view costs well under ~100 µs ([`CullMethod::is_cheap`]).
    fn is_cheap(&self) -> bool;
}

impl<M: CullMethod> Culler for M {
    fn is_cheap(&self) -> bool {
        CullMethod::is_cheap(self)
    }

    fn name(&self) -> &'static str {
        CullMethod::name(self)
    }

    fn new_cache(&self, options: &MethodOptions) -> Result<ClientCache, MethodError> {
        let state = self.new_state(options)?;
        Ok(ClientCache {
            method: CullMethod::name(self),
            conservative: self.is_conservative(&state),
            state: Box::new(state),
        })
    }

    fn cull_dynamic(
        &self,
        view: &View,
        cache: &mut ClientCache,
        out: &mut VisibleSet,
        dynamic: &[Aabb],
        visible: &mut Vec<bool>,
    ) -> CullStats {
        let method = cache.method;
        let state = cache
            .state
            .downcast_mut::<M::State>()
            .unwrap_or_else(|| wrong_cache(method, CullMethod::name(self)));
        out.clear();
        let start = Instant::now();
        let counters = CullMethod::cull_dynamic(self, view, state, out, dynamic, visible);
        out.finish();
        let cull_us = start.elapsed().as_secs_f64() * 1e6;
        CullStats {
            method: CullMethod::name(self),
            cull_us,
            nodes_tested: counters.nodes_tested,
            in_frustum: match counters.in_frustum {
                InFrustum::Answer => Some(out.len() as u64),
                InFrustum::Counted(n) => Some(n),
                InFrustum::Unknown => None,
            },
            visible: out.len() as u64,
        }
    }

    fn cache_bytes(&self, cache: &ClientCache) -> usize {
        let state = cache
            .state
            .downcast_ref::<M::State>()
            .unwrap_or_else(|| wrong_cache(cache.method, CullMethod::name(self)));
        self.state_bytes(state)
    }
}

/// A cache made by one method handed to another: a caller bug.
fn wrong_cache(made_by: &str, handed_to: &str) -> ! {
    panic!("a '{made_by}' cache handed to '{handed_to}'")
}

/// A scene with the methods it supports, ready to answer views.
///
/// Built once per scene at load; everything in it is read-only afterwards
/// and shared between requests.
pub struct SceneMethods {
    scene: Arc<Scene>,
    methods: Vec<Arc<dyn Culler>>,
    unsupported: Vec<(&'static str, String)>,
}

impl SceneMethods {
    /// Prepares what `scene`'s methods need and nothing more.
    pub fn prepare(scene: Arc<Scene>) -> SceneMethods {
        let tree = Arc::new(KdTree::build(&scene, KdTreeParams::default()));
        let mut methods: Vec<Arc<dyn Culler>> = vec![Arc::new(frustum::FrustumCulling::new(
            scene.clone(),
            tree.clone(),
        ))];
        let mut unsupported = Vec::new();
        // Horizons only where the scene stands on a ground as a height
        // field; no prisms or quadtree are kept otherwise.
        match horizon::HorizonCulling::new(scene.clone()) {
            Ok(h) => methods.push(Arc::new(h)),
            Err(why) => unsupported.push(("horizon", why)),
        }
        // The occlusion methods only where the scene has occluders; no
        // occluder data is kept otherwise.
        if let Some(occluders) = occluder::Occluders::find(&scene, &tree).map(Arc::new) {
            methods.push(Arc::new(occlusion_tree::OcclusionTreeCulling::new(
                scene.clone(),
                tree.clone(),
                occluders.clone(),
            )));
            methods.push(Arc::new(supporting_planes::SupportingPlanesCulling::new(
                scene.clone(),
                tree,
                occluders,
            )));
        } else {
            let why = "no opaque planar occluder is large enough against the scene".to_string();
            unsupported.push(("occlusion_tree", why.clone()));
            unsupported.push(("supporting_planes", why));
        }
        SceneMethods {
            scene,
            methods,
            unsupported,
        }
    }

    /// Methods of DESIGN's list this scene does not support, with why
    /// (`ddo` and `gpu`, not built yet, are not listed).
    pub fn unsupported(&self) -> &[(&'static str, String)] {
        &self.unsupported
    }

    /// The scene.
    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }

    /// Names of the methods this scene supports, best first (`auto` excluded).
    pub fn names(&self) -> Vec<&'static str> {
        self.methods.iter().map(|m| m.name()).collect()
    }

    /// The method called `name`; `auto` is the best this scene supports.
    pub fn get(&self, name: &str) -> Result<&Arc<dyn Culler>, MethodError> {
        if name == "auto" {
            return Ok(&self.methods[0]);
        }
        if let Some(m) = self.methods.iter().find(|m| m.name() == name) {
            return Ok(m);
        }
        if METHOD_NAMES.contains(&name) {
            Err(MethodError::Unsupported {
                name: name.into(),
                scene: self.scene.id.clone(),
                supported: self
                    .names()
                    .into_iter()
                    .map(String::from)
                    .chain(["auto".to_string()])
                    .collect(),
            })
        } else {
            Err(MethodError::Unknown { name: name.into() })
        }
    }

    /// Resolves a spec to its method and a fresh client cache.
    pub fn prepare_client(
        &self,
        spec: &MethodSpec,
    ) -> Result<(Arc<dyn Culler>, ClientCache), MethodError> {
        let method = self.get(&spec.name)?;
        let cache = method.new_cache(&spec.options)?;
        Ok((method.clone(), cache))
    }

    /// One stateless answer: a fresh cache, one view.
    pub fn cull_once(
        &self,
        spec: &MethodSpec,
        view: &View,
        out: &mut VisibleSet,
    ) -> Result<CullStats, MethodError> {
        let (method, mut cache) = self.prepare_client(spec)?;
        Ok(method.cull(view, &mut cache, out))
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use proptest::prelude::*;

    use super::VisibleSet;

    proptest! {
        /// Frames of pushes with repeats, retains and clears in between
        /// give the sorted distinct ids, whichever way `finish` reads them:
        /// dense frames (ids under 5000) read the bitset, sparse ones (ids
        /// spread to a million) are sorted.
        #[test]
        fn a_set_is_its_distinct_ids_sorted(
            frames in prop::collection::vec(
                (prop::collection::vec(0u32..5000, 0..400), 0u32..5000, any::<bool>(), any::<bool>()),
                1..6,
            )
        ) {
            let mut set = VisibleSet::new();
            for (pushed, cut, retain, sparse) in frames {
                let spread = if sparse { 200 } else { 1 };
                let pushed: Vec<u32> = pushed.iter().map(|id| id * spread).collect();
                let cut = cut * spread;
                set.clear();
                let mut expected: BTreeSet<u32> = BTreeSet::new();
                // Alternately one by one and as slices, as kd subtrees come.
                for (i, chunk) in pushed.chunks(7).enumerate() {
                    if i % 2 == 0 {
                        set.extend_from_slice(chunk);
                    } else {
                        chunk.iter().for_each(|&id| set.push(id));
                    }
                }
                expected.extend(pushed.iter().copied());
                if retain {
                    set.retain(|&id| id < cut);
                    expected.retain(|&id| id < cut);
                }
                for id in (0..5000).chain(pushed.iter().flat_map(|&id| [id, id + 1])) {
                    prop_assert_eq!(set.contains(id), expected.contains(&id));
                }
                set.finish();
                let want: Vec<u32> = expected.into_iter().collect();
                prop_assert_eq!(set.ids(), &want[..]);
            }
        }
    }

    #[test]
    fn areas_keep_the_largest_bound_of_repeats() {
        let mut set = VisibleSet::new();
        set.push_with_area(9, 1.0);
        set.push_with_area(2, 5.0);
        set.push_with_area(9, 3.0);
        set.finish();
        assert_eq!(set.ids(), &[2, 9]);
        assert_eq!(set.areas(), Some(vec![5.0, 3.0]));
        set.clear();
        assert!(set.is_empty() && !set.contains(9) && set.areas().is_none());
    }

    #[test]
    fn a_dense_set_and_a_sparse_one_finish_alike() {
        // 3000 ids under 4096 read off the bitset; 3 ids under 1e6 are sorted.
        let mut dense = VisibleSet::new();
        for id in (0..3000u32).rev() {
            dense.push(id);
            dense.push(id);
        }
        dense.finish();
        assert!(dense.ids().iter().copied().eq(0..3000));
        let mut sparse = VisibleSet::new();
        for id in [999_999, 7, 500_000, 7] {
            sparse.push(id);
        }
        sparse.finish();
        assert_eq!(sparse.ids(), &[7, 500_000, 999_999]);
    }
}
