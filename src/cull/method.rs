//! The two traits every culling method is seen through.
//!
//! A method implements [`CullMethod`]: one required [`CullMethod::cull`]
//! that answers a view into a [`VisibleSet`], with its per-client temporal
//! state (occluders chosen last frame, node marks, cached plane relations) a
//! typed [`CullMethod::State`] that the *caller* keeps between frames. It
//! says how it must be run ([`Execution`]): inline, on the blocking pool, or
//! on a device's own thread.
//!
//! Callers that do not know the method (the server, eval) go through the
//! object-safe [`Culler`], which every `CullMethod` is: they hold the state
//! as an opaque [`ClientCache`] inside a [`CullJob`], and run jobs through
//! one dispatch (`SceneMethods::cull`, `SceneMethods::cull_blocking`).

use std::any::Any;
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::device::DeviceQueue;
use super::{MethodError, MethodOptions, View, VisibleSet};
use crate::geom::Aabb;

/// Where a method's culls run, so that no request stalls another.
#[derive(Clone, Debug)]
pub enum Execution {
    /// On the async worker that received the request: the cull takes
    /// microseconds, less than handing it to another thread would.
    Inline,
    /// On the runtime's blocking pool: past ~100 µs a cull would stall the
    /// other requests sharing its async worker.
    Blocking,
    /// On a device's own thread, submitted through its bounded queue and
    /// answered later; jobs that wait together run as one batch
    /// ([`Culler::cull_batch`]).
    Device(Arc<DeviceQueue>),
}

/// Why a method gave no answer for a view.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum CullError {
    /// The method cannot take more work now (a device's queue is full);
    /// the client should try again after `retry_after`. Nothing was culled.
    #[error("method '{method}' is busy; retry after {retry_after:?}")]
    Busy {
        /// The method.
        method: &'static str,
        /// A fair wait before the next try.
        retry_after: Duration,
    },
    /// The method failed at run time (a lost device, a panic): the view is
    /// answered by frustum culling instead, and the answer says so.
    #[error("method '{method}' failed: {reason}")]
    Failed {
        /// The method.
        method: &'static str,
        /// What went wrong.
        reason: String,
    },
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

/// The method that answered instead of the one asked, and why
/// (DESIGN: `stats.fallback`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fallback {
    /// The method that answered (always `frustum`, which cannot fail).
    pub method: &'static str,
    /// Why the asked method gave no answer.
    pub reason: String,
}

/// What one culled view cost and found (DESIGN: the answer's `stats`).
#[derive(Clone, Debug, PartialEq)]
pub struct CullStats {
    /// The method that was asked (`auto` resolved to a real one).
    pub method: &'static str,
    /// Wall time of the cull, microseconds, including sorting the answer.
    pub cull_us: f64,
    /// Hierarchy nodes tested.
    pub nodes_tested: u64,
    /// Objects inside the frustum; `None` when the method does not count them.
    pub in_frustum: Option<u64>,
    /// Objects in the answer.
    pub visible: u64,
    /// Set when `method` failed and another answered.
    pub fallback: Option<Fallback>,
}

/// Boxes that move between frames (dynamic occludees: the avatars of a
/// walkthrough's other users, and the scene's movable objects, which the
/// dispatch adds after them), in the scene's local coordinates, and what a
/// cull found of each. They never hide anything.
#[derive(Clone, Debug, Default)]
pub struct Occludees {
    boxes: Vec<Aabb>,
    visible: Vec<bool>,
}

impl Occludees {
    /// Sets the boxes of the next cull (their answers are cleared).
    pub fn set_boxes(&mut self, boxes: impl IntoIterator<Item = Aabb>) {
        self.boxes.clear();
        self.boxes.extend(boxes);
        self.visible.clear();
    }

    /// Adds boxes after those set (every answer is cleared).
    pub fn extend_boxes(&mut self, boxes: impl IntoIterator<Item = Aabb>) {
        self.boxes.extend(boxes);
        self.visible.clear();
    }

