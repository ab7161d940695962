//! The gpu method on the machine's Vulkan device (lavapipe in CI): a
//! query's pixel count against ground truth's, the options, aggressive
//! culling measured against truth, the device worker under many
//! concurrent clients, and a machine without a Vulkan driver. Its
//! conservativeness is checked by the shared table (tests/conservative.rs).
//!
//! Each test skips with a message when the machine has no Vulkan device,
//! and fails instead when `PVSD_REQUIRE_GPU` is set (CI sets it).

mod common;

use std::ops::Range;
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::server::{Server, view_json};
use common::{gpu_or_skip, office_scene};
use glam::{DVec3, Vec3};
use pvsd::cull::gpu::Gpu;
use pvsd::cull::gpu::grid::Grid;
use pvsd::cull::gpu::movers::Movers;
use pvsd::cull::gpu::traversal::{Settings, Traversal};
use pvsd::cull::gpu::vulkan::{Mask, QuerySource, Setup};
use pvsd::cull::{DeviceLimits, MethodContext, MethodSpec, Occludees, Registry, View, VisibleSet};
use pvsd::eval::{Contender, EvalParams, WalkKind, WalkParams};
use pvsd::geom::Camera;
use pvsd::scene::{Scene, SceneBuilder};
use pvsd::server::{AppState, Limits};
use pvsd::truth::Truth;
use serde_json::{Value, json};

/// One pass of box queries against an empty depth buffer.
struct BoxQueries {
    setup: Setup,
    boxes: Vec<[Vec3; 2]>,
    counts: Vec<u64>,
    sent: bool,
}

impl QuerySource for BoxQueries {
    fn setup(&self) -> Setup {
        self.setup
    }
    fn next_pass(&mut self, _: &mut Vec<Range<u32>>, boxes: &mut Vec<[Vec3; 2]>) -> bool {
        if self.sent {
            return false;
        }
        self.sent = true;
        boxes.extend(&self.boxes);
        true
    }
    fn answer(&mut self, counts: &[u64]) {
        self.counts = counts.to_vec();
    }
}

/// A scene of one closed box.
fn box_scene(min: DVec3, max: DVec3) -> Scene {
    let mut m = pvsd::scene::generate::MeshBuilder::new();
    m.cuboid(min.as_vec3(), max.as_vec3(), true);
    let mesh = m.build(false);
    let mut b = SceneBuilder::new("box");
    b.begin_object("box", None);
    b.add_triangles(mesh.triangles().map(|t| t.map(|v| v.as_dvec3())), false);
    b.finish()
}

/// The box's pixel count by an occlusion query, the box drawn exactly.
fn query_pixels(gpu: &Gpu, scene: &Scene, camera: Camera) -> u64 {
    query_masked(gpu, scene, camera, None)
}

/// [`query_pixels`] counting only the pixels `mask` leaves important.
fn query_masked(gpu: &Gpu, scene: &Scene, camera: Camera, mask: Option<Mask>) -> u64 {
    let view = View::new(camera, scene).unwrap();
    let grid = Grid::build(scene);
    let (mut out, mut occludees) = (VisibleSet::new(), Occludees::default());
    let settings = Settings {
        batch: 1,
        tier: 0,
        threshold: 0,
        mask,
        merge: false,
        proxies: None,
        draw_visible: false,
    };
    let setup = Traversal::new(
        &grid,
        &Movers::default(),
        scene,
        &view,
        settings,
        &mut out,
        &mut occludees,
    )
    .setup();
    let b = scene.objects()[0].bounds;
    let eye = view.eye();
    let mut q = BoxQueries {
        setup,
        boxes: vec![[
            (b.min.as_dvec3() - eye).as_vec3(),
            (b.max.as_dvec3() - eye).as_vec3(),
        ]],
        counts: Vec::new(),
        sent: false,
    };
    let none = vec![[pvsd::cull::gpu::vulkan::NO_NEIGHBOUR; 3]; scene.triangles().len()];
    let geometry = gpu.vulkan().upload(scene, &[], &none).unwrap();
    gpu.vulkan().run(&geometry, &mut [&mut q]).unwrap();
    gpu.vulkan().release(&geometry);
    q.counts[0]
}

