//! `gpu`: hardware occlusion queries in the server (Tai & Hsu, "A
//! Visibility Pipeline toward Real-time Rendering Based on the
//! Hardware-accelerated Occlusion Query"), on a Vulkan device; lavapipe,
//! Mesa's Vulkan driver on the CPU, where the machine has no GPU.
//!
//! - [`grid`]: the scene as a regular grid organized as an octree-like
//!   hierarchy of overlapping voxels, and eye-siding numbers (§3.1, §3.3);
//! - [`movers`]: the scene's movable objects placed in the grid where they
//!   are now (§3.1's dynamic objects), so the walk culls them with the rest;
//! - [`traversal`]: one view's walk: 2-tier frustum culling with the
//!   near-face test (§3.2), parallel units in front-to-back order and
//!   multipass batched queries (§3.3), contribution and importance culling
//!   (§3.4); why it is conservative is in its module doc;
//! - [`vulkan`]: the device, the scene's triangles uploaded once (with each
//!   edge's neighbour, `adjacency.rs`, so depth is pulled in only at
//!   outlines and silhouettes), and the passes of the views of one batch
//!   run in lock-step.
//!
//! The depth buffer is drawn, by default, from occluder proxies: the
//! scene's large planar occluders (polygons merged from one object's own
//! triangles), drawn before the first query; `depth=geometry` draws the
//! real geometry of the objects found visible instead, in the order they
//! are found, as the paper does, and `depth=both` does both. The method
//! runs on the device's own thread ([`Execution::Device`]): views that
//! arrive together are one batch, and share every submission.

mod adjacency;
pub mod grid;
pub mod movers;
pub mod traversal;
pub mod vulkan;

use std::ops::Range;
use std::sync::{Arc, Mutex, OnceLock};

use glam::Vec3;

use grid::Grid;
use movers::Movers;
use traversal::{Settings, Traversal};
use vulkan::{Mask, QuerySource, SceneGeometry, Vulkan};

use crate::cull::{
    BatchItem, CullCounters, CullError, CullMethod, Culler, DeviceLimits, DeviceQueue, Execution,
    InFrustum, MethodEntry, MethodError, MethodOptions, Occludees, Preparation, Ranged, View,
    VisibleSet,
};
use crate::cull::occluder::Occluders;
use crate::scene::Scene;

/// Most queries sent at once, per view (§3.3's N).
const BATCH: Ranged<usize> = Ranged {
    key: "batch",
    noun: "a whole number",
    default: 64,
    min: 1,
    max: vulkan::MAX_QUERIES as usize,
};

/// Nodes above this depth get the CPU's frustum test instead of a query
/// (§3.2; the paper found 3 best).
const TIER: Ranged<u32> = Ranged {
    key: "tier",
    noun: "a whole number",
    default: 3,
    min: 0,
    max: 16,
};

/// Contribution culling (§3.4): a box showing at most this share of the
/// viewport's pixels is culled. Not conservative unless 0.
const CONTRIBUTION: Ranged<f64> = Ranged {
    key: "contribution",
    noun: "a ratio",
    default: 0.0,
    min: 0.0,
    max: 1.0,
};

/// Importance culling (§3.4): the mask type; not conservative unless none.
const IMPORTANCE: &str = "importance";

/// The importance mask's fill ratio: the share of the masked frame's
/// pixels that are masked off (the paper's II(0.6) is `importance=II:fill=0.6`).
const FILL: Ranged<f64> = Ranged {
    key: "fill",
    noun: "a ratio",
    default: 0.6,
    min: 0.0,
    max: 1.0,
};

/// What is drawn into each view's depth buffer: `proxies` (the scene's
/// large occluders, drawn first; the default: on every scene measured as
/// tight as `both` and 1.4–10× faster, docs/gpu.md), `both` (the proxies,
/// then the objects found visible) or `geometry` (only the objects found
/// visible, as in the paper). A scene without proxies draws its visible
/// objects whatever the choice. Every choice is conservative: all are
/// real surfaces.
const DEPTH: &str = "depth";

/// `merge=false`: every parallel unit is its own pass, as in the paper;
/// by default units that follow join a pass while it has room.
const MERGE: &str = "merge";

const OPTIONS: [&str; 7] = [
    MERGE,
    BATCH.key,
    TIER.key,
    CONTRIBUTION.key,
    IMPORTANCE,
    FILL.key,
    DEPTH,
];