    /// Keeps the first `len` boxes and their answers.
    pub fn truncate(&mut self, len: usize) {
        self.boxes.truncate(len);
        self.visible.truncate(len);
    }

    /// The boxes.
    pub fn boxes(&self) -> &[Aabb] {
        &self.boxes
    }

    /// After a cull: `visible()[i]` is false only when box `i` certainly
    /// shows no pixel.
    pub fn visible(&self) -> &[bool] {
        &self.visible
    }

    /// Before a cull: every box that touches the frustum may be visible.
    fn reset(&mut self, view: &View) {
        self.visible.clear();
        let frustum = view.frustum();
        self.visible
            .extend(self.boxes.iter().map(|b| frustum.intersects(b)));
    }

    /// Marks box `i` hidden: a method that proves it shows no pixel.
    pub fn hide(&mut self, i: usize) {
        self.visible[i] = false;
    }

    /// Bytes its buffers hold on the heap.
    pub fn heap_bytes(&self) -> usize {
        self.boxes.capacity() * std::mem::size_of::<Aabb>() + self.visible.capacity()
    }
}

/// A culling method built for one scene. Implement this; call [`Culler`].
pub trait CullMethod: Send + Sync + 'static {
    /// Per-client state: the options it was made with and whatever the
    /// method carries from frame to frame.
    type State: Send + 'static;

    /// The method's name, one of [`super::METHOD_NAMES`].
    fn name(&self) -> &'static str;

    /// A fresh state for a client, from the request's options; unknown or
    /// invalid options are refused by name.
    ///
    /// A state is plain per-client data, made on the caller's thread: what a
    /// method needs of its device belongs to the method, not to a state, so
    /// options accepted once make a state again whatever the device does
    /// (the dispatch remakes a failed client's state this way).
    fn new_state(&self, options: &MethodOptions) -> Result<Self::State, MethodError>;

    /// Whether, with this state's options, the method never drops a visible object.
    fn is_conservative(&self, state: &Self::State) -> bool;

    /// Where its culls run; the default, the blocking pool, is right for
    /// anything that may take more than ~100 µs.
    fn execution(&self) -> Execution {
        Execution::Blocking
    }

    /// Whether it culls the scene's movable objects itself (from
    /// `Scene::motion`, adding those it finds visible to its answer); by
    /// default it does not, and the dispatch hands them to it as dynamic
    /// occludees after the avatars.
    fn culls_movers(&self) -> bool {
        false
    }

    /// Adds the possibly visible objects of `view` to `out` (in any order,
    /// repeats allowed). `occludees` arrive answered by the frustum alone,
    /// which is conservative; a method with an occlusion test of its own
    /// hides those it proves hidden ([`Occludees::hide`]).
    fn cull(
        &self,
        view: &View,
        state: &mut Self::State,
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> Result<CullCounters, CullError>;

    /// Culls views that were submitted together (a device's batch), each
    /// as [`CullMethod::cull`] would. A device method overrides it to
    /// answer them with one submission; the default culls one by one.
    fn cull_batch(
        &self,
        batch: &mut [BatchItem<'_, Self::State>],
    ) -> Vec<Result<CullCounters, CullError>> {
        batch
            .iter_mut()
            .map(|b| self.cull(b.view, b.state, b.out, b.occludees))
            .collect()
    }

    /// About how many bytes a client's state holds (for the server's cache
    /// budget); the default counts the state itself, no heap.
    fn state_bytes(&self, state: &Self::State) -> usize {
        let _ = state;
        std::mem::size_of::<Self::State>()
    }
}

/// One view of a batch ([`CullMethod::cull_batch`]): what
/// [`CullMethod::cull`] takes for it.
pub struct BatchItem<'a, S> {
    /// The view.
    pub view: &'a View,
    /// Its client's state.
    pub state: &'a mut S,
    /// Its answer.
    pub out: &'a mut VisibleSet,
    /// Its dynamic occludees.
    pub occludees: &'a mut Occludees,
}

