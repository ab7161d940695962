//! One method over one walk, for a profiler: the scene is prepared with
//! that method alone (and frustum), then every frame of the walk is culled
//! `REPS` times as `pvsd eval` does (a session's cache carried along a
//! street, orbit or random walk; a fresh one per frame of `views`).
//!
//! `cargo run --release --example cull_profile -- SCENE METHOD [street|orbit|random|views] [REPS]`
//! prints the median over frames of each frame's median cull time, the
//! 90th percentile, the mean PVS and the nodes tested per frame. Under
//! valgrind, count only the culls with
//! `valgrind --tool=callgrind --toggle-collect='*cull_blocking*' target/release/examples/cull_profile …`:
//! instruction counts do not drift with the machine as times do.
//! `ONLY=3,14,20` culls only those frames (for a profile of the frames
//! near the median); `PER_FRAME=1` prints each frame's median time to
//! stderr. `DDO_LEAF_TRIANGLES=128` bakes `ddo`'s octree with that many triangles
//! a leaf (`--ddo-leaf-triangles` of `pvsd eval`) instead of the default;
//! `VIEWPORT=512x320` culls at that viewport.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use pvsd::cull::{CullJob, MethodContext, MethodSpec, Registry, SceneMethods, View};
use pvsd::eval::{WalkKind, WalkParams, walk};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (path, spec) = (&args[1], &args[2]);
    let kind = match args.get(3).map(String::as_str) {
        Some("random") => WalkKind::Random,
        Some("orbit") => WalkKind::Orbit,
        Some("street") => WalkKind::Street,
        _ => WalkKind::Views,
    };
    let reps: usize = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(20);
    let spec: MethodSpec = spec.parse().unwrap();
    let scene = Arc::new(pvsd::scene::load_path(Path::new(path)).unwrap());
    let registry = Registry::standard();
    let context = MethodContext {
        bake_dir: Some(std::env::temp_dir().join("pvsd-cull-profile-bakes")),
        disabled: registry
            .entries()
            .iter()
            .map(|e| e.name)
            .filter(|m| *m != "frustum" && *m != spec.name)
            .map(String::from)
            .collect(),
        ..MethodContext::default()
    };
    let context = match std::env::var("DDO_LEAF_TRIANGLES") {
        Ok(n) => context
            .with_ddo_leaf_triangles(n.parse().expect("DDO_LEAF_TRIANGLES: a whole number"))
            .unwrap(),
        Err(_) => context,
    };
    let methods = SceneMethods::prepare_with(scene.clone(), &registry, &context);
    // `pvsd eval`'s viewports: MOC's 512×320 for unrelated views;
    // `VIEWPORT=512x320` sets another (`--width`, `--height` of eval).
    let viewport = match std::env::var("VIEWPORT") {
        Ok(v) => {
            let (w, h) = v.split_once('x').expect("VIEWPORT: WIDTHxHEIGHT");
            [
                w.parse().expect("VIEWPORT width"),
                h.parse().expect("VIEWPORT height"),
            ]
        }
        Err(_) if kind == WalkKind::Views => [512, 320],
        Err(_) => [1024, 768],
    };
    let params = WalkParams {
        kind,
        frames: 60,
        viewport,
        ..WalkParams::default()
    };
    let cams = walk(&scene, &params).unwrap();
    let (method, cache) = methods.prepare_client(&spec).unwrap();
    let mut job = Some(CullJob::new(View::new(cams[0], &scene).unwrap(), cache));
    let mut times = vec![Vec::new(); cams.len()];
    let (mut pvs, mut nodes) = (0u64, 0u64);
    for rep in 0..reps {
        for (i, cam) in cams.iter().enumerate() {
            if let Ok(only) = std::env::var("ONLY") {
                if !only.split(',').any(|f| f.parse::<usize>().ok() == Some(i)) {
                    continue;
                }
            }
            let mut next = job.take().unwrap();
            next.view = View::new(*cam, &scene).unwrap();
            if !kind.follows_on() {
                next.cache = method.new_cache(&spec.options).unwrap();
            }
            let started = Instant::now();
            let culled = methods.cull_blocking(&method, next).unwrap();
            times[i].push(started.elapsed().as_secs_f64() * 1e6);
            if rep == 0 {
                pvs += culled.stats.visible;
                nodes += culled.stats.nodes_tested;
            }
            job = Some(culled.job);
        }
    }
    if std::env::var("PER_FRAME").is_ok() {
        for (i, t) in times.iter().enumerate() {
            let mut t = t.clone();
            t.sort_by(f64::total_cmp);
            if !t.is_empty() {
                eprintln!("frame {i} {:.1}", t[t.len() / 2]);
            }
        }
    }
    let mut medians: Vec<f64> = times
        .iter_mut()
        .filter(|t| !t.is_empty())
        .map(|t| {
            t.sort_by(f64::total_cmp);
            t[t.len() / 2]
        })
        .collect();
    medians.sort_by(f64::total_cmp);
    let n = cams.len() as f64;
    println!(
        "{spec} on {} ({} walk, {} frames × {reps}): median {:.1} µs, p90 {:.1} µs, mean PVS {:.2}, nodes tested {:.1}",
        scene.id,
        kind.name(),
        cams.len(),
        medians[medians.len() / 2],
        medians[medians.len() * 9 / 10],
        pvs as f64 / n,
        nodes as f64 / n
    );
}