/// The method's registry entry; the table checks one query at a time and
/// queries from the root too.
pub const ENTRY: MethodEntry = MethodEntry {
    name: "gpu",
    purpose: "hardware occlusion queries on a Vulkan device, lavapipe on the CPU (Tai & Hsu)",
    options: &OPTIONS,
    checked_with: &["batch=1", "tier=0"],
    regions: Some("its occlusion queries are drawn at the request's viewport for one camera, and its occluder proxies are not shrunk for a ball of eyes"),
    build,
};

fn build(p: &Preparation<'_>) -> Result<Arc<dyn Culler>, String> {
    let gpu = p.context().gpu.clone()?;
    let proxies = p.occluders().map(|o| proxy_fans(&o)).unwrap_or_default();
    Ok(Arc::new(GpuCulling::new(p.scene().clone(), gpu, &proxies)?))
}

/// The scene's large planar occluders as fans of triangles, one fan a
/// polygon: each is a union of one object's own triangles, so drawing them
/// first puts only real surfaces into the depth buffer.
fn proxy_fans(occluders: &Occluders) -> Vec<Vec<[Vec3; 3]>> {
    occluders
        .all()
        .iter()
        .map(|o| {
            let v = &o.polygon.vertices;
            (1..v.len().saturating_sub(1))
                .map(|i| [v[0].as_vec3(), v[i].as_vec3(), v[i + 1].as_vec3()])
                .collect()
        })
        .collect()
}

/// The machine's Vulkan device and the thread that drives it.
pub struct Gpu {
    vulkan: Vulkan,
    queue: Arc<DeviceQueue>,
}

impl std::fmt::Debug for Gpu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gpu")
            .field("device", &self.vulkan.name())
            .finish_non_exhaustive()
    }
}

impl Gpu {
    /// Opens the machine's Vulkan device and starts its thread.
    pub fn open(limits: DeviceLimits) -> Result<Arc<Gpu>, String> {
        let vulkan = Vulkan::open()?;
        let queue = DeviceQueue::start("gpu", limits)
            .map_err(|e| format!("starting the device thread: {e}"))?;
        Ok(Arc::new(Gpu { vulkan, queue }))
    }

    /// The machine's device, opened once per process; the error says why
    /// there is none.
    pub fn of_this_machine() -> Result<Arc<Gpu>, String> {
        static GPU: OnceLock<Result<Arc<Gpu>, String>> = OnceLock::new();
        GPU.get_or_init(|| Gpu::open(DeviceLimits::default()))
            .clone()
    }

    /// The device itself (tests count a query's pixels with it).
    pub fn vulkan(&self) -> &Vulkan {
        &self.vulkan
    }
}

/// Occlusion queries over a grid hierarchy of one scene, on the device.
pub struct GpuCulling {
    scene: Arc<Scene>,
    grid: Grid,
    gpu: Arc<Gpu>,
    geometry: SceneGeometry,
    /// Where the occluder proxies are in `geometry`, in triangles.
    proxies: Range<u32>,
    /// The movable objects placed in the grid (used by the device thread).
    movers: Mutex<Movers>,
}

impl GpuCulling {
    /// The method for `scene` on `gpu`, with `proxies` (polygons as fans
    /// of triangles lying on the scene's opaque surfaces) drawn first into
    /// every view's depth; everything is uploaded now.
    pub fn new(
        scene: Arc<Scene>,
        gpu: Arc<Gpu>,
        proxies: &[Vec<[Vec3; 3]>],
    ) -> Result<GpuCulling, String> {
        let start = scene.triangles().len() as u32;
        let mut triangles = scene.triangles().to_vec();
        // Edges are shared within an object's opaque triangles, or within
        // one proxy polygon.
        let mut groups: Vec<Vec<Range<u32>>> =
            scene.objects().iter().map(|o| o.opaque_ranges()).collect();
        for fan in proxies {
            let at = triangles.len() as u32;
            triangles.extend_from_slice(fan);
            groups.push(std::iter::once(at..triangles.len() as u32).collect());
        }
        let started = std::time::Instant::now();
        let apices = adjacency::neighbours(&triangles, &groups);
        let adjacency_ms = started.elapsed().as_secs_f64() * 1e3;
        let proxies = &triangles[start as usize..];
        let geometry = gpu.vulkan.upload(&scene, proxies, &apices)?;
        tracing::debug!(
            scene = %scene.id,
            triangles = triangles.len(),
            adjacency_ms,
            upload_ms = started.elapsed().as_secs_f64() * 1e3 - adjacency_ms,
            "gpu geometry"
        );
        Ok(GpuCulling {
            grid: Grid::build(&scene),
            scene,
            gpu,
            geometry,
            proxies: start..start + proxies.len() as u32,
            movers: Mutex::new(Movers::default()),
        })
    }
}

