//! Sessions: a client's temporal cache on the server, and the deltas that
//! let only changes travel after the first frame.
//!
//! A [`Session`] holds its method's [`ClientCache`] (occluders picked last
//! frame, node marks, cached plane relations, horizon buffers) and its last
//! [`KEEP_FRAMES`] visible sets, encoded ([`IdSet`]). A frame's answer is
//! the change from the set the client holds: the last one sent, or the
//! `base` it names; when that base is no longer kept, the whole set with
//! `base: null`.
//!
//! [`Sessions`] is the store: a `moka` cache that expires idle sessions
//! and evicts the least recently used past a cap on their number and one on
//! their bytes. Ended sessions leave a tombstone so a late client hears 410
//! (expired or evicted), not 404 (never made, or deleted).
//!
//! Ordering: frames of one session take its `tokio::sync::Mutex`, which is
//! fair (first come, first served), so they are answered one at a time in
//! arrival order; sessions share no lock.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use super::error::ApiError;
use super::metrics::Metrics;
use super::route::RouteKey;
use super::state::SessionLimits;
use super::walkthrough::User;
use crate::cull::{
    ClientCache, CullJob, CullStats, Culler, MethodOptions, MethodSpec, Occludees, SceneMethods,
    View, VisibleSet,
};
use crate::geom::{Camera, Region};
use moka::notification::RemovalCause;
use moka::ops::compute::Op;
use moka::policy::EvictionPolicy;
use moka::sync::Cache;
use pvsd_proto::delta::{IdSet, diff};
use pvsd_proto::json::FrameResponse;

/// Past frames a session keeps, so a client that lost answers can name an
/// older base and still get a delta.
pub const KEEP_FRAMES: usize = 4;

/// One client's session.
pub struct Session {
    /// Its id.
    pub id: String,
    /// The scene it looks at.
    pub scene: Arc<SceneMethods>,
    /// The method answering its frames.
    pub method: Arc<dyn Culler>,
    /// The walkthrough and user it belongs to, if any.
    pub user: Option<User>,
    /// The region of frames that give none (`POST /sessions`'s `radius`
    /// and `angle`).
    pub region: Region,
    /// The method's options, to make its cache again if a failed cull lost it.
    options: MethodOptions,
    /// Its bytes when made (what the store first weighs it at).
    created_bytes: usize,
    frames: Arc<tokio::sync::Mutex<Frames>>,
}

/// What a session carries from frame to frame.
struct Frames {
    /// The method's cache; `None` after a cull that kept it (a job lost
    /// with its thread, or a request cancelled mid-cull by its client or
    /// the timeout): the next frame makes a fresh one.
    cache: Option<ClientCache>,
    /// The number the next frame gets.
    next: u64,
    /// The last frames sent, oldest first.
    kept: VecDeque<(u64, IdSet)>,
    /// This frame's set, while it is culled and answered (its buffers
    /// between frames).
    visible: VisibleSet,
    /// The last frame's set (the newest in `kept`) as culled: most clients
    /// hold it, and diffing against it needs no decoding.
    previous: VisibleSet,
    /// An older base, decoded.
    base: Vec<u32>,
    /// The other users' avatars, and which of them this frame sees.
    occludees: Occludees,
    /// Bytes the store last weighed the session at.
    weighed: usize,
}

/// A frame's answer, with what it cost and the session's new size.
pub struct Answered {
    /// The answer.
    pub frame: FrameResponse,
    /// The cull's stats.
    pub stats: CullStats,
    /// The session's bytes, when they moved by more than an eighth since
    /// the store last weighed it ([`Sessions::resized`]).
    pub resized: Option<usize>,
}

impl Session {
    /// A session of `method` (made for `scene` with `cache`), its id
    /// minted on `route` ([`RouteKey`]).
    pub fn new(
        route: &RouteKey,
        scene: Arc<SceneMethods>,
        method: Arc<dyn Culler>,
        cache: ClientCache,
        user: Option<User>,
    ) -> Session {
        let options = cache.options().clone();
        let mut frames = Frames {
            cache: Some(cache),
            next: 1,
            kept: VecDeque::with_capacity(KEEP_FRAMES + 1),
            visible: VisibleSet::new(),
            previous: VisibleSet::new(),
            base: Vec::new(),
            occludees: Occludees::default(),
            weighed: 0,
        };
        frames.weighed = frames.bytes(&*method);
        Session {
            id: route.mint(),
            scene,
            method,
            user,
            region: Region::POINT,
            options,
            created_bytes: frames.weighed,
            frames: Arc::new(tokio::sync::Mutex::new(frames)),
        }
    }

