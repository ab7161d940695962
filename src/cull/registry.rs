//! The list of methods, and a scene prepared with the ones it supports.
//!
//! A [`Registry`] is one list of [`MethodEntry`]: a name, what the method
//! is for, and how to build it for a scene, or why the scene cannot have
//! it. [`SceneMethods::prepare`] runs every entry against one scene with a
//! [`Preparation`]: the scene, the [`MethodContext`] (configuration, the
//! bake cache's folder, a device), and what several methods share (the
//! kd-tree, the occluders), each built once and only when an entry asks
//! for it, so a scene keeps only what its methods need.
//!
//! A new method is its folder under `cull/` (with its `ENTRY`) and its name
//! in the `methods!` list of `cull/mod.rs`; [`Registry::standard`], the
//! server, eval, `/scenes` and the conservativeness table
//! (tests/conservative.rs) take it from there.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock, Weak};

use super::ddo::OctreeParams;
use super::device::DeviceQueue;
use super::dispatch::cull_here;
use super::frustum::FrustumCulling;
use super::gpu::Gpu;
use super::horizon::Prisms;
use super::occluder::Occluders;
use super::ranking::{FrameCost, Ranking};
use super::{ClientCache, CullStats, Culler, METHOD_NAMES, MethodError, MethodOptions, MethodSpec};
use super::{CullError, CullJob, Execution, View, VisibleSet};
use crate::scene::{BakeCache, Scene};
use crate::spatial::{KdTree, KdTreeParams};

/// What preparing methods may use beyond the scene itself.
#[derive(Clone, Debug)]
pub struct MethodContext {
    /// How the shared kd-tree is built.
    pub kd_tree: KdTreeParams,
    /// Where baked data (DDO masks, occluder proxies) is cached between
    /// runs; `None` keeps bakes in memory only.
    pub bake_dir: Option<PathBuf>,
    /// The device that device methods submit to; `None` when the machine
    /// has none (those methods are then unsupported, with that reason).
    pub device: Option<Arc<DeviceQueue>>,
    /// The Vulkan device `gpu` runs on, or why there is none.
    pub gpu: Result<Arc<Gpu>, String>,
    /// Methods the operator turned off; listed as unsupported with that reason.
    pub disabled: Vec<String>,
    /// The prices `auto` ranks methods with when a request names none.
    pub frame_cost: FrameCost,
    /// How `ddo`'s octree is cut: its leaf size is the paper's threshold,
    /// trading bake and cull time for occluders near the geometry.
    pub ddo_octree: OctreeParams,
}

impl Default for MethodContext {
    /// Nothing but the scene: no device, no bake cache, every method on.
    fn default() -> Self {
        MethodContext {
            kd_tree: KdTreeParams::default(),
            bake_dir: None,
            device: None,
            gpu: Err("no Vulkan device in this context".into()),
            disabled: Vec::new(),
            frame_cost: FrameCost::default(),
            ddo_octree: OctreeParams::default(),
        }
    }
}

impl MethodContext {
    /// The context with `ddo`'s octree split above `n` triangles a leaf,
    /// or why `n` is out of range: the server's configuration checks its
    /// value here, so `server/` holds no method's parameter types.
    pub fn with_ddo_leaf_triangles(self, n: usize) -> Result<MethodContext, String> {
        Ok(MethodContext {
            ddo_octree: OctreeParams::with_leaf_triangles(n)?,
            ..self
        })
    }

    /// What this machine offers the methods: its Vulkan device if it has
    /// one (opened once per process), nothing baked on disk, every method
    /// on. The server starts from it (adding its configuration), and so do
    /// [`SceneMethods::prepare`], eval and the conservativeness table, so a
    /// device method is checked wherever it would serve.
    pub fn of_this_machine() -> MethodContext {
        MethodContext {
            gpu: Gpu::of_this_machine(),
            ..MethodContext::default()
        }
    }
}

/// One scene being prepared: what an entry's `build` reads.
pub struct Preparation<'a> {
    scene: &'a Arc<Scene>,
    context: &'a MethodContext,
    kd_tree: OnceLock<Arc<KdTree>>,
    occluders: OnceLock<Option<Arc<Occluders>>>,
    prisms: OnceLock<Result<Arc<Prisms>, String>>,
}

