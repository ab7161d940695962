//! Fixtures shared by the integration tests: the real scenes of
//! `../shared/scenes`, generated scenes, and random cameras.
#![allow(dead_code)] // each test binary uses a different part of it

pub mod router;
pub mod server;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::DVec3;
use pvsd::cull::{CullJob, Culler, MethodOptions, MethodSpec, Registry, SceneMethods};
use pvsd::eval::{Contender, EvalParams, WalkKind, WalkParams};
use pvsd::geom::{Camera, Region};
use pvsd::scene::generate::{CityOptions, OfficeOptions, city, office};
use pvsd::scene::{Scene, load_path, load_slice};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `../shared/scenes/<name>/<name>.gltf`; the shared folder sits beside the repo.
pub fn shared_scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/scenes")
        .join(name)
        .join(format!("{name}.gltf"))
}

/// [`SceneMethods::prepare`] with the bakes kept in one folder under the
/// build's scratch space: a scene file that several tests prepare (the
/// shared scenes, a generated scene of the same bytes) is baked once.
pub fn prepare(scene: Arc<Scene>) -> SceneMethods {
    SceneMethods::prepare_with(scene, &Registry::standard(), &test_context())
}

/// This machine's context with the tests' bake folder ([`prepare`]).
pub fn test_context() -> pvsd::cull::MethodContext {
    pvsd::cull::MethodContext {
        bake_dir: Some(Path::new(env!("CARGO_TARGET_TMPDIR")).join("bakes")),
        ..pvsd::cull::MethodContext::of_this_machine()
    }
}

/// Loads a shared scene; fails the test loudly if `../shared` is missing.
pub fn shared_scene(name: &str) -> Arc<Scene> {
    let path = shared_scene_path(name);
    Arc::new(load_path(&path).unwrap_or_else(|e| panic!("shared scene: {e}")))
}

/// A generated city, written to glb bytes and loaded back as a user would.
pub fn city_scene(buildings: u32, seed: u64, offset: [f32; 3]) -> Arc<Scene> {
    let doc = city(&CityOptions {
        seed,
        buildings,
        offset,
        ..CityOptions::default()
    });
    Arc::new(load_slice("city", &doc.to_glb(), None, Path::new("city.glb")).unwrap())
}

/// A generated CAD body (a closed skin with windows around dense parts),
/// smaller than the default, written to glb bytes and loaded back.
pub fn cad_scene(seed: u64, offset: [f32; 3]) -> Arc<Scene> {
    let doc = pvsd::scene::generate::cad(&pvsd::scene::generate::CadOptions {
        seed,
        cells: 24,
        parts: 80,
        offset,
    });
    Arc::new(load_slice("cad", &doc.to_glb(), None, Path::new("cad.glb")).unwrap())
}

/// A generated crowd (half its things movable), written to glb bytes and
/// loaded back.
pub fn crowd_scene(objects: u32, seed: u64) -> Arc<Scene> {
    let doc = pvsd::scene::generate::crowd(&pvsd::scene::generate::CrowdOptions {
        seed,
        objects,
        ..Default::default()
    });
    Arc::new(load_slice("crowd", &doc.to_glb(), None, Path::new("crowd.glb")).unwrap())
}

/// A generated office, written to glb bytes and loaded back.
pub fn office_scene(seed: u64, offset: [f32; 3]) -> Arc<Scene> {
    let doc = office(&OfficeOptions {
        seed,
        offset,
        ..OfficeOptions::default()
    });
    Arc::new(load_slice("office", &doc.to_glb(), None, Path::new("office.glb")).unwrap())
}

