//! What a two-eye request costs against one view: a headset's eyes 6.4 cm
//! apart, culled as one region around them (the way the server answers
//! `views` that close together for a method that answers regions), and,
//! for comparison, as two views culled one after the other.
//!
//! `cargo run --release --example two_eyes -- SCENE METHOD[,METHOD…] [street|orbit|random]`
//! prints, per method, the median cull time of each over the walk (each
//! frame repeated `REPS` times, default 20), the ratios to one view, and
//! the mean PVS of each.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use pvsd::cull::view::gather;
use pvsd::cull::{CullJob, MethodContext, Registry, SceneMethods, View};
use pvsd::eval::{WalkKind, WalkParams, walk};
use pvsd::geom::Camera;

/// The distance between a headset's eyes, metres.
const EYES_APART: f64 = 0.064;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (path, specs) = (&args[1], &args[2]);
    let kind = match args.get(3).map(String::as_str) {
        Some("random") => WalkKind::Random,
        Some("orbit") => WalkKind::Orbit,
        _ => WalkKind::Street,
    };
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let scene = Arc::new(pvsd::scene::load_path(Path::new(path)).unwrap());
    let context = MethodContext {
        bake_dir: Some(std::env::temp_dir().join("pvsd-two-eyes-bakes")),
        ..MethodContext::default()
    };
    let methods = SceneMethods::prepare_with(scene.clone(), &Registry::standard(), &context);
    let cams = walk(
        &scene,
        &WalkParams {
            kind,
            frames: 60,
            ..WalkParams::default()
        },
    )
    .unwrap();
    let eyes = |c: &Camera| -> Vec<View> {
        let right = c.basis().unwrap().right;
        [-0.5, 0.5]
            .iter()
            .map(|s| {
                let eye = Camera {
                    eye: c.eye + right * (s * EYES_APART),
                    ..*c
                };
                View::new(eye, &scene).unwrap()
            })
            .collect()
    };
    println!(
        "{} {} walk, {} frames × {reps}: median cull µs (ratio to one view), mean PVS",
        scene.id,
        kind.name(),
        cams.len()
    );
    for spec in specs.split(',') {
        let spec: pvsd::cull::MethodSpec = spec.parse().unwrap();
        let (method, cache) = methods.prepare_client(&spec).unwrap();
        let regions = methods.answers_regions(method.name());
        let mut job = Some(CullJob::new(View::new(cams[0], &scene).unwrap(), cache));
        // Times every frame's job `reps` times; median µs and mean PVS.
        let mut run = |make: &dyn Fn(&Camera) -> (View, Vec<View>)| -> (f64, f64) {
            let (mut times, mut pvs) = (Vec::new(), 0usize);
            for c in &cams {
                let (view, also) = make(c);
                for _ in 0..reps {
                    let mut next = job.take().unwrap();
                    next.view = view;
                    next.also = also.clone();
                    let start = Instant::now();
                    let culled = methods.cull_blocking(&method, next).unwrap();
                    times.push(start.elapsed().as_secs_f64() * 1e6);
                    pvs += culled.job.out.len();
                    job = Some(culled.job);
                }
            }
            times.sort_by(f64::total_cmp);
            (times[times.len() / 2], pvs as f64 / times.len() as f64)
        };
        // Once untimed: the first pass over a scene pays for its pages.
        run(&|c| (View::new(*c, &scene).unwrap(), Vec::new()));
        let one = run(&|c| (View::new(*c, &scene).unwrap(), Vec::new()));
        let enclosed = run(&|c| gather(&eyes(c), regions, &scene));
        let apart = run(&|c| {
            let mut v = eyes(c);
            let first = v.remove(0);
            (first, v)
        });
        println!(
            "{:<20} one view {:>8.1} µs, PVS {:>7.1} | two eyes as one region {:>8.1} µs ({:.2}×), PVS {:>7.1} | two views one by one {:>8.1} µs ({:.2}×), PVS {:>7.1}",
            spec.to_string(),
            one.0,
            one.1,
            enclosed.0,
            enclosed.0 / one.0,
            enclosed.1,
            apart.0,
            apart.0 / one.0,
            apart.1,
        );
    }
}