impl<'a> Preparation<'a> {
    fn new(scene: &'a Arc<Scene>, context: &'a MethodContext) -> Self {
        Preparation {
            scene,
            context,
            kd_tree: OnceLock::new(),
            occluders: OnceLock::new(),
            prisms: OnceLock::new(),
        }
    }

    /// A preparation that starts from what an earlier one built and is
    /// still held by some method (a released method built again shares
    /// the kd-tree and the occluders of those still resident).
    fn resuming(scene: &'a Arc<Scene>, context: &'a MethodContext, shared: &Shared) -> Self {
        let prep = Preparation::new(scene, context);
        let _ = prep.kd_tree.set(shared.kd_tree.clone());
        if let Some(occluders) = shared.occluders.upgrade() {
            let _ = prep.occluders.set(Some(occluders));
        }
        if let Some(prisms) = shared.prisms.upgrade() {
            let _ = prep.prisms.set(Ok(prisms));
        }
        prep
    }

    /// What it built that later builds may share.
    fn shared(&self) -> Shared {
        Shared {
            kd_tree: self.kd_tree(),
            occluders: match self.occluders.get() {
                Some(Some(o)) => Arc::downgrade(o),
                _ => Weak::new(),
            },
            prisms: match self.prisms.get() {
                Some(Ok(p)) => Arc::downgrade(p),
                _ => Weak::new(),
            },
        }
    }

    /// The scene.
    pub fn scene(&self) -> &Arc<Scene> {
        self.scene
    }

    /// The context the scene is prepared in.
    pub fn context(&self) -> &MethodContext {
        self.context
    }

    /// The scene's kd-tree, built on first use and shared by every method.
    pub fn kd_tree(&self) -> Arc<KdTree> {
        self.kd_tree
            .get_or_init(|| Arc::new(KdTree::build(self.scene, self.context.kd_tree)))
            .clone()
    }

    /// The scene's large planar occluders, found on first use (read from
    /// the bake cache when the context has one and an earlier run baked
    /// them); `None` when it has none large enough to be worth testing
    /// against.
    pub fn occluders(&self) -> Option<Arc<Occluders>> {
        self.occluders
            .get_or_init(|| {
                let tree = self.kd_tree();
                match &self.context.bake_dir {
                    Some(dir) => Occluders::find_baked(self.scene, &tree, &BakeCache::new(dir)),
                    None => Occluders::find(self.scene, &tree),
                }
                .map(Arc::new)
            })
            .clone()
    }

    /// The convex vertical prisms inside the scene's objects (read from the
    /// bake cache when the context has one), or why the scene is no
    /// height field over a ground.
    pub fn prisms(&self) -> Result<Arc<Prisms>, String> {
        self.prisms
            .get_or_init(|| {
                match &self.context.bake_dir {
                    Some(dir) => Prisms::find_baked(self.scene, &BakeCache::new(dir)),
                    None => Prisms::find(self.scene),
                }
                .map(Arc::new)
            })
            .clone()
    }

    /// The occluders, or the reason every occluder-based method gives.
    pub fn require_occluders(&self) -> Result<Arc<Occluders>, String> {
        self.occluders()
            .ok_or_else(|| "no opaque planar occluder is large enough against the scene".into())
    }
}

/// Builds a method for a scene, or says why the scene cannot have it.
pub type Build = fn(&Preparation<'_>) -> Result<Arc<dyn Culler>, String>;

/// One method of the registry.
#[derive(Clone, Copy)]
pub struct MethodEntry {
    /// Its name in requests, one of [`METHOD_NAMES`] for the standard ones.
    pub name: &'static str,
    /// What it is for, in a line (the README's method table).
    pub purpose: &'static str,
    /// Option sets, besides the defaults, that change how it decides what
    /// is hidden (`variant=fse`, `k=8:temporal=false`): the
    /// conservativeness table (tests/conservative.rs) checks each.
    pub checked_with: &'static [&'static str],
    /// The options it takes (`GET /scenes` lists them for clients' forms).
    pub options: &'static [&'static str],
    /// Whether it answers for a region of views (a request's `radius` and
    /// `angle`): `None` when it does, else why not (a request with a region
    /// is refused with this reason).
    pub regions: Option<&'static str>,
    /// How to build it for one scene.
    pub build: Build,
}

impl std::fmt::Debug for MethodEntry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MethodEntry")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

/// The methods a server knows, in the order `/scenes` lists them.
#[derive(Clone, Debug)]
pub struct Registry {
    entries: Vec<MethodEntry>,
}