/// A random camera around `scene`: eye in its world box grown by `margin`
/// of its size, any direction, fov 20–120°, aspect 0.5–2.5.
pub fn random_camera(rng: &mut ChaCha8Rng, scene: &Scene, margin: f64) -> Camera {
    let (lo, hi) = scene.to_world(&scene.bounds());
    let grow = (hi - lo) * margin;
    let (lo, hi) = (lo - grow, hi + grow);
    let eye = DVec3::new(
        rng.random_range(lo.x..=hi.x),
        rng.random_range(lo.y..=hi.y),
        rng.random_range(lo.z..=hi.z),
    );
    let forward = random_unit(rng);
    let mut up = random_unit(rng);
    while forward.cross(up).length() < 0.1 {
        up = random_unit(rng);
    }
    Camera {
        eye,
        forward,
        up,
        fov_y_deg: rng.random_range(20.0..120.0),
        aspect: rng.random_range(0.5..2.5),
        near: rng.random_range(0.01..1.0),
        far: rng.random_range(10.0..5000.0),
        viewport: [640, 480],
    }
}

pub fn random_unit(rng: &mut ChaCha8Rng) -> DVec3 {
    loop {
        let v = DVec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if v.length() > 0.1 && v.length() <= 1.0 {
            return v.normalize();
        }
    }
}

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// Image size of the ground truth in the conservativeness check: small
/// enough to be quick, large enough that a missed object of a few pixels at
/// 1024×768 still covers a pixel centre here at least as often as not.
pub const CHECK_VIEWPORT: [u32; 2] = [256, 160];

/// The shared conservativeness check (DESIGN "Accuracy"): runs fresh
/// contenders from `make` over each walk of `methods`' scene against ground
/// truth, and reports every walk where a method that claims to be
/// conservative dropped a truth-visible object. Every method's tests go
/// through it; it refuses a walk that sees nothing (it would check nothing).
pub fn check_conservative(
    methods: &SceneMethods,
    walks: &[WalkKind],
    frames: usize,
    make: impl Fn(&SceneMethods) -> Vec<Contender>,
) -> Result<(), String> {
    check_conservative_in(methods, walks, frames, Region::POINT, make)
}

/// [`check_conservative`] for answers valid for `region`: each frame's
/// answer is held to the union of the truths of the cameras sampled in it
/// (`pvsd::eval::sample_cameras`, ≥ 16 for a ball or cone).
pub fn check_conservative_in(
    methods: &SceneMethods,
    walks: &[WalkKind],
    frames: usize,
    region: Region,
    make: impl Fn(&SceneMethods) -> Vec<Contender>,
) -> Result<(), String> {
    let scene = methods.scene();
    let mut failures = Vec::new();
    for &kind in walks {
        let params = EvalParams {
            walk: WalkParams {
                kind,
                frames,
                seed: 7,
                viewport: CHECK_VIEWPORT,
                ..WalkParams::default()
            },
            region,
            ..EvalParams::default()
        };
        let cameras = pvsd::eval::walk(scene, &params.walk)
            .map_err(|e| format!("{} {}: {e}", scene.id, kind.name()))?;
        let contenders = make(methods);
        assert!(!contenders.is_empty(), "no method to check");
        let report = pvsd::eval::run(scene, contenders, &cameras, &params, |_| {})
            .map_err(|e| e.to_string())?;
        for m in &report.methods {
            assert!(
                m.mean_truth > 0.0,
                "{} {}: the walk sees nothing, so it checks nothing",
                scene.id,
                kind.name()
            );
            if m.conservative && m.misses > 0 {
                let examples: Vec<String> = m
                    .miss_examples
                    .iter()
                    .map(|&(frame, id)| {
                        format!(
                            "frame {frame}: {} ({id})",
                            scene.objects()[id as usize].name
                        )
                    })
                    .collect();
                failures.push(format!(
                    "{} {} walk: {} misses by {}; {}",
                    scene.id,
                    kind.name(),
                    m.misses,
                    m.method,
                    examples.join(", ")
                ));
            }
        }
    }
    if failures.is_empty() {
        Ok(())
    } else {
        Err(failures.join("\n"))
    }
}

/// [`check_conservative`] for one method named by its spec (`frustum`, `occlusion_tree:k=32`).
pub fn assert_conservative(scene: &Arc<Scene>, method: &str, walks: &[WalkKind], frames: usize) {
    let spec: MethodSpec = method.parse().unwrap();
    let methods = prepare(scene.clone());
    check_conservative(&methods, walks, frames, |m| {
        vec![Contender::from_spec(m, &spec).unwrap()]
    })
    .unwrap_or_else(|e| panic!("{e}"));
}

