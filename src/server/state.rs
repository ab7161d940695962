//! What every request shares: the scenes with their methods, the metrics,
//! the limits, and the session and walkthrough stores. Cheap to clone (an
//! `Arc`); the scenes are read-only once built and the stores are
//! concurrent caches, so requests of different sessions never wait on each
//! other.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, Instant};

use pvsd_proto::json::{ReloadFailure, ReloadReport};

use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use super::error::ApiError;
use super::limit::ClientRate;
use super::listener::ConnectionLimits;
use super::metrics::Metrics;
use super::session::Sessions;
use super::walkthrough::Walkthroughs;
use crate::cull::{MethodContext, Registry, SceneMethods};
use crate::eval::{RankParams, rank_cached};
use crate::scene::{BakeCache, Scene, load_path};

/// Limits applied to every request.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Largest accepted request body, bytes.
    pub body_bytes: usize,
    /// Longest a request may take before it is answered with 503 `timeout`.
    pub request_timeout: Duration,
    /// Caps on sessions and walkthroughs.
    pub sessions: SessionLimits,
    /// Caps and timeouts of connections.
    pub connections: ConnectionLimits,
    /// How deep and how long a JSON body may be.
    pub json: JsonLimits,
    /// Requests a second each client (IP address) may make; none: no limit.
    pub client_rate: Option<Rate>,
    /// Messages a second each WebSocket may send; none: no limit (a
    /// socket's backpressure already holds it to one answer at a time).
    pub websocket_rate: Option<Rate>,
}

/// How deep and how wide a JSON body may be: no body the routes take
/// comes near these, and they bound what a body within the byte limit can
/// make the parser do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct JsonLimits {
    /// Most nested arrays and objects.
    pub max_depth: usize,
    /// Most items in one array.
    pub max_array: usize,
}

impl Default for JsonLimits {
    fn default() -> Self {
        JsonLimits {
            max_depth: 16,
            max_array: 1024,
        }
    }
}

/// A token bucket: `per_s` a second on average, `burst` at once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rate {
    /// Sustained rate, a second.
    pub per_s: f64,
    /// Most at once after a pause.
    pub burst: u32,
}

/// How long sessions live and how many the server keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SessionLimits {
    /// A session (or walkthrough) without a frame this long ends (410 after).
    pub idle: Duration,
    /// Most live sessions; past it the least recently used is evicted.
    pub max_sessions: u64,
    /// Most bytes all sessions' caches and kept frames may hold; past it the
    /// least recently used is evicted.
    pub cache_bytes: u64,
    /// Most live walkthroughs.
    pub max_walkthroughs: u64,
}

impl Default for SessionLimits {
    fn default() -> Self {
        // A horizon session on a 10k city holds ~100 KB; 256 MiB keeps a
        // few thousand of those, and 100k light (frustum) ones.
        SessionLimits {
            idle: Duration::from_secs(300),
            max_sessions: 100_000,
            cache_bytes: 256 << 20,
            max_walkthroughs: 10_000,
        }
    }
}

impl Default for Limits {
    fn default() -> Self {
        // A view is ~300 bytes; 64 KiB leaves room for options without
        // letting a client make the server buffer megabytes.
        Limits {
            body_bytes: 64 * 1024,
            request_timeout: Duration::from_secs(10),
            sessions: SessionLimits::default(),
            connections: ConnectionLimits::default(),
            json: JsonLimits::default(),
            client_rate: None,
            websocket_rate: None,
        }
    }
}

/// The state handlers see.
#[derive(Clone)]
pub struct AppState {
    inner: Arc<Shared>,
}

struct Shared {
    /// Scenes by id, each with the methods it supports; a reload swaps a
    /// scene's entry, and requests holding the old `Arc` finish on it.
    scenes: RwLock<BTreeMap<String, Arc<SceneMethods>>>,
    /// The files scenes were loaded from, by id: what a reload reads.
    files: BTreeMap<String, PathBuf>,
    /// How a reloaded scene's methods are prepared.
    registry: Registry,
    context: MethodContext,
    /// One reload at a time; and how to rank a reloaded scene, once the
    /// server ranks.
    reloading: Mutex<Option<(RankParams, Option<BakeCache>)>>,
    /// Counters and histograms behind `/metrics`.
    metrics: Metrics,
    /// Body size and time limits.
    limits: Limits,
    /// Live sessions.
    sessions: Sessions,
    /// Live walkthroughs.
    walkthroughs: Walkthroughs,
    /// The bearer token of routes that change scenes; none: they are off.
    admin_token: Option<String>,
    /// This replica's name, sent as `x-pvsd-replica` on every answer.
    replica: Option<String>,
    /// Connections and WebSockets, and the signal that ends them.
    lifecycle: Lifecycle,
    /// Each client's request rate, when limited.
    client_rate: Option<ClientRate>,
}