/// A blocking method measured at under this many microseconds a frame on a
/// scene runs inline there ([`SceneMethods::execution_of`]): handing a cull
/// to the blocking pool costs a wake-up and a context switch each way,
/// which for the horizon's ~100 µs culls of the 10k city was 15% of the
/// frames a server could serve (README, "Load tests"), while 200 µs on an
/// async worker delays the requests queued behind it by less than the
/// network does.
pub const INLINE_BELOW_US: f64 = 200.0;

/// The method `auto` answers with until the scene's methods are ranked
/// ([`SceneMethods::set_ranking`]): the exact in-frustum set, which never
/// costs much.
pub const AUTO_CHOICE: &str = "frustum";

impl Registry {
    /// Every method of DESIGN's list, in its order (declared in
    /// `cull/mod.rs`, each entry in its folder).
    pub fn standard() -> Registry {
        Registry {
            entries: super::BUILT.to_vec(),
        }
    }

    /// This registry with one more entry (a test's method, a plug-in);
    /// an entry of the same name is replaced.
    pub fn with(mut self, entry: MethodEntry) -> Registry {
        self.entries.retain(|e| e.name != entry.name);
        self.entries.push(entry);
        self
    }

    /// The entries, in order.
    pub fn entries(&self) -> &[MethodEntry] {
        &self.entries
    }

    /// Whether `name` is one of its methods.
    pub fn knows(&self, name: &str) -> bool {
        self.entries.iter().any(|e| e.name == name)
    }
}

impl Default for Registry {
    fn default() -> Self {
        Registry::standard()
    }
}

/// A method a scene does not support, and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Unsupported {
    /// The method.
    pub method: &'static str,
    /// Why, in a sentence for `/scenes`.
    pub reason: String,
}

/// What a preparation built that a released method, built again, reuses:
/// the kd-tree (frustum culling keeps it), and the occluders and prisms
/// while any method still holds them.
struct Shared {
    kd_tree: Arc<KdTree>,
    occluders: Weak<Occluders>,
    prisms: Weak<Prisms>,
}

/// One supported method of a scene: built at preparation, released by
/// [`SceneMethods::release_unasked`] while no client has asked for it, and
/// built again, the same, on its first ask.
struct Slot {
    entry: MethodEntry,
    /// The method while its data is in memory.
    resident: Mutex<Option<Arc<dyn Culler>>>,
    /// Whether a client has asked for it (it then stays resident).
    asked: AtomicBool,
    /// Whether its build reads a device, which may differ the next time:
    /// such a method is never released.
    on_device: bool,
}

/// A scene with the methods it supports, ready to answer views.
///
/// Built once per scene at load; what it answers with is read-only
/// afterwards and shared between requests. A method whose data no
/// ranking chose and no client asked for may be released
/// ([`SceneMethods::release_unasked`]) and is then built again when first
/// asked: the same build of the same scene, so the same answers.
pub struct SceneMethods {
    scene: Arc<Scene>,
    /// Supported methods, in registry order.
    slots: Vec<Slot>,
    /// The registry's other methods, with why.
    unsupported: Vec<Unsupported>,
    /// What answers when a method fails: frustum culling, which cannot.
    fallback: Arc<dyn Culler>,
    /// Every name a request may use here (the registry's and `auto`).
    known: Vec<&'static str>,
    /// The measured ranking `auto` answers from, once there is one.
    ranking: OnceLock<Ranking>,
    /// The prices `auto` ranks with when a request names none.
    frame_cost: FrameCost,
    /// The context the methods were built in, to build a released one again.
    context: MethodContext,
    /// What builds share; locked while a released method is built again,
    /// so two first asks build it once.
    shared: Mutex<Shared>,
}

impl std::fmt::Debug for SceneMethods {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneMethods")
            .field("scene", &self.scene.id)
            .field("methods", &self.names())
            .field("resident", &self.resident())
            .finish_non_exhaustive()
    }
}

impl SceneMethods {
    /// Prepares `scene` with the standard registry in this machine's
    /// context ([`MethodContext::of_this_machine`]).
    pub fn prepare(scene: Arc<Scene>) -> SceneMethods {
        SceneMethods::prepare_with(
            scene,
            &Registry::standard(),
            &MethodContext::of_this_machine(),
        )
    }