/// Every method `methods` supports, once with its defaults and once with
/// each option set its registry entry is checked with
/// ([`pvsd::cull::MethodEntry::checked_with`]), as (label, method, options).
pub fn checked_methods(
    methods: &SceneMethods,
    registry: &Registry,
) -> Vec<(String, Arc<dyn Culler>, MethodOptions)> {
    let mut out = Vec::new();
    for method in methods.methods() {
        let entry = registry
            .entries()
            .iter()
            .find(|e| e.name == method.name())
            .expect("a prepared method has a registry entry");
        out.push((entry.name.to_string(), method.clone(), MethodOptions::new()));
        for options in entry.checked_with {
            let spec: MethodSpec = format!("{}:{options}", entry.name)
                .parse()
                .unwrap_or_else(|e| panic!("{}'s checked_with: {e}", entry.name));
            out.push((spec.to_string(), method.clone(), spec.options));
        }
    }
    out
}

/// Every checked method's answer for `cam` holds every truth-visible
/// object; returns how many objects the truth saw, so that a caller can
/// refuse cameras that check nothing.
pub fn check_camera(methods: &SceneMethods, registry: &Registry, cam: Camera) -> usize {
    let scene = methods.scene();
    // Truth and methods at the same viewport: a method that samples pixels
    // (gpu) answers for its view's pixel centres, as truth does.
    let cam = Camera {
        viewport: CHECK_VIEWPORT,
        ..cam
    };
    let truth = pvsd::truth::Truth::render(scene, &cam).unwrap();
    let view = pvsd::cull::View::new(cam, scene).unwrap();
    let visible = truth.visible();
    for (label, method, options) in checked_methods(methods, registry) {
        let job = CullJob::new(view, method.new_cache(&options).unwrap());
        let culled = methods.cull_blocking(&method, job).unwrap();
        assert!(
            culled.stats.fallback.is_none(),
            "{label} fell back from {cam:?}"
        );
        for &v in &visible {
            assert!(
                culled.job.out.ids().binary_search(&v).is_ok(),
                "{label} dropped {} ({v}) from {cam:?}",
                scene.objects()[v as usize].name
            );
        }
    }
    visible.len()
}

/// DESIGN's camera extremes over `methods`' scene: `cameras` random
/// cameras (far 1e6), every fourth with near 1e-6 and far 1e9, fov 0.01°
/// or 179°, each through [`check_camera`] (every method drops nothing
/// truth sees); at least a quarter of them must see something.
pub fn check_extreme_cameras(methods: &SceneMethods, seed: u64, cameras: usize) {
    let registry = Registry::standard();
    let mut r = rng(seed);
    let mut seen = Vec::new();
    for i in 0..cameras {
        let mut cam = random_camera(&mut r, methods.scene(), 0.0);
        cam.far = 1e6;
        match i % 4 {
            1 => (cam.near, cam.far) = (1e-6, 1e9),
            2 => cam.fov_y_deg = 0.01,
            3 => cam.fov_y_deg = 179.0,
            _ => {}
        }
        seen.push(check_camera(methods, &registry, cam));
    }
    assert_seen(&seen, 0.25);
}

/// At least `share` of the cameras saw something (counts from
/// [`check_camera`]): checks at extreme cameras were not vacuous.
pub fn assert_seen(seen: &[usize], share: f64) {
    let seeing = seen.iter().filter(|&&n| n > 0).count();
    assert!(
        seeing > 0 && seeing as f64 >= share * seen.len() as f64,
        "only {seeing} of {} cameras saw anything: {seen:?}",
        seen.len()
    );
}

/// Sends a request to a real server and decodes its JSON answer.
pub async fn fetch<T: serde::de::DeserializeOwned>(req: reqwest::RequestBuilder) -> T {
    let res = req.send().await.expect("the server answers");
    res.json().await.expect("a JSON answer")
}