/// Where no edge passes through a pixel centre, a query counts exactly
/// the pixels ground truth sees the box at: both sample pixel centres.
/// Where edges pass exactly through centres (a box facing the camera,
/// its edges on pixel rows), truth counts a centre on an edge as covered
/// (inclusive edges) and the device applies the top-left rule, so it
/// counts fewer, by at most the pixels on the box's outline.
#[test]
fn a_query_counts_the_pixels_ground_truth_sees() {
    let Some(gpu) = gpu_or_skip("a_query_counts_the_pixels_ground_truth_sees") else {
        return;
    };
    let scene = box_scene(DVec3::new(-1.3, -0.7, 4.1), DVec3::new(0.9, 1.1, 6.3));
    for (i, eye) in [
        DVec3::new(0.31, 0.17, -0.23),
        DVec3::new(-2.7, 1.9, 0.4),
        DVec3::new(3.3, -2.1, 1.7),
    ]
    .into_iter()
    .enumerate()
    {
        let camera = Camera {
            eye,
            forward: DVec3::new(-0.2, 0.2, 5.2) - eye,
            up: DVec3::Y,
            fov_y_deg: 53.0,
            aspect: 1.5,
            near: 0.05,
            far: 100.0,
            viewport: [300, 200],
        };
        let truth = Truth::render(&scene, &camera).unwrap().pixels(0) as u64;
        let counted = query_pixels(&gpu, &scene, camera);
        assert!(
            truth > 1000,
            "view {i}: the box is on screen ({truth} pixels)"
        );
        assert_eq!(counted, truth, "view {i}: query vs truth");
    }

    // A square facing the camera whose edges lie exactly on pixel centres.
    let scene = box_scene(DVec3::new(-1.25, -1.25, 10.0), DVec3::new(1.25, 1.25, 12.0));
    let camera = Camera {
        eye: DVec3::ZERO,
        forward: DVec3::Z,
        up: DVec3::Y,
        // tan(fov/2) = 0.5: the square's edges at ±1.25 / (10 × 0.5) =
        // ±0.25 of the half-view, 100 pixels wide: at 37.5 and 62.5, the
        // centres of pixels 37 and 62 (up to the rounding of the tangent).
        fov_y_deg: 2.0 * 0.5f64.atan().to_degrees(),
        aspect: 1.0,
        near: 0.05,
        far: 100.0,
        viewport: [100, 100],
    };
    let truth = Truth::render(&scene, &camera).unwrap().pixels(0) as u64;
    let counted = query_pixels(&gpu, &scene, camera);
    eprintln!("edges on pixel centres: truth {truth}, query {counted}");
    assert!((24 * 24..=26 * 26).contains(&truth), "{truth}");
    assert!(
        counted <= truth && truth - counted <= 2 * 26,
        "{counted} vs {truth}"
    );
}

/// The importance masks (§3.4) leave the queries only the important
/// pixels: with fill 1, type I keeps the middle half of the screen in x
/// and y (a quarter of it), type II the middle third and half the pixels
/// of the frame around it.
#[test]
fn importance_masks_leave_queries_only_the_important_pixels() {
    let Some(gpu) = gpu_or_skip("importance_masks_leave_queries_only_the_important_pixels") else {
        return;
    };
    // A box that fills the whole view.
    let scene = box_scene(DVec3::new(-50.0, -50.0, 10.0), DVec3::new(50.0, 50.0, 12.0));
    let camera = Camera {
        eye: DVec3::ZERO,
        forward: DVec3::Z,
        up: DVec3::Y,
        fov_y_deg: 60.0,
        aspect: 1.5,
        near: 0.05,
        far: 100.0,
        viewport: [240, 160],
    };
    let all = query_pixels(&gpu, &scene, camera);
    assert_eq!(all, 240 * 160);
    let masked = |kind, fill| query_masked(&gpu, &scene, camera, Some(Mask { kind, fill }));
    assert_eq!(masked(1, 1.0), 120 * 80);
    // Type II: the middle third (80 × 54 pixels), and half of the frame
    // around it out to the middle two thirds (160 × 106 pixels).
    let ring = (160 * 106 - 80 * 54) as f64;
    let kept = masked(2, 1.0) as f64 - (80 * 54) as f64;
    assert!((kept / ring - 0.5).abs() < 0.05, "{kept} of {ring}");
    assert_eq!(masked(1, 0.0), all);
    // At fill 0.6, 60% of the frame's pixels are masked off, about.
    let frame = (all - 120 * 80) as f64;
    let kept = masked(1, 0.6) as f64 - (120 * 80) as f64;
    assert!((kept / frame - 0.4).abs() < 0.05, "{kept} of {frame}");
}

