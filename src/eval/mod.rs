//! `pvsd eval`: every method's speed against its accuracy, on the same frames.
//!
//! A walkthrough ([`walk`]) gives the cameras. Each method first culls the
//! whole walk on its own, frame after frame with its client cache carried
//! as a session would (over unrelated `views`, each frame gets a fresh
//! cache, as a stateless request does): its times are those of a server
//! serving frames, not of a method run after a truth render has swept the
//! CPU's caches. Then each frame's ground truth is rendered once
//! ([`Truth`]) and every method's answer is compared with it. The metrics are DESIGN's ("`pvsd
//! eval --json` output"), plus a frame-cost model after the "Speedup" column
//! of Bittner et al.'s Table 2: cull time + PVS triangles × a cost per
//! triangle, so the report shows when culling pays.

mod clock;
mod rank;
mod region;
mod report;
mod walk;

use std::sync::Arc;
use std::time::Instant;

pub use rank::{RankParams, rank, rank_cached};
pub use region::{request_share, sample_cameras};
pub use report::{EvalReport, MethodReport, RegionReport, write_svg};
pub use walk::{WalkError, WalkKind, WalkParams, resample, walk};

use crate::cull::dispatch::cull_here;
use crate::cull::frustum::FrustumCulling;
use crate::cull::{
    ClientCache, CullError, CullJob, Culler, MethodError, MethodOptions, MethodSpec, SceneMethods,
    View, VisibleSet,
};
use crate::geom::{Camera, Region};
use crate::scene::Scene;
use crate::truth::Truth;

/// What to evaluate on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvalParams {
    /// The walkthrough.
    pub walk: WalkParams,
    /// Modelled cost of drawing one triangle, nanoseconds (frame cost =
    /// cull time + PVS triangles × this).
    pub cost_per_triangle_ns: f64,
    /// The region every answer must hold for (`--radius`, `--angle`):
    /// each frame's answer is held to the truths of cameras sampled in it
    /// ([`sample_cameras`]).
    pub region: Region,
    /// The speed of the walking client whose requests a region saves
    /// ([`request_share`]), scene units per second.
    pub walker_speed: f64,
}

impl Default for EvalParams {
    fn default() -> Self {
        // ~2 ns a triangle: a mid-range GPU's throughput for small meshes.
        EvalParams {
            walk: WalkParams::default(),
            cost_per_triangle_ns: 2.0,
            region: Region::POINT,
            walker_speed: 1.4,
        }
    }
}