    /// Prepares what `scene`'s methods need and nothing more.
    pub fn prepare_with(
        scene: Arc<Scene>,
        registry: &Registry,
        context: &MethodContext,
    ) -> SceneMethods {
        let prep = Preparation::new(&scene, context);
        let mut methods = Vec::new();
        let mut unsupported = Vec::new();
        for entry in registry.entries() {
            let built = if context.disabled.iter().any(|d| d == entry.name) {
                Err("disabled by the server's configuration".to_string())
            } else {
                (entry.build)(&prep)
            };
            match built {
                Ok(method) => {
                    debug_assert_eq!(method.name(), entry.name, "an entry builds its own method");
                    methods.push(Slot {
                        entry: *entry,
                        on_device: matches!(method.execution(), Execution::Device(_)),
                        resident: Mutex::new(Some(method)),
                        asked: AtomicBool::new(false),
                    });
                }
                Err(reason) => unsupported.push(Unsupported {
                    method: entry.name,
                    reason,
                }),
            }
        }
        let fallback: Arc<dyn Culler> = match methods.iter().find(|m| m.entry.name == "frustum") {
            Some(f) => f.built().expect("just built"),
            None => Arc::new(FrustumCulling::new(scene.clone(), prep.kd_tree())),
        };
        let known = registry
            .entries()
            .iter()
            .map(|e| e.name)
            .chain(["auto"])
            .collect();
        let shared = prep.shared();
        SceneMethods {
            scene,
            slots: methods,
            unsupported,
            fallback,
            known,
            ranking: OnceLock::new(),
            frame_cost: context.frame_cost,
            context: context.clone(),
            shared: Mutex::new(shared),
        }
    }

    /// Installs the measured ranking `auto` answers from (the first one
    /// given; false when one was there already).
    pub fn set_ranking(&self, ranking: Ranking) -> bool {
        self.ranking.set(ranking).is_ok()
    }

    /// The measured ranking, once [`SceneMethods::set_ranking`] gave one.
    pub fn ranking(&self) -> Option<&Ranking> {
        self.ranking.get()
    }

    /// Where `method` runs for this scene: where it says, except that a
    /// blocking method the ranking measured at under [`INLINE_BELOW_US`] a
    /// frame here runs inline on the async worker.
    pub fn execution_of(&self, method: &dyn Culler) -> Execution {
        match method.execution() {
            Execution::Blocking
                if self.ranking().is_some_and(|r| {
                    r.measured
                        .iter()
                        .any(|m| m.method == method.name() && m.mean_cull_us < INLINE_BELOW_US)
                }) =>
            {
                Execution::Inline
            }
            other => other,
        }
    }

    /// The prices `auto` ranks with when a request names none.
    pub fn frame_cost(&self) -> FrameCost {
        self.frame_cost
    }

    /// The context the methods were built in.
    pub fn context(&self) -> &MethodContext {
        &self.context
    }