/// DESIGN's extremes of size: objects from 1e-4 to 1e5 units, points and
/// zero-area triangles, from random cameras and at near 1e-6, far 1e9,
/// fov 0.01° and 179° — every method, gpu among them, drops nothing truth
/// sees (the other extremes run every method in tests/occlusion.rs,
/// tests/horizon.rs and the table's 1e7 rows).
#[test]
fn tiny_huge_and_degenerate_objects_at_extreme_cameras() {
    if gpu_or_skip("tiny_huge_and_degenerate_objects_at_extreme_cameras").is_none() {
        return;
    }
    let methods = common::prepare(common::scales_scene());
    assert!(methods.names().contains(&"gpu"), "{:?}", methods.names());
    common::check_extreme_cameras(&methods, 5, 60);
}

/// Geometry 1e5 units from the scene's origin seen from a metre away: a
/// fence of posts (occluders) with small things behind its gaps. The
/// vertices are moved to the eye on the device, in `f32`; done naively
/// the eye alone is off by half an ulp of 1e5 (4 mm, half a pixel here).
#[test]
fn far_from_the_scene_origin_up_close() {
    if gpu_or_skip("far_from_the_scene_origin_up_close").is_none() {
        return;
    }
    let mut b = SceneBuilder::new("far");
    let cuboid = |min: DVec3, max: DVec3| {
        let mut m = pvsd::scene::generate::MeshBuilder::new();
        m.cuboid(min.as_vec3(), max.as_vec3(), true);
        m.build(false)
            .triangles()
            .map(|t| t.map(|v| v.as_dvec3()))
            .collect::<Vec<_>>()
    };
    // The far end of the scene: a ground 2e5 long puts the origin 1e5 away.
    b.begin_object("ground", Some(true));
    b.add_triangles(
        cuboid(DVec3::new(-1e5, -0.1, -5.0), DVec3::new(1e5, 0.0, 5.0)),
        false,
    );
    let x0 = 99_990.0;
    for i in 0..40 {
        let x = x0 + i as f64 * 0.05;
        b.begin_object(format!("post{i}"), Some(true));
        b.add_triangles(
            cuboid(DVec3::new(x, 0.0, 1.0), DVec3::new(x + 0.043, 2.0, 1.02)),
            false,
        );
        b.begin_object(format!("thing{i}"), None);
        let y = 0.2 + (i % 7) as f64 * 0.2;
        b.add_triangles(
            cuboid(
                DVec3::new(x + 0.02, y, 1.5),
                DVec3::new(x + 0.05, y + 0.03, 1.53),
            ),
            false,
        );
    }
    let methods = common::prepare(Arc::new(b.finish()));
    let registry = Registry::standard();
    let mut seen = Vec::new();
    let mut culled = 0;
    for i in 0..24 {
        let camera = Camera {
            eye: DVec3::new(x0 + 0.1 + 0.07 * i as f64, 1.0 + 0.01 * i as f64, 0.0),
            forward: DVec3::new(0.03 * (i % 5) as f64 - 0.06, -0.05, 1.0),
            up: DVec3::Y,
            fov_y_deg: 60.0,
            aspect: 1.6,
            near: 0.01,
            far: 1000.0,
            viewport: [256, 160],
        };
        seen.push(common::check_camera(&methods, &registry, camera));
        // The posts are too small against the scene to be proxies: the
        // depth they make is drawn from the visible objects' triangles.
        let truth = Truth::render(methods.scene(), &camera).unwrap().visible();
        let view = View::new(camera, methods.scene()).unwrap();
        let mut in_frustum = VisibleSet::new();
        methods
            .cull_once(&"frustum".parse().unwrap(), &view, &mut in_frustum)
            .unwrap();
        for spec in ["gpu:depth=geometry", "gpu:depth=both"] {
            let mut out = VisibleSet::new();
            methods
                .cull_once(&spec.parse().unwrap(), &view, &mut out)
                .unwrap();
            for id in &truth {
                assert!(out.contains(*id), "{spec} dropped {id} from {camera:?}");
            }
            culled += in_frustum.len() - out.len();
        }
    }
    common::assert_seen(&seen, 1.0);
    assert!(culled > 24, "the fence hid things ({culled})");
}