/// Why an evaluation could not run.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A method or its options were refused.
    #[error(transparent)]
    Method(#[from] MethodError),
    /// No walkthrough could be made.
    #[error(transparent)]
    Walk(#[from] WalkError),
    /// A method failed to answer a frame (eval measures the method, not
    /// the fallback a server would answer with).
    #[error("frame {frame}: {error}")]
    Cull {
        /// The frame.
        frame: usize,
        /// The method's error.
        error: CullError,
    },
    /// A camera handed to [`run`] is unusable.
    #[error("frame {frame}: {problem}")]
    Camera {
        /// The frame.
        frame: usize,
        /// What is wrong.
        problem: String,
    },
}

/// One method under evaluation: a label, the method and a client cache.
pub struct Contender {
    /// How the report names it (`frustum`, `gpu:contribution=0.001`).
    pub label: String,
    /// Its options, echoed in the report.
    pub options: MethodOptions,
    method: Arc<dyn Culler>,
    /// Its cache, carried from frame to frame (`None` only while it culls).
    cache: Option<ClientCache>,
    /// Whether the method is conservative with these options.
    conservative: bool,
}

impl Contender {
    /// A contender from any culler (tests hand in deliberately broken ones).
    pub fn new(
        label: impl Into<String>,
        method: Arc<dyn Culler>,
        options: MethodOptions,
    ) -> Result<Self, MethodError> {
        let cache = method.new_cache(&options)?;
        Ok(Contender {
            label: label.into(),
            options,
            conservative: cache.is_conservative(),
            method,
            cache: Some(cache),
        })
    }

    /// A contender for a method of `methods` named by `spec`.
    pub fn from_spec(methods: &SceneMethods, spec: &MethodSpec) -> Result<Self, MethodError> {
        Contender::for_regions(methods, spec, false)
    }

    /// [`Contender::from_spec`] for region answers when `regions`: a
    /// method that cannot answer for a region is refused with why.
    pub fn for_regions(
        methods: &SceneMethods,
        spec: &MethodSpec,
        regions: bool,
    ) -> Result<Self, MethodError> {
        let (method, options) = methods.resolve_for(spec, regions)?;
        let label = if spec.name == "auto" {
            // Say what `auto` answered with: the table is about methods.
            format!("{spec}→{}", method.name())
        } else {
            spec.to_string()
        };
        Contender::new(label, method.clone(), options)
    }
}

/// Per-frame measurements of one method.
#[derive(Clone, Debug, Default)]
struct Tally {
    cull_us: Vec<f64>,
    /// Per frame, the CPU time the calling thread spent in the cull
    /// (empty where there is no per-thread clock): what a ranking charges.
    cpu_us: Vec<f64>,
    pvs: u64,
    pvs_triangles: u64,
    in_frustum: u64,
    misses: u64,
    ties: u64,
    wrong_pixels: u64,
    /// The first few `(frame, object)` misses, to say where to look.
    examples: Vec<(usize, u32)>,
}

/// Runs `methods` (specs resolved on `scene_methods`) over the walkthrough.
pub fn evaluate(
    scene_methods: &SceneMethods,
    specs: &[MethodSpec],
    params: &EvalParams,
    progress: impl FnMut(usize),
) -> Result<EvalReport, EvalError> {
    let regions = !params.region.is_point();
    let contenders = specs
        .iter()
        .map(|s| Contender::for_regions(scene_methods, s, regions))
        .collect::<Result<Vec<_>, _>>()?;
    let cameras = walk(scene_methods.scene(), &params.walk)?;
    run(
        scene_methods.scene(),
        contenders,
        &cameras,
        params,
        progress,
    )
}

/// Runs contenders over given cameras: the core of [`evaluate`], open to any
/// [`Culler`] so tests can prove the accounting catches a broken method.
pub fn run(
    scene: &Scene,
    mut contenders: Vec<Contender>,
    cameras: &[Camera],
    params: &EvalParams,
    mut progress: impl FnMut(usize),
) -> Result<EvalReport, EvalError> {
    let mut tallies = vec![Tally::default(); contenders.len()];
    let views_for = |region: Region| {
        cameras
            .iter()
            .enumerate()
            .map(|(frame, camera)| {
                View::with_region(*camera, region, scene).map_err(|e| EvalError::Camera {
                    frame,
                    problem: e.to_string(),
                })
            })
            .collect::<Result<Vec<_>, _>>()
    };
    let views = views_for(params.region)?;
    let is_region = !params.region.is_point();
    // First each method runs the whole walk on its own, frame after frame,
    // as a server runs a session: what is timed is the method with the
    // caches its own frames leave, not the method after a truth render has
    // swept every cache (which took 2–4× longer on the 10k city).
    let answers: Vec<Vec<Vec<u32>>> = contenders
        .iter_mut()
        .zip(&mut tallies)
        .map(|(c, tally)| time_walk(scene, c, &views, params, tally))
        .collect::<Result<_, _>>()?;
    // For a region, the same methods on the walk's point views: what the
    // region costs in PVS.
    let point_pvs: Vec<Option<f64>> = if is_region {
        let point_views = views_for(Region::POINT)?;
        contenders
            .iter_mut()
            .map(|c| {
                let mut scratch = Tally::default();
                let answers = time_walk(scene, c, &point_views, params, &mut scratch)?;
                let total: usize = answers.iter().map(Vec::len).sum();
                Ok(Some(total as f64 / answers.len().max(1) as f64))
            })
            .collect::<Result<_, EvalError>>()?
    } else {
        vec![None; contenders.len()]
    };
    let mut samples_per_frame = 1;
    // Then each frame's truth is rendered once and every answer held to it.
    let (mut truth_total, mut tie_total, mut truth_ms) =
        (0u64, 0u64, Vec::with_capacity(cameras.len()));
    let mut pixels = 0u64;
    for (frame, (camera, view)) in cameras.iter().zip(&views).enumerate() {
        let started = Instant::now();
        let render = |camera: &Camera| {
            Truth::render(scene, camera).map_err(|e| EvalError::Camera {
                frame,
                problem: e.to_string(),
            })
        };
        let truth = render(camera)?;
        let (mut visible, mut ties) = (truth.visible(), truth.ties());
        if is_region {
            // The union of the truths of the region's sampled cameras; an
            // object a sample sees is no tie.
            let samples = sample_cameras(camera, params.region, frame as u64);
            samples_per_frame = samples.len();
            for sample in &samples[1..] {
                let t = render(sample)?;
                visible.extend(t.visible());
                ties.extend(t.ties());
            }
            visible.sort_unstable();
            visible.dedup();
            ties.sort_unstable();
            ties.dedup();
            ties.retain(|t| visible.binary_search(t).is_err());
        }
        truth_ms.push(started.elapsed().as_secs_f64() * 1e3);
        truth_total += visible.len() as u64;
        tie_total += ties.len() as u64;
        pixels += truth.pixel_count();
        // The in-frustum set is the walk's, not a method's: counted once,
        // exactly.
        let in_frustum = FrustumCulling::reference(scene, view.frustum()).len() as u64;
        for (answer, tally) in answers.iter().zip(&mut tallies) {
            let ids = &answer[frame];
            tally.pvs += ids.len() as u64;
            tally.in_frustum += in_frustum;
            tally.pvs_triangles += ids
                .iter()
                .map(|&i| scene.objects()[i as usize].triangle_count() as u64)
                .sum::<u64>();
            for &v in &visible {
                if ids.binary_search(&v).is_err() {
                    tally.misses += 1;
                    if tally.examples.len() < 8 {
                        tally.examples.push((frame, v));
                    }
                }
            }
            tally.ties += ties
                .iter()
                .filter(|t| ids.binary_search(t).is_err())
                .count() as u64;
            tally.wrong_pixels += truth.wrong_pixels(ids);
        }
        progress(frame + 1);
    }
    let frames = cameras.len().max(1) as f64;
    let mean_truth = truth_total as f64 / frames;
    let mut methods: Vec<MethodReport> = contenders
        .iter()
        .zip(tallies)
        .zip(point_pvs)
        .map(|((c, t), point_pvs)| {
            let mean_pvs = t.pvs as f64 / frames;
            let mean_in_frustum = t.in_frustum as f64 / frames;
            let mean_cull = t.cull_us.iter().sum::<f64>() / frames;
            let mean_pvs_triangles = t.pvs_triangles as f64 / frames;
            MethodReport {
                method: c.label.clone(),
                options: c
                    .options
                    .iter()
                    .map(|(k, v)| (k.to_string(), v.to_string()))
                    .collect(),
                conservative: c.conservative,
                median_cull_us: percentile(&t.cull_us, 0.5),
                p99_cull_us: percentile(&t.cull_us, 0.99),
                mean_pvs,
                mean_truth,
                mean_in_frustum,
                misses: t.misses,
                ties: t.ties,
                overestimation: ratio(mean_pvs, mean_truth),
                culled_in_frustum_share: if mean_in_frustum > 0.0 {
                    1.0 - mean_pvs / mean_in_frustum
                } else {
                    0.0
                },
                wrong_pixel_share: ratio(t.wrong_pixels as f64, pixels as f64),
                mean_pvs_triangles,
                mean_frame_cost_us: mean_cull
                    + mean_pvs_triangles * params.cost_per_triangle_ns * 1e-3,
                speedup: None,
                miss_examples: t.examples,
                pvs_growth: point_pvs.map(|p| ratio(mean_pvs, p)),
            }
        })
        .collect();
    // Speedup against frustum culling, when it ran (Bittner et al., Table 2).
    if let Some(base) = methods
        .iter()
        .find(|m| m.method == "frustum")
        .map(|m| m.mean_frame_cost_us)
    {
        for m in &mut methods {
            m.speedup = Some(ratio(base, m.mean_frame_cost_us));
        }
    }
    Ok(EvalReport {
        scene: scene.id.clone(),
        walk: params.walk.kind.name().to_string(),
        frames: cameras.len(),
        resolution: params.walk.viewport,
        cost_per_triangle_ns: params.cost_per_triangle_ns,
        mean_tie_objects: tie_total as f64 / frames,
        median_truth_ms: percentile(&truth_ms, 0.5),
        methods,
        region: is_region.then(|| RegionReport {
            radius: params.region.radius(),
            angle: params.region.angle_deg(),
            samples_per_frame,
            request_share: request_share(cameras, params.region, params.walker_speed),
            walker_speed: params.walker_speed,
        }),
    })
}

/// Runs one contender over every view with its cache carried from frame to
/// frame (a fresh one per frame for unrelated views, as stateless requests
/// get), recording its cull times; returns its answer for each frame.
fn time_walk(
    scene: &Scene,
    c: &mut Contender,
    views: &[View],
    params: &EvalParams,
    tally: &mut Tally,
) -> Result<Vec<Vec<u32>>, EvalError> {
    let mut out = VisibleSet::new();
    let mut answers = Vec::with_capacity(views.len());
    // One untimed cull with a throwaway cache first: what a process does
    // once (first touches of the scene's pages, lazy statics) is no frame's.
    if let Some(view) = views.first() {
        let cache = c
            .method
            .new_cache(&c.options)
            .expect("options accepted once are accepted again");
        cull_here(scene, &c.method, CullJob::new(*view, cache))
            .map_err(|error| EvalError::Cull { frame: 0, error })?;
    }
    for (frame, view) in views.iter().enumerate() {
        let mut cache = c
            .cache
            .take()
            .expect("a contender's cache is back after each frame");
        if !params.walk.kind.follows_on() {
            // Unrelated views are stateless requests: nothing carried.
            cache = c
                .method
                .new_cache(&c.options)
                .expect("options accepted once are accepted again");
        }
        let mut job = CullJob::new(*view, cache);
        job.out = std::mem::take(&mut out);
        let cpu = clock::thread_cpu_time();
        let culled =
            cull_here(scene, &c.method, job).map_err(|error| EvalError::Cull { frame, error })?;
        if let (Some(before), Some(after)) = (cpu, clock::thread_cpu_time()) {
            tally.cpu_us.push((after - before).as_secs_f64() * 1e6);
        }
        tally.cull_us.push(culled.stats.cull_us);
        c.cache = Some(culled.job.cache);
        out = culled.job.out;
        answers.push(out.ids().to_vec());
    }
    Ok(answers)
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 { a / b } else { 0.0 }
}

/// The `q` quantile (nearest rank) of unsorted values; 0 for none.
fn percentile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}

#[cfg(test)]
mod tests {
    use super::percentile;

    #[test]
    fn nearest_rank_percentiles() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.5), 50.0);
        assert_eq!(percentile(&v, 0.99), 99.0);
        assert_eq!(percentile(&[3.0, 1.0, 2.0], 0.5), 2.0);
        assert_eq!(percentile(&[7.0], 0.99), 7.0);
        assert_eq!(percentile(&[], 0.5), 0.0);
    }
}