/// The world triangles of a box without its underside (a building on the ground).
pub fn cuboid(min: glam::Vec3, max: glam::Vec3) -> Vec<[DVec3; 3]> {
    let mut m = pvsd::scene::generate::MeshBuilder::new();
    m.cuboid(min, max, false);
    m.build(false)
        .triangles()
        .map(|t| t.map(|v| v.as_dvec3()))
        .collect()
}

/// The machine's Vulkan device for the gpu tests, or `None` after saying
/// how to get one. With `PVSD_REQUIRE_GPU` set (CI sets it), a machine
/// without one fails instead: the gpu method must not go unchecked there.
pub fn gpu_or_skip(test: &str) -> Option<Arc<pvsd::cull::gpu::Gpu>> {
    match pvsd::cull::gpu::Gpu::of_this_machine() {
        Ok(gpu) => Some(gpu),
        Err(reason) if std::env::var_os("PVSD_REQUIRE_GPU").is_some() => {
            panic!("{test}: PVSD_REQUIRE_GPU is set, but gpu cannot run here: {reason}")
        }
        Err(reason) => {
            eprintln!(
                "{test}: skipped, no Vulkan device ({reason}); `apt-get install \
                 mesa-vulkan-drivers` gives lavapipe, and PVSD_REQUIRE_GPU=1 \
                 makes this a failure"
            );
            None
        }
    }
}

/// Starts `pvsd serve --addr 127.0.0.1:0` with `args` more and `envs` set
/// (logging at info; the user's cache folder moved to a scratch one unless
/// `envs` says otherwise) and waits until it is ready (its scenes loaded);
/// returns the child, the address its "listening on" line gives, and the
/// log lines until "ready". The caller stops the child.
pub fn spawn_serve(
    args: &[&str],
    envs: &[(&str, &str)],
) -> (std::process::Child, String, Vec<String>) {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    let scratch = std::env::temp_dir().join(format!("pvsd-test-cache-{}", std::process::id()));
    let mut child = Command::new(env!("CARGO_BIN_EXE_pvsd"))
        .env_remove("RUST_BACKTRACE")
        .env("RUST_LOG", "info")
        .env("XDG_CACHE_HOME", &scratch)
        .envs(envs.iter().copied())
        .args(["serve", "--addr", "127.0.0.1:0"])
        .args(args)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut before = Vec::new();
    let mut addr = None;
    loop {
        assert!(Instant::now() < deadline, "no 'ready' line");
        let line = lines.next().expect("server exited early").unwrap();
        if let Some(rest) = line.split("listening on http://").nth(1) {
            addr = rest.split_whitespace().next().map(str::to_string);
        }
        let ready = line.contains("ready: every scene is loaded");
        before.push(line);
        if ready {
            break;
        }
    }
    let addr = addr.expect("a 'listening on' line before 'ready'");
    // Keep draining its log so it never blocks on a full pipe.
    std::thread::spawn(move || lines.for_each(drop));
    (child, addr, before)
}

/// Boxes from 1e-4 to 1e5 units in one scene, some degenerate.
pub fn scales_scene() -> Arc<Scene> {
    let mut b = pvsd::scene::SceneBuilder::new("scales");
    let mut r = rng(3);
    for i in 0..400 {
        let size = 10f64.powf(r.random_range(-4.0..5.0));
        let c = DVec3::new(
            r.random_range(-2e4..2e4),
            r.random_range(-2e4..2e4),
            r.random_range(-2e4..2e4),
        );
        b.begin_object(format!("o{i}"), None);
        let tri = match i % 10 {
            0 => [c, c, c],                                           // a point
            1 => [c, c + DVec3::X * size, c + DVec3::X * size * 2.0], // zero area, a segment
            _ => [
                c,
                c + DVec3::new(size, 0.0, 0.0),
                c + DVec3::new(0.0, size, size),
            ],
        };
        b.add_triangles([tri], false);
    }
    Arc::new(b.finish())
}