    /// The session with `region` for frames that give none.
    pub fn with_region(mut self, region: Region) -> Session {
        self.region = region;
        self
    }

    /// The method and options its frames are answered with.
    pub fn spec(&self) -> MethodSpec {
        MethodSpec {
            name: self.method.name().to_string(),
            options: self.options.clone(),
        }
    }

    /// This session on a reloaded scene: the same id and user, `method`
    /// and `cache` made for `scene`, frame numbers going on; no frame is
    /// kept, so its next answer is the whole set (`base: null`).
    pub async fn rebound(
        &self,
        scene: Arc<SceneMethods>,
        method: Arc<dyn Culler>,
        cache: ClientCache,
    ) -> Session {
        let next = self.frames.lock().await.next;
        let route = RouteKey::of_id(&self.id).unwrap_or_else(RouteKey::random);
        let mut session =
            Session::new(&route, scene, method, cache, self.user.clone()).with_region(self.region);
        session.id = self.id.clone();
        session.frames.lock().await.next = next;
        session
    }

    /// Answers one frame, after every frame that reached the session
    /// before it; the cull runs where the session's method runs.
    ///
    /// `view` and `also` are the job's views ([`crate::cull::view::gather`]);
    /// `pose` is the camera the user (in a walkthrough) stands at, anywhere
    /// within `radius` of its eye.
    pub async fn frame(
        &self,
        (view, also): (View, Vec<View>),
        (pose, radius): (Camera, f64),
        base: Option<u64>,
    ) -> Result<Answered, ApiError> {
        let mut frames = self.frames.lock().await;
        // The user moves before looking, so others see where it is now.
        let others = self.user.as_ref().map(|u| {
            let scene = self.scene.scene();
            u.moved(
                &pose,
                radius,
                &scene.origin,
                f64::from(scene.bounds().min.y),
            )
        });
        let f = &mut *frames;
        let cache = match f.cache.take() {
            Some(cache) => cache,
            // Kept by a cull that never came back: a fresh one.
            None => self
                .method
                .new_cache(&self.options)
                .map_err(|e| ApiError::Internal(format!("cannot remake a session's cache: {e}")))?,
        };
        let mut job = CullJob::new(view, cache);
        job.also = also;
        job.out = std::mem::take(&mut f.visible);
        job.occludees = std::mem::take(&mut f.occludees);
        job.occludees
            .set_boxes(others.iter().flatten().map(|(_, b)| *b));
        let culled = match self.scene.cull(&self.method, job).await {
            Ok(culled) => culled,
            Err(mut unanswered) => {
                // No frame was answered: keep what the job carried, so a
                // refused (busy) frame costs the session nothing.
                if let Some(job) = unanswered.job.take() {
                    let job = *job;
                    f.cache = Some(job.cache);
                    f.visible = job.out;
                    f.occludees = job.occludees;
                }
                return Err(unanswered.into());
            }
        };
        let mut job = culled.job;
        let mut answer = f.answer(&mut job.out, base);
        answer.users_visible = others.map(|others| {
            others
                .into_iter()
                .zip(job.occludees.visible())
                .filter(|&(_, &seen)| seen)
                .map(|((user, _), _)| user)
                .collect()
        });
        f.visible = job.out;
        f.occludees = job.occludees;
        f.cache = Some(job.cache);
        let bytes = f.bytes(&*self.method);
        let resized = (bytes.abs_diff(f.weighed) > f.weighed / 8).then(|| {
            f.weighed = bytes;
            bytes
        });
        Ok(Answered {
            frame: answer,
            stats: culled.stats,
            resized,
        })
    }
}