/// Options are read by name and range; aggressive ones say so.
#[test]
fn options_are_checked_and_aggressive_ones_are_not_conservative() {
    let Some(_) = gpu_or_skip("options_are_checked_and_aggressive_ones_are_not_conservative")
    else {
        return;
    };
    let methods = common::prepare(office_scene(1, [0.0; 3]));
    let gpu = methods.get("gpu").unwrap();
    for (spec, conservative) in [
        ("gpu", true),
        ("gpu:batch=1:tier=0", true),
        ("gpu:depth=geometry:merge=false", true),
        ("gpu:depth=proxies", true),
        ("gpu:contribution=0.001", false),
        ("gpu:importance=II", false),
        ("gpu:importance=I:fill=0", true),
    ] {
        let spec: MethodSpec = spec.parse().unwrap();
        let cache = gpu.new_cache(&spec.options).unwrap();
        assert_eq!(cache.is_conservative(), conservative, "{spec:?}");
    }
    for bad in [
        "gpu:batch=0",
        "gpu:batch=5000",
        "gpu:importance=III",
        "gpu:depth=none",
        "gpu:contribution=2",
        "gpu:colour=red",
    ] {
        let spec: MethodSpec = bad.parse().unwrap();
        let err = gpu.new_cache(&spec.options).unwrap_err().to_string();
        assert!(err.contains("gpu"), "{bad}: {err}");
    }
}

/// The paper's aggressive settings (§3.4), measured against truth: they
/// shrink the set, at a small share of wrong pixels.
#[test]
fn contribution_and_importance_culling_trade_pixels_for_a_smaller_set() {
    let Some(_) = gpu_or_skip("contribution_and_importance_culling") else {
        return;
    };
    let scene = common::city_scene(1000, 1, [0.0; 3]);
    let methods = common::prepare(scene.clone());
    let params = EvalParams {
        walk: WalkParams {
            kind: WalkKind::Street,
            frames: 12,
            seed: 3,
            viewport: [320, 200],
            ..WalkParams::default()
        },
        ..EvalParams::default()
    };
    let cameras = pvsd::eval::walk(&scene, &params.walk).unwrap();
    // A dithered frame at fill 0.6 still shows every object of more than a
    // few pixels (the paper measured 4.6% from it); a full frame hides
    // what lies only in it.
    let contenders = ["gpu", "gpu:contribution=0.001", "gpu:importance=II:fill=1"]
        .iter()
        .map(|s| {
            let spec: MethodSpec = s.parse().unwrap();
            Contender::new(
                s.to_string(),
                methods.get(&spec.name).unwrap().clone(),
                spec.options,
            )
            .unwrap()
        })
        .collect();
    let report = pvsd::eval::run(&scene, contenders, &cameras, &params, |_| {}).unwrap();
    let [exact, contribution, importance] = &report.methods[..] else {
        panic!("three methods");
    };
    assert_eq!(exact.misses, 0);
    assert!(contribution.mean_pvs < exact.mean_pvs, "{contribution:?}");
    assert!(contribution.wrong_pixel_share < 0.01, "{contribution:?}");
    assert!(importance.mean_pvs < exact.mean_pvs, "{importance:?}");
    assert!(!contribution.conservative && !importance.conservative);
}