impl Drop for GpuCulling {
    fn drop(&mut self) {
        // The device thread holds the method while it runs a batch of it,
        // so nothing on the device uses this scene's triangles now.
        self.gpu.vulkan.release(&self.geometry);
    }
}

/// A client's options (nothing carries over between frames: the depth
/// buffer is drawn again for every view).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuState {
    batch: usize,
    tier: u32,
    contribution: f64,
    mask: Option<Mask>,
    depth: &'static str,
    merge: bool,
}

impl GpuState {
    fn settings(&self, view: &View, proxies: &Range<u32>) -> Settings {
        let [w, h] = view.camera().viewport;
        Settings {
            batch: self.batch,
            tier: self.tier,
            threshold: (self.contribution * w as f64 * h as f64).floor() as u64,
            mask: self.mask,
            proxies: (self.depth != "geometry" && !proxies.is_empty()).then(|| proxies.clone()),
            draw_visible: self.depth != "proxies" || proxies.is_empty(),
            merge: self.merge,
        }
    }
}

impl CullMethod for GpuCulling {
    type State = GpuState;

    fn name(&self) -> &'static str {
        "gpu"
    }

    fn new_state(&self, options: &MethodOptions) -> Result<GpuState, MethodError> {
        let r = options.reader("gpu", &OPTIONS);
        let mask = match r.choice(IMPORTANCE, &["none", "I", "II"])? {
            "I" => Some(1),
            "II" => Some(2),
            _ => None,
        };
        let fill = r.ranged(&FILL)?;
        let state = GpuState {
            batch: r.ranged(&BATCH)?,
            tier: r.ranged(&TIER)?,
            contribution: r.ranged(&CONTRIBUTION)?,
            mask: mask.map(|kind| Mask {
                kind,
                fill: fill as f32,
            }),
            depth: r.choice(DEPTH, &["proxies", "both", "geometry"])?,
            merge: r.flag(MERGE, true)?,
        };
        r.finish()?;
        Ok(state)
    }

    fn is_conservative(&self, state: &GpuState) -> bool {
        state.contribution == 0.0 && state.mask.is_none_or(|m| m.fill == 0.0)
    }

    fn execution(&self) -> Execution {
        Execution::Device(self.gpu.queue.clone())
    }

    /// Movers are walked in the grid with everything else (§3.1).
    fn culls_movers(&self) -> bool {
        true
    }

    fn cull(
        &self,
        view: &View,
        state: &mut GpuState,
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        let mut item = [BatchItem {
            view,
            state,
            out,
            occludees,
        }];
        CullMethod::cull_batch(self, &mut item)
            .pop()
            .expect("one answer")
    }

    /// The batch's views share every submission ([`Vulkan::run`]).
    fn cull_batch(
        &self,
        batch: &mut [BatchItem<'_, GpuState>],
    ) -> Vec<Result<CullCounters, CullError>> {
        let mut movers = self.movers.lock().unwrap_or_else(|p| p.into_inner());
        movers.update(&self.grid, &self.scene);
        let movers = &*movers;
        let mut walks: Vec<Traversal<'_>> = batch
            .iter_mut()
            .map(|b| {
                let settings = b.state.settings(b.view, &self.proxies);
                Traversal::new(
                    &self.grid,
                    movers,
                    &self.scene,
                    b.view,
                    settings,
                    b.out,
                    b.occludees,
                )
            })
            .collect();
        let mut sources: Vec<&mut dyn QuerySource> = walks
            .iter_mut()
            .map(|w| w as &mut dyn QuerySource)
            .collect();
        let ran = self.gpu.vulkan.run(&self.geometry, &mut sources);
        drop(sources);
        match ran {
            Ok(times) => {
                tracing::debug!(
                    views = walks.len(),
                    steps = times.steps,
                    queries = walks.iter().map(|w| w.queries).sum::<u64>(),
                    record_ms = times.record_s * 1e3,
                    device_ms = times.device_s * 1e3,
                    readback_ms = times.readback_s * 1e3,
                    "gpu batch"
                );
                walks
                .iter()
                .map(|w| {
                    Ok(CullCounters {
                        nodes_tested: w.tested,
                        in_frustum: InFrustum::Unknown,
                    })
                })
                .collect()
            }
            Err(reason) => walks
                .iter()
                .map(|_| {
                    Err(CullError::Failed {
                        method: "gpu",
                        reason: reason.clone(),
                    })
                })
                .collect(),
        }
    }
}