impl Frames {
    /// The delta of the culled `visible` against `base` (or the last frame
    /// sent); keeps the new set, swapping it with `previous`.
    fn answer(&mut self, visible: &mut VisibleSet, base: Option<u64>) -> FrameResponse {
        let frame = self.next;
        self.next += 1;
        let ids = visible.ids();
        let held = match base {
            Some(b) => self.kept.iter().find(|(n, _)| *n == b),
            None => self.kept.back(),
        };
        let mut out = FrameResponse {
            frame,
            ..FrameResponse::default()
        };
        let last = self.kept.back().map(|(n, _)| *n);
        match held {
            Some((n, set)) => {
                let old = if Some(*n) == last {
                    self.previous.ids()
                } else {
                    set.decode_into(&mut self.base);
                    &self.base
                };
                diff(old, ids, &mut out.added, &mut out.removed);
                out.base = Some(*n);
            }
            None => out.added = ids.to_vec(),
        }
        self.kept.push_back((frame, IdSet::new(ids)));
        if self.kept.len() > KEEP_FRAMES {
            self.kept.pop_front();
        }
        // This set is the next frame's `previous`; the next cull reuses the
        // old one's buffers. Swapped only once the frame is kept, so a cull
        // that never finished cannot leave `previous` out of step.
        std::mem::swap(visible, &mut self.previous);
        out
    }

    /// The session's bytes: itself, its kept frames and buffers, and the
    /// method's cache.
    fn bytes(&self, method: &dyn Culler) -> usize {
        std::mem::size_of::<Session>()
            + std::mem::size_of::<Frames>()
            + self.kept.iter().map(|(_, s)| 16 + s.bytes()).sum::<usize>()
            + self.visible.heap_bytes()
            + self.previous.heap_bytes()
            + self.base.capacity() * std::mem::size_of::<u32>()
            + self.occludees.heap_bytes()
            + self.cache.as_ref().map_or(0, |c| method.cache_bytes(c))
    }
}

/// A stored session with the weight it was stored at.
#[derive(Clone)]
struct Slot {
    session: Arc<Session>,
    /// Bytes when stored (what the live-bytes count holds for it).
    bytes: u64,
    /// Its weight against the byte cap: at least `cap / max_sessions`, so
    /// the byte cap also caps the count.
    weight: u32,
}

/// Why a session ended without being deleted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ended {
    Expired,
    Evicted,
}

/// Every live session.
pub struct Sessions {
    live: Cache<String, Slot>,
    ended: Cache<String, Ended>,
    bytes: Arc<AtomicU64>,
    limits: SessionLimits,
    /// Weight floor per session.
    floor: u64,
}

impl Sessions {
    /// An empty store within `limits`, counting into `metrics`.
    pub fn new(limits: SessionLimits, metrics: &Metrics) -> Sessions {
        let bytes = Arc::new(AtomicU64::new(0));
        // Tombstones: ids only, a few times the session cap, an hour each.
        let ended: Cache<String, Ended> = Cache::builder()
            .max_capacity(limits.max_sessions.saturating_mul(4).max(1024))
            .time_to_live(std::time::Duration::from_secs(3600))
            .build();
        let listener = {
            let (bytes, ended) = (bytes.clone(), ended.clone());
            let evictions = metrics.session_evictions();
            move |id: Arc<String>, slot: Slot, cause: RemovalCause| {
                bytes.fetch_sub(slot.bytes, Ordering::Relaxed);
                if cause == RemovalCause::Replaced {
                    return;
                }
                if let Some(user) = &slot.session.user {
                    user.leave();
                }
                let why = match cause {
                    RemovalCause::Expired => Ended::Expired,
                    RemovalCause::Size => Ended::Evicted,
                    RemovalCause::Explicit | RemovalCause::Replaced => return,
                };
                evictions(why == Ended::Expired);
                ended.insert((*id).clone(), why);
            }
        };
        // Rounded up: every session weighs at least the floor, so the byte
        // cap holds at most `max_sessions` of them (rounded down, 8 MiB over
        // 5,000 sessions let 5,002 in once sessions were light enough).
        let floor = limits
            .cache_bytes
            .div_ceil(limits.max_sessions.max(1))
            .max(1);
        // Least recently used, not moka's default TinyLFU: TinyLFU may
        // refuse a new session outright when the cache is full, and a
        // client that just made one must be able to use it.
        let live = Cache::builder()
            .eviction_policy(EvictionPolicy::lru())
            .max_capacity(limits.cache_bytes)
            .weigher(|_, s: &Slot| s.weight)
            .time_to_idle(limits.idle)
            .eviction_listener(listener)
            .build();
        Sessions {
            live,
            ended,
            bytes,
            limits,
            floor,
        }
    }