/// The server's connections and WebSockets as tasks, the token that
/// tells them the server is shutting down, and whether it is ready.
#[derive(Clone, Default)]
pub struct Lifecycle {
    /// Cancelled when the server begins to shut down.
    pub shutdown: CancellationToken,
    /// Every connection and WebSocket; shutdown waits for them.
    pub tasks: TaskTracker,
    /// Whether load balancers should send the server traffic.
    pub readiness: Readiness,
}

/// What `GET /healthz/ready` answers: ready once nothing is loading and
/// the server is not draining. A state made over scenes already loaded is
/// ready at once; `pvsd serve` listens first and loads after, counting
/// what is left ([`Readiness::loading`]).
#[derive(Clone, Default)]
pub struct Readiness(Arc<ReadyState>);

#[derive(Default)]
struct ReadyState {
    /// Scenes still to load and prepare.
    scenes: AtomicUsize,
    /// Scenes still to rank for `auto`.
    ranking: AtomicUsize,
    /// Told to stop: serving on only until load balancers notice.
    draining: AtomicBool,
}

impl Readiness {
    /// `scenes` are to be loaded and, when `ranked`, ranked, before the
    /// server is ready.
    pub fn loading(&self, scenes: usize, ranked: bool) {
        self.0.scenes.store(scenes, Ordering::SeqCst);
        self.0
            .ranking
            .store(if ranked { scenes } else { 0 }, Ordering::SeqCst);
    }

    /// One scene is loaded and prepared.
    pub fn scene_loaded(&self) {
        let _ = self
            .0
            .scenes
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1));
    }

    /// One scene is ranked.
    pub fn scene_ranked(&self) {
        let _ = self
            .0
            .ranking
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1));
    }

    /// Ranking is over (done, or given up: `auto` answers with frustum
    /// culling where a scene is not ranked), whatever is left of it.
    pub fn ranking_over(&self) {
        self.0.ranking.store(0, Ordering::SeqCst);
    }

    /// The server was told to stop: not ready from now on.
    pub fn drain(&self) {
        self.0.draining.store(true, Ordering::SeqCst);
    }

    /// Whether the server is draining.
    pub fn is_draining(&self) -> bool {
        self.0.draining.load(Ordering::SeqCst)
    }

    /// Ok when ready; else `not_ready` saying what it waits for.
    pub fn check(&self) -> Result<(), ApiError> {
        if self.is_draining() {
            return Err(ApiError::NotReady(
                "draining: the server is shutting down and takes no new work".into(),
            ));
        }
        let scenes = self.0.scenes.load(Ordering::SeqCst);
        if scenes > 0 {
            return Err(ApiError::NotReady(format!(
                "loading: {scenes} scene(s) still loading"
            )));
        }
        let ranking = self.0.ranking.load(Ordering::SeqCst);
        if ranking > 0 {
            return Err(ApiError::NotReady(format!(
                "loading: {ranking} scene(s) still ranking their methods for auto"
            )));
        }
        Ok(())
    }
}

/// Two scenes with one id: ids must name one scene each.
#[derive(Debug, thiserror::Error)]
#[error("two scenes are called '{0}' (a scene's id is its file stem)")]
pub struct DuplicateScene(pub String);

impl AppState {
    /// State over these scenes, each prepared with the standard methods in
    /// this machine's context.
    pub fn new(scenes: Vec<Arc<Scene>>, limits: Limits) -> Result<AppState, DuplicateScene> {
        AppState::with_methods(
            scenes,
            limits,
            &Registry::standard(),
            &MethodContext::of_this_machine(),
        )
    }

    /// State over these scenes, each prepared with `registry`'s methods in
    /// `context`.
    pub fn with_methods(
        scenes: Vec<Arc<Scene>>,
        limits: Limits,
        registry: &Registry,
        context: &MethodContext,
    ) -> Result<AppState, DuplicateScene> {
        let mut map = BTreeMap::new();
        for scene in scenes {
            let id = scene.id.clone();
            let methods = SceneMethods::prepare_with(scene, registry, context);
            if map.insert(id.clone(), Arc::new(methods)).is_some() {
                return Err(DuplicateScene(id));
            }
        }
        let metrics = Metrics::new();
        metrics.set_scenes(map.len());
        let sessions = Sessions::new(limits.sessions, &metrics);
        let walkthroughs =
            Walkthroughs::new(limits.sessions.max_walkthroughs, limits.sessions.idle);
        Ok(AppState {
            inner: Arc::new(Shared {
                scenes: RwLock::new(map),
                files: BTreeMap::new(),
                registry: registry.clone(),
                context: context.clone(),
                reloading: Mutex::new(None),
                metrics,
                limits,
                sessions,
                walkthroughs,
                admin_token: None,
                replica: None,
                lifecycle: Lifecycle::default(),
                client_rate: limits.client_rate.map(ClientRate::new),
            }),
        })
    }