/// 200 requests at once from many sessions and stateless clients: every
/// one is answered (200, or 503 with Retry-After when the device's queue
/// is full), each session's frames in order, and the server answers
/// afterwards: no deadlock.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_device_worker_serves_200_concurrent_requests() {
    if gpu_or_skip("the_device_worker_serves_200_concurrent_requests").is_none() {
        return;
    }
    // A device of its own with a small queue, so that it fills.
    let limits = DeviceLimits {
        capacity: 8,
        max_batch: 16,
        retry_after: Duration::from_millis(50),
        deadline: Duration::from_secs(60),
    };
    let context = MethodContext {
        gpu: Gpu::open(limits),
        ..MethodContext::of_this_machine()
    };
    let scene = office_scene(1, [0.0; 3]);
    let state = AppState::with_methods(
        vec![scene.clone()],
        Limits::default(),
        &Registry::standard(),
        &context,
    )
    .unwrap();
    let s = Arc::new(Server::start(state).await);
    let c = reqwest::Client::new();
    let mut rng = common::rng(11);
    let cameras: Vec<Camera> = (0..40)
        .map(|_| Camera {
            viewport: [256, 160],
            ..common::random_camera(&mut rng, &scene, 0.5)
        })
        .collect();
    let started = Instant::now();

    // 25 sessions × 4 frames, sent in order, retried when busy.
    let mut sessions = Vec::new();
    for i in 0..25 {
        let (c, s, cameras) = (c.clone(), s.clone(), cameras.clone());
        sessions.push(tokio::spawn(async move {
            let created: Value = c
                .post(s.url("/sessions"))
                .json(&json!({"scene": "office", "method": "gpu"}))
                .send()
                .await
                .unwrap()
                .json()
                .await
                .unwrap();
            let sid = created["session"].as_str().unwrap().to_string();
            let mut frames = Vec::new();
            let mut busy = 0;
            for k in 0..4 {
                loop {
                    let res = c
                        .post(s.url(&format!("/sessions/{sid}/frames")))
                        .json(&view_json(&cameras[(i + k) % cameras.len()]))
                        .send()
                        .await
                        .unwrap();
                    if res.status() == 503 {
                        assert!(res.headers().contains_key("retry-after"));
                        busy += 1;
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                    assert_eq!(res.status(), 200);
                    let f: Value = res.json().await.unwrap();
                    frames.push(f["frame"].as_u64().unwrap());
                    break;
                }
            }
            (frames, busy)
        }));
    }
    // And 100 stateless requests at once.
    let mut stateless = Vec::new();
    for i in 0..100 {
        let (c, s) = (c.clone(), s.clone());
        let mut body = view_json(&cameras[i % cameras.len()]);
        body["method"] = json!("gpu");
        stateless.push(tokio::spawn(async move {
            let res = c
                .post(s.url("/scenes/office/visible"))
                .json(&body)
                .send()
                .await
                .unwrap();
            let status = res.status().as_u16();
            let retry = res.headers().contains_key("retry-after");
            let v: Value = res.json().await.unwrap();
            (status, retry, v)
        }));
    }
    let mut refused = 0;
    for task in stateless {
        let (status, retry, v) = task.await.unwrap();
        match status {
            200 => assert_eq!(v["stats"]["method"], "gpu", "{v}"),
            503 => {
                assert!(retry, "a busy answer says when to retry");
                assert_eq!(v["error"]["code"], "busy", "{v}");
                refused += 1;
            }
            other => panic!("status {other}: {v}"),
        }
    }
    let mut busy_frames = 0;
    for task in sessions {
        let (frames, busy) = task.await.unwrap();
        assert_eq!(frames.len(), 4);
        assert!(
            frames.windows(2).all(|w| w[0] < w[1]),
            "in order: {frames:?}"
        );
        busy_frames += busy;
    }
    eprintln!(
        "200 requests in {:?}: {refused} stateless and {busy_frames} frames refused as busy",
        started.elapsed()
    );
    assert!(
        refused + busy_frames > 0,
        "a queue of 8 fills under 100 requests at once"
    );
    assert!(started.elapsed() < Duration::from_secs(120));
    // Still serving.
    let mut body = view_json(&cameras[0]);
    body["method"] = json!("gpu");
    let res = c
        .post(s.url("/scenes/office/visible"))
        .json(&body)
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 200);
}

/// A machine whose Vulkan loader finds no driver: `gpu` is unsupported on
/// every scene with the reason, and the server serves everything else.
#[test]
fn without_a_vulkan_driver_gpu_is_unsupported_and_the_server_serves() {
    let nowhere = "/nonexistent/pvsd-no-driver.json";
    // The loader's variables for where drivers are: pointed at nothing.
    let (mut child, addr, _) = common::spawn_serve(
        &[],
        &[("VK_DRIVER_FILES", nowhere), ("VK_ICD_FILENAMES", nowhere)],
    );
    let rt = tokio::runtime::Runtime::new().unwrap();
    let checked = rt.block_on(async {
        let c = reqwest::Client::new();
        let scenes: Value = common::fetch(c.get(format!("http://{addr}/scenes"))).await;
        let reason = scenes[0]["unsupported"]["gpu"]
            .as_str()
            .unwrap_or_default()
            .to_string();
        let gpu = c
            .post(format!("http://{addr}/scenes/city/visible"))
            .body(r#"{"eye":[60,1.7,-20],"forward":[1,0,0.3],"method":"gpu"}"#)
            .send()
            .await
            .unwrap();
        let gpu_status = gpu.status().as_u16();
        let frustum: Value = common::fetch(
            c.post(format!("http://{addr}/scenes/city/visible"))
                .body(r#"{"eye":[60,1.7,-20],"forward":[1,0,0.3]}"#),
        )
        .await;
        (reason, gpu_status, frustum)
    });
    let _ = child.kill();
    let _ = child.wait();
    let (reason, gpu_status, frustum) = checked;
    assert!(reason.contains("Vulkan"), "gpu's reason: {reason:?}");
    assert_eq!(gpu_status, 400, "asking for gpu is refused by name");
    assert!(
        !frustum["visible"].as_array().unwrap().is_empty(),
        "{frustum}"
    );
}
