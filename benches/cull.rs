//! Cull time per frame of each method on the same walkthrough frames, with
//! each method's client cache carried from frame to frame as a session's is
//! (over unrelated views, a fresh cache each frame, as a stateless request's).
//! Compare each method's time with `frustum`'s in the same run:
//! `cargo bench --bench cull`.

use std::path::Path;
use std::sync::Arc;

use criterion::{Criterion, criterion_group, criterion_main};
use pvsd::cull::{CullJob, MethodSpec, SceneMethods, View};
use pvsd::eval::{WalkKind, WalkParams, walk};
use pvsd::scene::generate::{CityOptions, OfficeOptions, city, office};
use pvsd::scene::{Scene, load_path, load_slice};

/// Times each of `specs` on the frames of one walk through `scene`.
fn bench_walk(c: &mut Criterion, group: &str, scene: Arc<Scene>, kind: WalkKind, specs: &[&str]) {
    let params = WalkParams {
        kind,
        frames: 60,
        ..WalkParams::default()
    };
    bench_frames(c, group, scene, params, specs);
}

/// [`bench_walk`] over 60 unrelated views at 512×320.
fn bench_views(c: &mut Criterion, group: &str, scene: Arc<Scene>, specs: &[&str]) {
    let params = WalkParams {
        kind: WalkKind::Views,
        frames: 60,
        viewport: [512, 320],
        ..WalkParams::default()
    };
    bench_frames(c, group, scene, params, specs);
}

fn bench_frames(
    c: &mut Criterion,
    group: &str,
    scene: Arc<Scene>,
    params: WalkParams,
    specs: &[&str],
) {
    let methods = SceneMethods::prepare(scene.clone());
    let views: Vec<View> = walk(&scene, &params)
        .unwrap()
        .into_iter()
        .map(|cam| View::new(cam, &scene).unwrap())
        .collect();
    let mut group = c.benchmark_group(group);
    for spec in specs {
        let spec: MethodSpec = spec.parse().unwrap();
        let (method, cache) = methods.prepare_client(&spec).unwrap();
        // The job carries the cache and buffers from frame to frame; over
        // unrelated views each frame is a stateless request's, with a
        // fresh cache (as `pvsd eval` does).
        let stateless = !params.kind.follows_on();
        let mut job = Some(CullJob::new(views[0], cache));
        let mut frame = 0;
        group.bench_function(spec.to_string(), |b| {
            b.iter(|| {
                let mut next = job.take().expect("the job is back after each frame");
                next.view = views[frame % views.len()];
                if stateless {
                    next.cache = method.new_cache(&spec.options).unwrap();
                }
                let culled = methods.cull_blocking(&method, next).unwrap();
                frame += 1;
                job = Some(culled.job);
                culled.stats.visible
            })
        });
    }
    group.finish();
}

fn office_walk(c: &mut Criterion) {
    let glb = office(&OfficeOptions::default()).to_glb();
    let scene = Arc::new(load_slice("office", &glb, None, Path::new("office.glb")).unwrap());
    let specs = [
        "frustum",
        "occlusion_tree:k=32",
        "occlusion_tree:k=32:variant=fmc",
        "supporting_planes:k=32",
        "raster",
    ];
    bench_walk(
        c,
        "office_random_walk_frame",
        scene,
        WalkKind::Random,
        &specs,
    );
}

/// Downs et al.'s setting: a 10k-building city seen from its streets.
fn city10k_walk(c: &mut Criterion) {
    let opts = CityOptions {
        buildings: 10_000,
        ..CityOptions::default()
    };
    let glb = city(&opts).to_glb();
    let scene = Arc::new(load_slice("city10k", &glb, None, Path::new("city10k.glb")).unwrap());
    let specs = ["frustum", "horizon", "horizon:min_area=4"];
    bench_walk(
        c,
        "city10k_street_walk_frame",
        scene,
        WalkKind::Street,
        &specs,
    );
}

/// `raster` against the object-space methods on unrelated random views
/// (`pvsd eval --walk views`'s frames) of the scenes issue 16 measured
/// Masked Occlusion Culling on, at its 512×320.
fn raster_views(c: &mut Criterion) {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes");
    let office_glb = office(&OfficeOptions::default()).to_glb();
    let city_glb = city(&CityOptions {
        buildings: 1000,
        ..CityOptions::default()
    })
    .to_glb();
    let scenes = [
        load_path(&shared.join("Sponza/Sponza.gltf")).unwrap(),
        load_path(&shared.join("2CylinderEngine/2CylinderEngine.gltf")).unwrap(),
        load_slice("office", &office_glb, None, Path::new("office.glb")).unwrap(),
        load_slice("city1k", &city_glb, None, Path::new("city1k.glb")).unwrap(),
    ];
    let specs = [
        "frustum",
        "occlusion_tree",
        "supporting_planes:k=50",
        "raster",
        "raster:cell=1",
    ];
    for scene in scenes {
        let group = format!("{}_views_frame", scene.id);
        bench_views(c, &group, Arc::new(scene), &specs);
    }
}

criterion_group!(benches, office_walk, city10k_walk, raster_views);
criterion_main!(benches);