    /// The method `auto` answers with at these prices: the ranking's
    /// cheapest, or [`AUTO_CHOICE`] before there is a ranking (or when the
    /// ranking's best is not supported here).
    pub fn auto_choice(&self, cost: FrameCost) -> &'static str {
        let best = self.ranking().and_then(|r| r.best(cost));
        self.slots
            .iter()
            .map(|s| s.entry.name)
            .find(|&name| Some(name) == best)
            .unwrap_or(AUTO_CHOICE)
    }

    /// [`SceneMethods::auto_choice`] among the methods that answer for a
    /// region of views ([`MethodEntry::regions`]).
    fn auto_choice_for_regions(&self, cost: FrameCost) -> &'static str {
        let ranking = self.ranking();
        ranking
            .iter()
            .flat_map(|r| r.ranked(cost))
            .find_map(|(m, _)| {
                self.slot(&m.method)
                    .filter(|s| s.entry.regions.is_none())
                    .map(|s| s.entry.name)
            })
            .unwrap_or(AUTO_CHOICE)
    }

    /// The scene's methods that answer for a region of views.
    pub fn answering_regions(&self) -> Vec<&'static str> {
        self.slots
            .iter()
            .filter(|s| s.entry.regions.is_none())
            .map(|s| s.entry.name)
            .collect()
    }

    /// [`SceneMethods::resolve`] for a request that asks for a region of
    /// views when `regions`: `auto` picks the best method that answers for
    /// one, and a named method that cannot is refused with its reason.
    pub fn resolve_for(
        &self,
        spec: &MethodSpec,
        regions: bool,
    ) -> Result<(Arc<dyn Culler>, MethodOptions), MethodError> {
        if !regions {
            return self.resolve(spec);
        }
        if spec.name == "auto" {
            let cost = FrameCost::read(&spec.options, self.frame_cost)?;
            let name = self.auto_choice_for_regions(cost);
            return Ok((self.get(name)?, MethodOptions::default()));
        }
        self.check_regions(&spec.name)?;
        self.resolve(spec)
    }

    /// Whether the method named answers for a region of views.
    pub fn answers_regions(&self, name: &str) -> bool {
        self.check_regions(name).is_ok()
    }

    /// Refuses a method that cannot answer for a region of views, with why.
    pub fn check_regions(&self, name: &str) -> Result<(), MethodError> {
        match self.slot(name).and_then(|s| s.entry.regions) {
            Some(reason) => Err(MethodError::NoRegions {
                name: name.to_string(),
                reason: reason.to_string(),
                answering: self
                    .answering_regions()
                    .into_iter()
                    .chain(["auto"])
                    .map(String::from)
                    .collect(),
            }),
            None => Ok(()),
        }
    }

    /// The method a spec names with the options it gets: `auto` reads its
    /// prices (`cost_per_triangle_ns`, `cost_per_byte_ns`) and hands its
    /// choice the choice's defaults. A released method is built again
    /// here (see [`SceneMethods::is_resident`]).
    pub fn resolve(
        &self,
        spec: &MethodSpec,
    ) -> Result<(Arc<dyn Culler>, MethodOptions), MethodError> {
        if spec.name == "auto" {
            let cost = FrameCost::read(&spec.options, self.frame_cost)?;
            return Ok((self.get(self.auto_choice(cost))?, MethodOptions::default()));
        }
        Ok((self.get(&spec.name)?, spec.options.clone()))
    }

    /// Whether the method a spec names is in memory, so that resolving it
    /// takes no build; false for a name it does not know (resolving that
    /// fails at once).
    pub fn is_resident(&self, spec: &MethodSpec) -> bool {
        self.is_resident_for(spec, false)
    }

    /// [`SceneMethods::is_resident`] for a client that asks for regions
    /// when `regions` (`auto` may pick another method then).
    pub fn is_resident_for(&self, spec: &MethodSpec, regions: bool) -> bool {
        let name = if spec.name == "auto" {
            match FrameCost::read(&spec.options, self.frame_cost) {
                Ok(cost) if regions => self.auto_choice_for_regions(cost),
                Ok(cost) => self.auto_choice(cost),
                Err(_) => return true,
            }
        } else {
            spec.name.as_str()
        };
        self.slot(name).is_none_or(|s| s.built().is_some())
    }

    /// The supported methods whose data is in memory, in registry order.
    pub fn resident(&self) -> Vec<&'static str> {
        self.slots
            .iter()
            .filter(|s| s.built().is_some())
            .map(|s| s.entry.name)
            .collect()
    }

    /// Releases every method no client has asked for, except frustum
    /// culling (the fallback), `auto`'s choice at the configured prices and
    /// device methods; returns the names released. Its data is freed once
    /// the last client holding it lets go, and built again on the next ask.
    pub fn release_unasked(&self) -> Vec<&'static str> {
        let keep = self.auto_choice(self.frame_cost);
        let mut released = Vec::new();
        for slot in &self.slots {
            let name = slot.entry.name;
            if name == self.fallback.name()
                || name == keep
                || slot.on_device
                || slot.asked.load(Ordering::Acquire)
            {
                continue;
            }
            if slot.resident.lock().expect("slot lock").take().is_some() {
                released.push(name);
            }
        }
        released
    }

    /// Methods of the registry this scene does not support, with why.
    pub fn unsupported(&self) -> &[Unsupported] {
        &self.unsupported
    }

    /// The scene.
    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }

    /// Names of the methods this scene supports, in registry order (`auto` excluded).
    pub fn names(&self) -> Vec<&'static str> {
        self.slots.iter().map(|s| s.entry.name).collect()
    }

    /// The supported methods, in registry order, building any released one
    /// again (ranking runs them all; a client's ask goes through
    /// [`SceneMethods::get`]). One that cannot be built again is left out,
    /// with a logged reason.
    pub fn methods(&self) -> Vec<Arc<dyn Culler>> {
        self.slots
            .iter()
            .filter_map(|s| {
                self.built(s)
                    .inspect_err(|e| tracing::error!(error = %e, "method left out"))
                    .ok()
            })
            .collect()
    }

    /// The method that answers when another fails (frustum culling).
    pub fn fallback(&self) -> &Arc<dyn Culler> {
        &self.fallback
    }

    /// The method called `name`, built again if it was released, and kept
    /// in memory from now on; `auto` is its choice at the configured
    /// prices ([`SceneMethods::auto_choice`]).
    pub fn get(&self, name: &str) -> Result<Arc<dyn Culler>, MethodError> {
        let name = if name == "auto" {
            self.auto_choice(self.frame_cost)
        } else {
            name
        };
        if let Some(slot) = self.slot(name) {
            slot.asked.store(true, Ordering::Release);
            return self.built(slot);
        }
        if name == self.fallback.name() {
            return Ok(self.fallback.clone());
        }
        if self.known.contains(&name) || METHOD_NAMES.contains(&name) {
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

    fn slot(&self, name: &str) -> Option<&Slot> {
        self.slots.iter().find(|s| s.entry.name == name)
    }

    /// The slot's method, built again from the scene and context if it was
    /// released.
    fn built(&self, slot: &Slot) -> Result<Arc<dyn Culler>, MethodError> {
        if let Some(method) = slot.built() {
            return Ok(method);
        }
        let mut shared = self.shared.lock().expect("shared lock");
        // Another first ask may have built it while this one waited.
        if let Some(method) = slot.built() {
            return Ok(method);
        }
        let start = std::time::Instant::now();
        let prep = Preparation::resuming(&self.scene, &self.context, &shared);
        let method = (slot.entry.build)(&prep).map_err(|reason| MethodError::NotRebuilt {
            name: slot.entry.name.into(),
            scene: self.scene.id.clone(),
            reason,
        })?;
        tracing::info!(
            scene = %self.scene.id,
            method = slot.entry.name,
            ms = start.elapsed().as_secs_f64() * 1e3,
            "built a released method again on its first ask"
        );
        *shared = prep.shared();
        *slot.resident.lock().expect("slot lock") = Some(method.clone());
        Ok(method)
    }

    /// Resolves a spec to its method and a fresh client cache.
    pub fn prepare_client(
        &self,
        spec: &MethodSpec,
    ) -> Result<(Arc<dyn Culler>, ClientCache), MethodError> {
        self.prepare_client_for(spec, false)
    }

    /// [`SceneMethods::prepare_client`] for a client that asks for regions
    /// of views when `regions` ([`SceneMethods::resolve_for`]).
    pub fn prepare_client_for(
        &self,
        spec: &MethodSpec,
        regions: bool,
    ) -> Result<(Arc<dyn Culler>, ClientCache), MethodError> {
        let (method, options) = self.resolve_for(spec, regions)?;
        let cache = method.new_cache(&options)?;
        Ok((method, cache))
    }

    /// One stateless answer on this thread: a fresh cache, one view, and
    /// no fallback, so a method that fails says so (the command line and
    /// tests; never from an async worker, since a device method waits for
    /// its device here).
    pub fn cull_once(
        &self,
        spec: &MethodSpec,
        view: &View,
        out: &mut VisibleSet,
    ) -> Result<CullStats, CullOnceError> {
        let (method, cache) = self.prepare_client(spec)?;
        let culled = cull_here(&self.scene, &method, CullJob::new(*view, cache))?;
        *out = culled.job.out;
        Ok(culled.stats)
    }
}

impl Slot {
    /// The method, if it is in memory.
    fn built(&self) -> Option<Arc<dyn Culler>> {
        self.resident.lock().expect("slot lock").clone()
    }
}

/// Why [`SceneMethods::cull_once`] gave no answer.
#[derive(Debug, thiserror::Error)]
pub enum CullOnceError {
    /// The method or its options were refused.
    #[error(transparent)]
    Method(#[from] MethodError),
    /// The method could not answer.
    #[error(transparent)]
    Cull(#[from] CullError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_standard_registry_is_designs_list_in_its_order() {
        let names: Vec<&str> = Registry::standard()
            .entries()
            .iter()
            .map(|e| e.name)
            .collect();
        let design: Vec<&str> = METHOD_NAMES
            .iter()
            .copied()
            .filter(|&n| n != "auto")
            .collect();
        assert_eq!(names, design);
    }
}
