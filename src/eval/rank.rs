//! Measuring a scene's methods for `auto` ("model only what a scene
//! requires"): each conservative method, with its defaults, culls sample
//! views of the scene (a street and a random walk at eye height, or an
//! orbit around a scene with no room at eye height), each cull charged
//! the CPU time of the thread that ran it (a server ranks while it serves,
//! and waiting for a core is not a method's cost); the figures become the scene's
//! [`Ranking`](crate::cull::ranking::Ranking), cached with the bakes.

use std::time::Instant;

use super::{Contender, EvalParams, Tally, WalkKind, WalkParams, time_walk, walk};
use crate::cull::ranking::{Measured, Ranking};
use crate::cull::{Execution, MethodOptions, SceneMethods, View};
use crate::scene::BakeCache;

/// The sample views a ranking is measured on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RankParams {
    /// Frames of each walk (street and random at eye height, else orbit).
    pub frames_per_walk: usize,
    /// Viewport of the sample views.
    pub viewport: [u32; 2],
    /// Seed of the walks.
    pub seed: u64,
}

impl Default for RankParams {
    /// 2 × 20 frames at 1024×768: well under a second a method on the
    /// 10k city (the device one aside), and enough that the order of
    /// methods whose costs differ by a fifth does not change between runs.
    fn default() -> Self {
        RankParams {
            frames_per_walk: 20,
            viewport: [1024, 768],
            seed: 1,
        }
    }
}

impl RankParams {
    /// The bake cache's parameter string: what the figures depend on,
    /// the build included (another build may cull at another speed): pvsd's
    /// version and the running executable's size and modification time.
    fn cache_key(&self) -> String {
        let build = std::env::current_exe()
            .and_then(std::fs::metadata)
            .map(|m| {
                let modified = m
                    .modified()
                    .ok()
                    .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                    .map_or(0, |d| d.as_secs());
                format!("{}-{modified}", m.len())
            })
            .unwrap_or_else(|_| "unknown".into());
        format!(
            "ranking v2 pvsd {} build {build} frames {} viewport {}x{} seed {}",
            env!("CARGO_PKG_VERSION"),
            self.frames_per_walk,
            self.viewport[0],
            self.viewport[1],
            self.seed
        )
    }
}

/// Measures every conservative method of `methods` on the sample views.
pub fn rank(methods: &SceneMethods, params: &RankParams) -> Ranking {
    let scene = methods.scene();
    let mut walks = Vec::new();
    let mut views: Vec<(WalkKind, Vec<View>)> = Vec::new();
    // Users walk through a scene at eye height (a city's streets, a
    // building's rooms); a scene with no room at eye height (a machine
    // part) is looked at from around it.
    for kind in [WalkKind::Street, WalkKind::Random, WalkKind::Orbit] {
        if kind == WalkKind::Orbit && !views.is_empty() {
            break;
        }
        let walk_params = WalkParams {
            kind,
            frames: params.frames_per_walk,
            seed: params.seed,
            viewport: params.viewport,
            ..WalkParams::default()
        };
        let Ok(cameras) = walk(scene, &walk_params) else {
            continue; // no free space at eye height
        };
        let v: Vec<View> = cameras
            .into_iter()
            .filter_map(|c| View::new(c, scene).ok())
            .collect();
        if !v.is_empty() {
            walks.push(kind.name().to_string());
            views.push((kind, v));
        }
    }
    let frames = views.iter().map(|(_, v)| v.len()).sum();
    let mut measured = Vec::new();
    for method in methods.methods() {
        let Ok(mut contender) =
            Contender::new(method.name(), method.clone(), MethodOptions::default())
        else {
            continue;
        };
        if !contender.conservative {
            continue;
        }
        let mut tally = Tally::default();
        let (mut pvs, mut triangles) = (0u64, 0u64);
        let mut failed = false;
        for (kind, v) in &views {
            // Each walk a session of its own.
            contender.cache = method.new_cache(&MethodOptions::default()).ok();
            let eval = EvalParams {
                walk: WalkParams {
                    kind: *kind,
                    ..WalkParams::default()
                },
                ..EvalParams::default()
            };
            match time_walk(scene, &mut contender, v, &eval, &mut tally) {
                Ok(answers) => {
                    for ids in answers {
                        pvs += ids.len() as u64;
                        triangles += ids
                            .iter()
                            .map(|&i| scene.objects()[i as usize].triangle_count() as u64)
                            .sum::<u64>();
                    }
                }
                Err(e) => {
                    // A method that cannot answer a sample view is not ranked.
                    tracing::warn!(scene = %scene.id, method = method.name(), error = %e, "not ranked");
                    failed = true;
                    break;
                }
            }
        }
        if failed || frames == 0 {
            continue;
        }
        let n = frames as f64;
        // The measuring thread's CPU time, which waiting for a core does
        // not inflate ([`super::clock`]); a device method works on the
        // device's thread, and is charged the wall time this one waited.
        let on_device = matches!(method.execution(), Execution::Device(_));
        let times = if on_device || tally.cpu_us.len() != tally.cull_us.len() {
            &tally.cull_us
        } else {
            &tally.cpu_us
        };
        measured.push(Measured {
            method: method.name().to_string(),
            mean_cull_us: times.iter().sum::<f64>() / n,
            median_cull_us: super::percentile(times, 0.5),
            mean_pvs: pvs as f64 / n,
            mean_pvs_triangles: triangles as f64 / n,
        });
    }
    Ranking {
        walks,
        frames,
        viewport: params.viewport,
        measured,
    }
}

/// [`rank`], read from the bake cache when a ranking of this scene file
/// with these parameters is there, else measured and written for next time.
pub fn rank_cached(
    methods: &SceneMethods,
    params: &RankParams,
    cache: Option<&BakeCache>,
) -> Ranking {
    let started = Instant::now();
    let ranking = match cache {
        Some(cache) => {
            cache
                .load_or_build(
                    methods.scene(),
                    "ranking",
                    // The methods measured depend on how they were built.
                    &format!(
                        "{} ddo leaves {}",
                        params.cache_key(),
                        methods.context().ddo_octree.leaf_triangles
                    ),
                    || rank(methods, params),
                    |r| serde_json::to_vec(r).expect("a ranking is plain data"),
                    |bytes| {
                        let r: Ranking = serde_json::from_slice(bytes)
                            .map_err(|e| format!("not a ranking: {e}"))?;
                        // Ranked for other methods than this server has (one
                        // disabled, a device gone or come): measure anew.
                        let ranked: Vec<&str> =
                            r.measured.iter().map(|m| m.method.as_str()).collect();
                        if ranked != methods.names() {
                            return Err("ranks methods this server does not have".into());
                        }
                        Ok(r)
                    },
                )
                .0
        }
        None => rank(methods, params),
    };
    let cost = methods.frame_cost();
    tracing::info!(
        scene = %methods.scene().id,
        ms = started.elapsed().as_millis() as u64,
        choice = ranking.best(cost).unwrap_or("none"),
        cost_per_triangle_ns = cost.per_triangle_ns,
        "ranked the methods for auto"
    );
    ranking
}