/// A client's state for one method, opaque to everyone but that method.
pub struct ClientCache {
    method: &'static str,
    conservative: bool,
    /// The options it was made with, to make it again after a failure.
    options: MethodOptions,
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

    /// The options it was made with.
    pub fn options(&self) -> &MethodOptions {
        &self.options
    }
}

impl std::fmt::Debug for ClientCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClientCache")
            .field("method", &self.method)
            .finish_non_exhaustive()
    }
}

/// Everything one cull reads and writes, owned, so that it can move to a
/// blocking thread or a device's thread and come back: the view, the
/// client's cache, the answer and the dynamic occludees. A session keeps
/// one between frames, so its buffers are reused.
#[derive(Debug)]
pub struct CullJob {
    /// The view to answer (the first, when there are several).
    pub view: View,
    /// More views answered together with `view` (a multi-view request:
    /// two eyes, split screens): the answer is the union, each method run
    /// once per view on the same state. Empty for one view.
    pub also: Vec<View>,
    /// The client's temporal state.
    pub cache: ClientCache,
    /// The answer: cleared before, sorted after the cull.
    pub out: VisibleSet,
    /// Dynamic occludees and the cull's answer for each.
    pub occludees: Occludees,
}

impl CullJob {
    /// A job with empty buffers.
    pub fn new(view: View, cache: ClientCache) -> CullJob {
        CullJob {
            view,
            also: Vec::new(),
            cache,
            out: VisibleSet::new(),
            occludees: Occludees::default(),
        }
    }
}

/// The object-safe face of every [`CullMethod`]: what the server and eval use.
pub trait Culler: Send + Sync {
    /// The method's name.
    fn name(&self) -> &'static str;
    /// Where its culls run ([`CullMethod::execution`]).
    fn execution(&self) -> Execution;
    /// Whether it culls the scene's movable objects itself ([`CullMethod::culls_movers`]).
    fn culls_movers(&self) -> bool;
    /// A fresh client cache for these options.
    fn new_cache(&self, options: &MethodOptions) -> Result<ClientCache, MethodError>;
    /// Culls the job's view into `job.out` (cleared first, sorted after)
    /// with its cache, here and now. Callers go through the dispatch
    /// (`SceneMethods::cull`), which runs this where [`Culler::execution`]
    /// says.
    ///
    /// # Panics
    /// When `job.cache` was made by another method: a caller bug, not bad input.
    fn cull(&self, job: &mut CullJob) -> Result<CullStats, CullError>;
    /// Culls jobs that were submitted together; a device method overrides
    /// it to run them as one submission. The default culls one by one.
    fn cull_batch(&self, jobs: &mut [CullJob]) -> Vec<Result<CullStats, CullError>> {
        jobs.iter_mut().map(|job| self.cull(job)).collect()
    }
    /// About how many bytes `cache` holds ([`CullMethod::state_bytes`]).
    ///
    /// # Panics
    /// When `cache` was made by another method.
    fn cache_bytes(&self, cache: &ClientCache) -> usize;
}