    /// This state with routes that change scenes (moving objects) open to
    /// requests bearing `token`; without one they answer 403.
    ///
    /// # Panics
    /// Once the state is shared (cloned): set it right after making it.
    pub fn with_admin_token(mut self, token: Option<String>) -> AppState {
        Arc::get_mut(&mut self.inner)
            .expect("the admin token is set before the state is shared")
            .admin_token = token.filter(|t| !t.is_empty());
        self
    }

    /// This state naming its replica `name` in every answer's
    /// `x-pvsd-replica` header (several replicas behind one proxy).
    ///
    /// # Panics
    /// Once the state is shared (cloned): set it right after making it.
    pub fn with_replica(mut self, name: Option<String>) -> AppState {
        Arc::get_mut(&mut self.inner)
            .expect("the replica name is set before the state is shared")
            .replica = name;
        self
    }

    /// This replica's name, if it has one.
    pub fn replica(&self) -> Option<&str> {
        self.inner.replica.as_deref()
    }

    /// Checks a request's `Authorization` header against the admin token:
    /// 403 when the server has none, 401 when it is missing or wrong.
    pub fn authorize_admin(&self, authorization: Option<&str>) -> Result<(), ApiError> {
        let Some(token) = &self.inner.admin_token else {
            return Err(ApiError::Forbidden);
        };
        let given = authorization
            .and_then(|h| h.strip_prefix("Bearer "))
            .ok_or_else(|| {
                ApiError::Unauthorized(
                    "this route needs 'Authorization: Bearer <admin_token>'".into(),
                )
            })?;
        // Compared in time independent of where they differ.
        let same = given.len() == token.len()
            && given
                .bytes()
                .zip(token.bytes())
                .fold(0u8, |acc, (a, b)| acc | (a ^ b))
                == 0;
        if same {
            Ok(())
        } else {
            Err(ApiError::Unauthorized(
                "the bearer token is not the admin token".into(),
            ))
        }
    }

    /// Measures every scene's methods for `auto` on a thread of its own,
    /// one scene after another, each ranking read from or written to the
    /// bake cache when there is one. Until a scene's ranking is in, `auto`
    /// answers there with frustum culling; the server serves throughout
    /// (the measuring takes one core for about a second a scene). Once a
    /// scene is ranked, the methods neither `auto` chose nor a client asked
    /// for are released ([`SceneMethods::release_unasked`]) until first
    /// asked. Scenes reloaded later are ranked the same way.
    pub fn rank_in_background(
        &self,
        params: RankParams,
        cache: Option<BakeCache>,
    ) -> std::thread::JoinHandle<()> {
        *lock(&self.inner.reloading) = Some((params, cache.clone()));
        rank_on_a_thread(self.scenes(), params, cache, Some(self.readiness().clone()))
    }

    /// This state with the files its scenes were loaded from (a scene's id
    /// is its file's stem), which [`AppState::reload`] reads again.
    ///
    /// # Panics
    /// Once the state is shared (cloned): set them right after making it.
    pub fn with_scene_files(mut self, files: Vec<PathBuf>) -> AppState {
        let shared = Arc::get_mut(&mut self.inner)
            .expect("the scene files are set before the state is shared");
        for path in files {
            if let Some(id) = path.file_stem().and_then(|s| s.to_str()) {
                shared.files.insert(id.to_string(), path);
            }
        }
        self
    }

    /// Reads every scene file again and swaps in each one that changed,
    /// with its methods prepared anew (blocking: loading and preparing take
    /// seconds on a big scene). Requests in flight finish on the scene they
    /// started with; sessions move to the new one at their next frame,
    /// which answers the whole set (`base: null`). A file that did not
    /// change keeps its scene, so its ids and every session's caches stay.
    /// A file that cannot be read or loaded keeps the old scene serving,
    /// and the report and the log say why.
    pub fn reload(&self) -> ReloadReport {
        let shared = &*self.inner;
        let ranking = lock(&shared.reloading);
        let mut report = ReloadReport::default();
        let mut fresh = Vec::new();
        for (id, path) in &shared.files {
            let started = Instant::now();
            let Some(old) = self.scene(id).ok() else {
                continue;
            };
            let scene = match load_path(path) {
                Ok(scene) => scene,
                Err(e) => {
                    tracing::error!(scene = %id, "reload failed, the old scene serves on: {e}");
                    report.failed.push(ReloadFailure {
                        scene: id.clone(),
                        error: e.to_string(),
                    });
                    continue;
                }
            };
            if scene.source_hash.is_some() && scene.source_hash == old.scene().source_hash {
                report.unchanged.push(id.clone());
                continue;
            }
            let methods = Arc::new(SceneMethods::prepare_with(
                Arc::new(scene),
                &shared.registry,
                &shared.context,
            ));
            write(&shared.scenes).insert(id.clone(), methods.clone());
            tracing::info!(
                scene = %id,
                ms = started.elapsed().as_millis() as u64,
                "reloaded {}: sessions get the whole set at their next frame",
                path.display()
            );
            report.reloaded.push(id.clone());
            fresh.push(methods);
        }
        if let Some((params, cache)) = ranking.clone()
            && !fresh.is_empty()
        {
            let _ = rank_on_a_thread(fresh, params, cache, None);
        }
        report
    }