    fn slot(&self, session: Arc<Session>, bytes: usize) -> Slot {
        let bytes = bytes as u64;
        Slot {
            session,
            bytes,
            weight: bytes.max(self.floor).min(u64::from(u32::MAX)) as u32,
        }
    }

    /// Stores a new session.
    pub fn insert(&self, session: Session) -> Arc<Session> {
        let session = Arc::new(session);
        let slot = self.slot(session.clone(), session.created_bytes);
        self.bytes.fetch_add(slot.bytes, Ordering::Relaxed);
        self.live.insert(session.id.clone(), slot);
        session
    }

    /// The session `id`, now used (its idle time restarts); 404 when never
    /// made or deleted, 410 when it expired or was evicted.
    pub fn get(&self, id: &str) -> Result<Arc<Session>, ApiError> {
        if let Some(slot) = self.live.get(id) {
            return Ok(slot.session);
        }
        Err(self.gone(id))
    }

    /// Why `id` is not live.
    fn gone(&self, id: &str) -> ApiError {
        // Let expiry notices through first: the cache hides an expired
        // session at once but tells its listener later.
        self.live.run_pending_tasks();
        match self.ended.get(id) {
            Some(Ended::Expired) => ApiError::SessionExpired {
                id: id.to_string(),
                idle_s: self.limits.idle.as_secs(),
            },
            Some(Ended::Evicted) => ApiError::SessionEvicted(id.to_string()),
            None => ApiError::UnknownSession(id.to_string()),
        }
    }

    /// Re-weighs a session at its new size, if it is still live (a frame
    /// answers [`Answered::resized`] only when the size moved enough to
    /// matter, so most frames never write to the store).
    pub fn resized(&self, session: &Arc<Session>, bytes: usize) {
        let new = self.slot(session.clone(), bytes);
        self.live
            .entry(session.id.clone())
            .and_compute_with(|old| match old {
                Some(e) if Arc::ptr_eq(&e.value().session, session) => {
                    self.bytes.fetch_add(new.bytes, Ordering::Relaxed);
                    Op::Put(new)
                }
                _ => Op::Nop,
            });
    }

    /// Puts `new` (the same id) in `old`'s place, if `old` is still the live
    /// session of that id; else keeps what is there. Returns what is live.
    pub fn replace(&self, old: &Arc<Session>, new: Session) -> Result<Arc<Session>, ApiError> {
        let new = Arc::new(new);
        let slot = self.slot(new.clone(), new.created_bytes);
        let entry = self
            .live
            .entry(old.id.clone())
            .and_compute_with(|live| match live {
                Some(e) if Arc::ptr_eq(&e.value().session, old) => {
                    self.bytes.fetch_add(slot.bytes, Ordering::Relaxed);
                    Op::Put(slot)
                }
                _ => Op::Nop,
            });
        match entry {
            moka::ops::compute::CompResult::ReplacedWith(e)
            | moka::ops::compute::CompResult::Unchanged(e) => Ok(e.into_value().session),
            _ => Err(self.gone(&old.id)),
        }
    }

    /// Ends a session; 404/410 as [`Sessions::get`] when it is not live.
    pub fn remove(&self, id: &str) -> Result<(), ApiError> {
        match self.live.remove(id) {
            Some(_) => Ok(()),
            None => Err(self.gone(id)),
        }
    }

    /// Live sessions and the bytes they hold, after pending expiries.
    pub fn usage(&self) -> (u64, u64) {
        self.live.run_pending_tasks();
        (self.live.entry_count(), self.bytes.load(Ordering::Relaxed))
    }

    /// The limits in force.
    pub fn limits(&self) -> SessionLimits {
        self.limits
    }
}