impl<M: CullMethod> Culler for M {
    fn name(&self) -> &'static str {
        CullMethod::name(self)
    }

    fn execution(&self) -> Execution {
        CullMethod::execution(self)
    }

    fn culls_movers(&self) -> bool {
        CullMethod::culls_movers(self)
    }

    fn new_cache(&self, options: &MethodOptions) -> Result<ClientCache, MethodError> {
        let state = self.new_state(options)?;
        Ok(ClientCache {
            method: CullMethod::name(self),
            conservative: self.is_conservative(&state),
            options: options.clone(),
            state: Box::new(state),
        })
    }

    fn cull(&self, job: &mut CullJob) -> Result<CullStats, CullError> {
        let start = Instant::now();
        // A copy (free for one view): the job keeps its views even if the
        // method panics, so a frustum fallback answers all of them.
        let also = job.also.clone();
        let item = self.begin(job);
        let result = cull_views(self, item, &also);
        Ok(self.finish(job, result?, start))
    }

    fn cull_batch(&self, jobs: &mut [CullJob]) -> Vec<Result<CullStats, CullError>> {
        if jobs.iter().any(|job| !job.also.is_empty()) {
            // A device batch answers one view per job.
            return jobs.iter_mut().map(|job| Culler::cull(self, job)).collect();
        }
        // Each answer's time is the batch's: what its client waited for.
        let start = Instant::now();
        let mut items: Vec<BatchItem<'_, M::State>> =
            jobs.iter_mut().map(|job| self.begin(job)).collect();
        let results = CullMethod::cull_batch(self, &mut items);
        drop(items);
        assert_eq!(results.len(), jobs.len(), "a batch answers every view");
        jobs.iter_mut()
            .zip(results)
            .map(|(job, result)| Ok(self.finish(job, result?, start)))
            .collect()
    }

    fn cache_bytes(&self, cache: &ClientCache) -> usize {
        let state = cache
            .state
            .downcast_ref::<M::State>()
            .unwrap_or_else(|| wrong_cache(cache.method, CullMethod::name(self)));
        self.state_bytes(state)
    }
}

impl<M: CullMethod> CullerSteps for M {}

/// The steps around a method's cull that every [`Culler`] takes.
trait CullerSteps: CullMethod + Sized {
    /// The job's parts for a cull: its state, its answer cleared, its
    /// occludees answered by the frustum alone.
    fn begin<'a>(&self, job: &'a mut CullJob) -> BatchItem<'a, Self::State> {
        let method = job.cache.method;
        let state = job
            .cache
            .state
            .downcast_mut::<Self::State>()
            .unwrap_or_else(|| wrong_cache(method, CullMethod::name(self)));
        job.out.clear();
        job.occludees.reset(&job.view);
        BatchItem {
            view: &job.view,
            state,
            out: &mut job.out,
            occludees: &mut job.occludees,
        }
    }

    /// The answer sorted, and the stats of a cull that began at `start`.
    fn finish(&self, job: &mut CullJob, counters: CullCounters, start: Instant) -> CullStats {
        job.out.finish();
        let cull_us = start.elapsed().as_secs_f64() * 1e6;
        let visible = job.out.len() as u64;
        CullStats {
            method: CullMethod::name(self),
            cull_us,
            nodes_tested: counters.nodes_tested,
            in_frustum: match counters.in_frustum {
                InFrustum::Answer => Some(visible),
                InFrustum::Counted(n) => Some(n),
                InFrustum::Unknown => None,
            },
            visible,
            fallback: None,
        }
    }
}

/// Culls `item`'s view and then each of `also` into the same answer with
/// the same state: the union. An occludee is visible when some view sees
/// it. With several views nothing counts the objects in their frusta.
fn cull_views<M: CullMethod>(
    method: &M,
    item: BatchItem<'_, M::State>,
    also: &[View],
) -> Result<CullCounters, CullError> {
    let mut counters = CullMethod::cull(method, item.view, item.state, item.out, item.occludees)?;
    if also.is_empty() {
        return Ok(counters);
    }
    let mut seen = item.occludees.visible().to_vec();
    for view in also {
        item.occludees.reset(view);
        let more = CullMethod::cull(method, view, item.state, item.out, item.occludees)?;
        counters.nodes_tested += more.nodes_tested;
        for (s, &v) in seen.iter_mut().zip(item.occludees.visible()) {
            *s |= v;
        }
    }
    item.occludees.visible = seen;
    counters.in_frustum = InFrustum::Unknown;
    Ok(counters)
}

/// A cache made by one method handed to another: a caller bug.
fn wrong_cache(made_by: &str, handed_to: &str) -> ! {
    panic!("a '{made_by}' cache handed to '{handed_to}'")
}