    /// Adds a scene loaded after the server started, with its methods
    /// prepared (blocking: preparing takes seconds on a big scene).
    pub fn add_scene(&self, scene: Arc<Scene>) -> Result<(), DuplicateScene> {
        let shared = &*self.inner;
        let id = scene.id.clone();
        let methods = Arc::new(SceneMethods::prepare_with(
            scene,
            &shared.registry,
            &shared.context,
        ));
        let mut scenes = write(&shared.scenes);
        if scenes.contains_key(&id) {
            return Err(DuplicateScene(id));
        }
        scenes.insert(id, methods);
        shared.metrics.set_scenes(scenes.len());
        Ok(())
    }

    /// Every scene, by id, as they are now.
    pub fn scenes(&self) -> Vec<Arc<SceneMethods>> {
        read(&self.inner.scenes).values().cloned().collect()
    }

    /// The scene `id` as it is now, or `unknown_scene` listing the loaded
    /// ones.
    pub fn scene(&self, id: &str) -> Result<Arc<SceneMethods>, ApiError> {
        let scenes = read(&self.inner.scenes);
        scenes.get(id).cloned().ok_or_else(|| {
            if self.inner.files.contains_key(id) {
                ApiError::SceneLoading(id.to_string())
            } else {
                ApiError::UnknownScene {
                    id: id.to_string(),
                    loaded: scenes.keys().cloned().collect(),
                }
            }
        })
    }

    /// The metrics.
    pub fn metrics(&self) -> &Metrics {
        &self.inner.metrics
    }

    /// The methods the server knows.
    pub fn registry(&self) -> &Registry {
        &self.inner.registry
    }

    /// The limits.
    pub fn limits(&self) -> Limits {
        self.inner.limits
    }

    /// The server's connections and its shutdown signal.
    pub fn lifecycle(&self) -> &Lifecycle {
        &self.inner.lifecycle
    }

    /// Whether the server is ready for traffic.
    pub fn readiness(&self) -> &Readiness {
        &self.inner.lifecycle.readiness
    }

    /// Each client's request rate, when the config limits it.
    pub fn client_rate(&self) -> Option<&ClientRate> {
        self.inner.client_rate.as_ref()
    }

    /// The live sessions.
    pub fn sessions(&self) -> &Sessions {
        &self.inner.sessions
    }

    /// The live walkthroughs.
    pub fn walkthroughs(&self) -> &Walkthroughs {
        &self.inner.walkthroughs
    }
}

/// Ranks `scenes` one after another on a thread of its own, releasing
/// what each ranking leaves unused (see [`AppState::rank_in_background`]).
fn rank_on_a_thread(
    scenes: Vec<Arc<SceneMethods>>,
    params: RankParams,
    cache: Option<BakeCache>,
    readiness: Option<Readiness>,
) -> std::thread::JoinHandle<()> {
    std::thread::Builder::new()
        .name("pvsd-rank".into())
        .spawn(move || {
            for methods in scenes {
                methods.set_ranking(rank_cached(&methods, &params, cache.as_ref()));
                let released = methods.release_unasked();
                tracing::info!(
                    scene = %methods.scene().id,
                    auto = methods.auto_choice(methods.frame_cost()),
                    released = ?released,
                    "ranked; methods no client asked for are released until asked"
                );
                if let Some(r) = &readiness {
                    r.scene_ranked();
                }
            }
        })
        .expect("a thread can be started")
}

// The locks guard maps changed by one insert at a time: a panic elsewhere
// cannot leave them half-changed, so a poisoned lock is still good.
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn read<T>(l: &RwLock<T>) -> std::sync::RwLockReadGuard<'_, T> {
    l.read().unwrap_or_else(|e| e.into_inner())
}

fn write<T>(l: &RwLock<T>) -> std::sync::RwLockWriteGuard<'_, T> {
    l.write().unwrap_or_else(|e| e.into_inner())
}
