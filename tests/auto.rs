//! `auto`: each scene's methods measured on its sample views, the cheapest
//! at the request's prices answering; the ranking in `/scenes`, kept in the
//! bake cache, and `auto`'s options checked by name.

mod common;

use std::path::Path;
use std::sync::Arc;

use axum::http::StatusCode;
use common::router::{NO_BODY, call};
use common::{city_scene, office_scene, test_context};
use pvsd::cull::ranking::FrameCost;
use pvsd::cull::{MethodSpec, Registry, SceneMethods};
use pvsd::eval::{RankParams, rank};
use pvsd::server::{AppState, Limits};
use pvsd_proto::json::{SceneInfo, VisibleResponse};
use serde_json::{Value, json};

/// Few small frames: the ranking's logic, not its figures, is under test.
const QUICK: RankParams = RankParams {
    frames_per_walk: 6,
    viewport: [320, 200],
    seed: 1,
};

/// A price per triangle at which drawing outweighs any cull time here.
const DRAWING_DOMINATES: FrameCost = FrameCost {
    per_triangle_ns: 1e6,
    per_byte_ns: 0.0,
};

const FREE: FrameCost = FrameCost {
    per_triangle_ns: 0.0,
    per_byte_ns: 0.0,
};

#[test]
fn every_conservative_method_is_measured_and_ranked_by_its_frame_cost() {
    let methods = SceneMethods::prepare_with(
        office_scene(7, [0.0; 3]),
        &Registry::standard(),
        &test_context(),
    );
    let ranking = rank(&methods, &QUICK);
    // An office has room at eye height: a street and a random walk.
    assert_eq!(ranking.walks, ["street", "random"]);
    assert_eq!(ranking.frames, 12);
    let ranked: Vec<&str> = ranking.measured.iter().map(|m| m.method.as_str()).collect();
    assert_eq!(ranked, methods.names(), "registry order, every method");
    let frustum = &ranking.measured[0];
    for m in &ranking.measured {
        assert!(m.mean_cull_us > 0.0 && m.median_cull_us > 0.0, "{m:?}");
        // Conservative methods answer within the frustum's set.
        assert!(m.mean_pvs <= frustum.mean_pvs + 1e-9, "{m:?}");
        assert!(m.mean_pvs_triangles <= frustum.mean_pvs_triangles + 1e-9);
    }
    // Where drawing is all that costs, the smallest answer wins; the office
    // has walls, so that is not frustum culling's.
    let best = ranking.best(DRAWING_DOMINATES).unwrap();
    let fewest = ranking
        .measured
        .iter()
        .min_by(|a, b| a.mean_pvs_triangles.total_cmp(&b.mean_pvs_triangles))
        .unwrap();
    assert_eq!(
        ranking
            .measured
            .iter()
            .find(|m| m.method == best)
            .unwrap()
            .mean_pvs_triangles,
        fewest.mean_pvs_triangles
    );
    assert_ne!(best, "frustum");
    // Where drawing is free, the quickest cull wins.
    let quickest = ranking
        .measured
        .iter()
        .min_by(|a, b| a.mean_cull_us.total_cmp(&b.mean_cull_us))
        .unwrap();
    assert_eq!(ranking.best(FREE), Some(quickest.method.as_str()));
    let costs: Vec<f64> = ranking
        .ranked(FrameCost::default())
        .iter()
        .map(|r| r.1)
        .collect();
    assert!(costs.windows(2).all(|w| w[0] <= w[1]), "{costs:?}");
}

#[test]
fn a_scene_with_no_room_at_eye_height_is_ranked_from_around_it() {
    let methods = SceneMethods::prepare_with(
        common::cad_scene(3, [0.0; 3]),
        &Registry::standard(),
        &test_context(),
    );
    let ranking = rank(&methods, &QUICK);
    assert_eq!(ranking.walks, ["orbit"]);
    assert_eq!(ranking.frames, 6);
    assert!(!ranking.measured.is_empty());
}

fn view(method: &str, options: Value) -> Value {
    json!({"eye": [0.5, 1.7, 0.5], "forward": [1, 0, 0.3], "viewport": [320, 200],
           "method": method, "options": options})
}

#[tokio::test]
async fn auto_answers_with_the_measured_best_at_the_requests_prices() {
    let state = AppState::with_methods(
        vec![office_scene(7, [0.0; 3])],
        Limits::default(),
        &Registry::standard(),
        &test_context(),
    )
    .unwrap();
    let (status, body) = call(&state, "GET", "/scenes", NO_BODY).await;
    assert_eq!(status, StatusCode::OK);
    let scenes: Vec<SceneInfo> = serde_json::from_value(body).unwrap();
    let auto = &scenes[0].auto;
    assert_eq!(
        (auto.status.as_str(), auto.choice.as_str()),
        ("unmeasured", "frustum")
    );
    assert!(auto.ranking.is_empty());
    // Before the ranking, auto is frustum culling.
    let (_, body) = call(
        &state,
        "POST",
        "/scenes/office/visible",
        Some(view("auto", json!({}))),
    )
    .await;
    assert_eq!(body["stats"]["method"], "frustum");

    state.rank_in_background(QUICK, None).join().unwrap();
    let (_, body) = call(&state, "GET", "/scenes", NO_BODY).await;
    let scenes: Vec<SceneInfo> = serde_json::from_value(body).unwrap();
    let auto = &scenes[0].auto;
    assert_eq!(auto.status, "measured");
    assert_eq!(auto.walks, ["street", "random"]);
    // What neither auto chose nor a client asked for is out of memory now;
    // the requests below build what they name again.
    let office = state.scenes().into_iter().next().unwrap().clone();
    let resident = office.resident();
    assert!(resident.len() < office.names().len(), "{resident:?}");
    assert!(resident.contains(&"frustum"), "{resident:?}");
    assert!(resident.contains(&auto.choice.as_str()), "{resident:?}");
    assert_eq!(auto.cost_per_triangle_ns, 2.0);
    assert_eq!(auto.choice, auto.ranking[0].method, "the cheapest first");
    for r in &auto.ranking {
        let modelled = r.mean_cull_us + r.mean_pvs_triangles * 2.0 * 1e-3;
        assert!((r.frame_cost_us - modelled).abs() < 1e-6, "{r:?}");
        assert_eq!(r.mean_pvs_bytes, r.mean_pvs_triangles * 36.0);
    }
    assert!(
        auto.ranking
            .windows(2)
            .all(|w| w[0].frame_cost_us <= w[1].frame_cost_us)
    );

    // A request's own prices: drawing dominates → the smallest answer's
    // method, which answers exactly as asked by name.
    let dear = json!({"cost_per_triangle_ns": 1e6});
    let (status, body) = call(
        &state,
        "POST",
        "/scenes/office/visible",
        Some(view("auto", dear)),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let chosen: VisibleResponse = serde_json::from_value(body).unwrap();
    let ranking = state
        .scenes()
        .into_iter()
        .next()
        .unwrap()
        .ranking()
        .unwrap()
        .clone();
    assert_eq!(
        Some(chosen.stats.method.as_str()),
        ranking.best(DRAWING_DOMINATES)
    );
    assert_ne!(chosen.stats.method, "frustum");
    let (_, body) = call(
        &state,
        "POST",
        "/scenes/office/visible",
        Some(view(&chosen.stats.method, json!({}))),
    )
    .await;
    let direct: VisibleResponse = serde_json::from_value(body).unwrap();
    assert_eq!(chosen.visible, direct.visible);
    // Free drawing: the quickest cull.
    let free = json!({"cost_per_triangle_ns": 0, "cost_per_byte_ns": 0});
    let (_, body) = call(
        &state,
        "POST",
        "/scenes/office/visible",
        Some(view("auto", free)),
    )
    .await;
    assert_eq!(
        Some(body["stats"]["method"].as_str().unwrap()),
        ranking.best(FREE)
    );

    // auto's options are its prices, checked by name and range.
    let (status, body) = call(
        &state,
        "POST",
        "/scenes/office/visible",
        Some(view("auto", json!({"k": 3}))),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert_eq!(body["error"]["code"], "unknown_option", "{body}");
    assert!(
        body["error"]["message"].as_str().unwrap().contains("'k'"),
        "{body}"
    );
    let bad = json!({"cost_per_byte_ns": -1});
    let (status, body) = call(
        &state,
        "POST",
        "/scenes/office/visible",
        Some(view("auto", bad)),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert!(
        body["error"]["message"]
            .as_str()
            .unwrap()
            .contains("cost_per_byte_ns"),
        "{body}"
    );
    // A session with auto's prices answers as that method does.
    let (status, body) = call(
        &state,
        "POST",
        "/sessions",
        Some(
            json!({"scene": "office", "method": "auto", "options": {"cost_per_triangle_ns": 1e6}}),
        ),
    )
    .await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    let sid = body["session"].as_str().unwrap().to_string();
    let (status, body) = call(
        &state,
        "POST",
        &format!("/sessions/{sid}/frames"),
        Some(json!({"eye": [0.5, 1.7, 0.5], "forward": [1, 0, 0.3], "viewport": [320, 200]})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let mut added: Vec<u32> = serde_json::from_value(body["added"].clone()).unwrap();
    added.sort_unstable();
    assert_eq!(added, direct.visible);
    assert!(office.resident().contains(&chosen.stats.method.as_str()));
}

/// A released method's data is freed, and the method built again on its
/// first ask answers as it did.
#[test]
fn methods_no_client_asked_for_are_released_and_answer_the_same_when_asked() {
    use pvsd::cull::View;
    use pvsd::geom::Camera;
    let methods = SceneMethods::prepare_with(
        city_scene(40, 6, [0.0; 3]),
        &Registry::standard(),
        &test_context(),
    );
    let names = methods.names();
    for needed in ["frustum", "horizon", "occlusion_tree", "supporting_planes"] {
        assert!(names.contains(&needed), "{names:?}");
    }
    let camera = Camera {
        eye: glam::DVec3::new(0.5, 1.7, 0.5),
        forward: glam::DVec3::new(1.0, 0.0, 0.3),
        aspect: 1.6,
        viewport: [320, 200],
        ..Camera::default()
    };
    let view = View::new(camera, methods.scene()).unwrap();
    let answers = |methods: &SceneMethods| -> Vec<(String, Vec<u32>)> {
        names
            .iter()
            .map(|&name| {
                let mut out = pvsd::cull::VisibleSet::new();
                methods
                    .cull_once(&name.parse().unwrap(), &view, &mut out)
                    .unwrap();
                (name.to_string(), out.ids().to_vec())
            })
            .collect()
    };
    // Asking marks a method as a client's: the answers before come from
    // a twin preparation.
    let before = answers(&SceneMethods::prepare_with(
        city_scene(40, 6, [0.0; 3]),
        &Registry::standard(),
        &test_context(),
    ));
    methods.set_ranking(ranking_of(
        names
            .iter()
            .map(|&n| (n, if n == "horizon" { 1.0 } else { 100.0 })),
    ));
    assert_eq!(methods.auto_choice(methods.frame_cost()), "horizon");
    // Asked by a client before the release, kept.
    methods.get("supporting_planes").unwrap();
    let tree = Arc::downgrade(&methods.get("occlusion_tree").unwrap());
    methods.methods(); // ranking's use is not a client's ask
    let released = methods.release_unasked();
    assert!(!released.contains(&"supporting_planes"), "{released:?}");
    assert!(!released.contains(&"occlusion_tree"), "{released:?}");
    assert!(tree.upgrade().is_some());
    let mut expected: Vec<&str> = names
        .iter()
        .copied()
        .filter(|n| !["frustum", "horizon", "supporting_planes", "occlusion_tree"].contains(n))
        .collect();
    expected.retain(|&n| n != "gpu"); // a device method stays
    assert_eq!(released, expected);
    assert!(!released.is_empty());
    assert!(!methods.resident().contains(&"raster"), "{released:?}");

    // A method released while no one held it is freed.
    let fresh = SceneMethods::prepare_with(
        city_scene(40, 6, [0.0; 3]),
        &Registry::standard(),
        &test_context(),
    );
    let gone = Arc::downgrade(
        &fresh.methods()[fresh
            .names()
            .iter()
            .position(|&n| n == "occlusion_tree")
            .unwrap()],
    );
    assert!(fresh.release_unasked().contains(&"occlusion_tree"));
    assert!(gone.upgrade().is_none(), "its data is freed");
    assert!(fresh.get("occlusion_tree").is_ok());

    // Built again on the ask, the same answers.
    assert_eq!(answers(&methods), before);
    assert_eq!(methods.resident(), names);
}

/// `pvsd bake` ranks the methods and keeps the ranking in the bake folder;
/// the next bake reads it, and a damaged file is measured anew.
#[test]
fn the_ranking_is_baked_and_a_damaged_one_is_remeasured() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("town.glb");
    let bakes = dir.path().join("bakes");
    let doc = pvsd::scene::generate::city(&pvsd::scene::generate::CityOptions {
        seed: 2,
        buildings: 60,
        ..Default::default()
    });
    std::fs::write(&scene, doc.to_glb()).unwrap();
    let bake = || {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_pvsd"))
            .env("RUST_LOG", "info")
            .env("NO_COLOR", "1")
            .args(["bake", "--scene", scene.to_str().unwrap(), "--bake-dir"])
            .arg(&bakes)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        (
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (first, log) = bake();
    assert!(first.contains("methods ranked for auto"), "{first}");
    assert!(
        first.contains("frame cost µs") && first.contains("horizon"),
        "{first}"
    );
    assert!(baked(&log, "none yet"), "{log}");
    let file = ranking_file(&bakes);
    let (second, log) = bake();
    assert!(
        log.lines()
            .any(|l| l.contains("loaded a bake") && l.contains("\"ranking\"")),
        "{log}"
    );
    // The same figures, read back.
    let table = |out: &str| {
        out.lines()
            .skip_while(|l| !l.starts_with("auto on"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(table(&first), table(&second));
    // A flipped payload byte fails the checksum: measured anew, saying why.
    let mut bytes = std::fs::read(&file).unwrap();
    let last = bytes.len() - 2;
    bytes[last] ^= 0x20;
    std::fs::write(&file, bytes).unwrap();
    let (_, log) = bake();
    assert!(baked(&log, "checksum"), "{log}");
}

/// Whether the log says the ranking was measured, for a reason saying `why`.
fn baked(log: &str, why: &str) -> bool {
    log.lines()
        .any(|l| l.contains(" baked ") && l.contains("\"ranking\"") && l.contains(why))
}

fn ranking_file(dir: &Path) -> std::path::PathBuf {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.to_string_lossy().contains("-ranking-"))
        .expect("a ranking bake")
}

#[test]
fn a_ranking_made_for_other_methods_is_not_trusted() {
    // Prepared with horizon off, then read by a server that has it: the
    // cached ranking would leave horizon out, so it is measured anew.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("town.glb");
    let doc = pvsd::scene::generate::city(&pvsd::scene::generate::CityOptions {
        seed: 4,
        buildings: 40,
        ..Default::default()
    });
    std::fs::write(&path, doc.to_glb()).unwrap();
    let scene = Arc::new(pvsd::scene::load_path(&path).unwrap());
    let cache = pvsd::scene::BakeCache::new(dir.path().join("bakes"));
    let mut context = test_context();
    context.disabled = vec!["horizon".into(), "gpu".into()];
    let without = SceneMethods::prepare_with(scene.clone(), &Registry::standard(), &context);
    let first = pvsd::eval::rank_cached(&without, &QUICK, Some(&cache));
    assert!(first.measured.iter().all(|m| m.method != "horizon"));
    context.disabled = vec!["gpu".into()];
    let with = SceneMethods::prepare_with(scene, &Registry::standard(), &context);
    let second = pvsd::eval::rank_cached(&with, &QUICK, Some(&cache));
    assert!(second.measured.iter().any(|m| m.method == "horizon"));
    // And the spec of a ranked method names it with its defaults.
    let spec: MethodSpec = "auto:cost_per_triangle_ns=5".parse().unwrap();
    assert!(with.set_ranking(second));
    let (m, options) = with.resolve(&spec).unwrap();
    assert!(options.is_empty());
    assert!(with.names().contains(&m.name()));
}

#[test]
fn the_city_ranks_every_method_it_supports() {
    let methods = SceneMethods::prepare_with(
        city_scene(120, 5, [0.0; 3]),
        &Registry::standard(),
        &test_context(),
    );
    let ranking = rank(&methods, &QUICK);
    assert_eq!(ranking.walks, ["street", "random"]);
    let ranked: Vec<&str> = ranking.measured.iter().map(|m| m.method.as_str()).collect();
    assert_eq!(ranked, methods.names());
}

/// A blocking method measured fast on a scene runs inline there: the
/// hand-off to the blocking pool would cost more than the cull.
#[test]
fn methods_measured_fast_run_inline() {
    use pvsd::cull::Execution;
    let methods = SceneMethods::prepare_with(
        city_scene(40, 6, [0.0; 3]),
        &Registry::standard(),
        &test_context(),
    );
    let kind = |name: &str| match methods.execution_of(methods.get(name).unwrap().as_ref()) {
        Execution::Inline => "inline",
        Execution::Blocking => "blocking",
        Execution::Device(_) => "device",
    };
    assert_eq!(
        (kind("frustum"), kind("horizon"), kind("supporting_planes")),
        ("inline", "blocking", "blocking"),
        "unmeasured, each where it says"
    );
    methods.set_ranking(ranking_of([
        ("frustum", 5.0),
        ("horizon", pvsd::cull::INLINE_BELOW_US * 0.5),
        ("supporting_planes", pvsd::cull::INLINE_BELOW_US * 2.0),
    ]));
    assert_eq!(
        (kind("frustum"), kind("horizon"), kind("supporting_planes")),
        ("inline", "inline", "blocking")
    );
}

/// A released method whose build fails the second time answers a clear
/// 500 naming the method and why, and the server goes on answering.
#[tokio::test]
async fn a_method_that_cannot_be_built_again_is_a_clear_error() {
    use pvsd::cull::MethodEntry;
    use std::sync::atomic::{AtomicBool, Ordering};
    static BUILT: AtomicBool = AtomicBool::new(false);
    let horizon = pvsd::cull::horizon::ENTRY;
    let registry = Registry::standard().with(MethodEntry {
        regions: None,
        build: |p| {
            if BUILT.swap(true, Ordering::SeqCst) {
                Err("the prisms are gone".into())
            } else {
                (pvsd::cull::horizon::ENTRY.build)(p)
            }
        },
        ..horizon
    });
    let state = AppState::with_methods(
        vec![city_scene(40, 6, [0.0; 3])],
        Limits::default(),
        &registry,
        &test_context(),
    )
    .unwrap();
    let city = state.scenes().into_iter().next().unwrap().clone();
    city.set_ranking(ranking_of([("frustum", 1.0), ("horizon", 100.0)]));
    assert!(city.release_unasked().contains(&"horizon"));
    let (status, body) = call(
        &state,
        "POST",
        "/scenes/city/visible",
        Some(view("horizon", json!({}))),
    )
    .await;
    assert_eq!(status, StatusCode::INTERNAL_SERVER_ERROR, "{body}");
    assert_eq!(body["error"]["code"], "internal", "{body}");
    let message = body["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("'horizon'") && message.contains("the prisms are gone"),
        "{message}"
    );
    let (status, body) = call(
        &state,
        "POST",
        "/scenes/city/visible",
        Some(view("frustum", json!({}))),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
}

/// A ranking measured as given: each method's mean cull time, one id and
/// one triangle a frame.
fn ranking_of<'a>(
    cull_us: impl IntoIterator<Item = (&'a str, f64)>,
) -> pvsd::cull::ranking::Ranking {
    use pvsd::cull::ranking::{Measured, Ranking};
    Ranking {
        walks: vec!["street".into()],
        frames: 1,
        viewport: [64, 64],
        measured: cull_us
            .into_iter()
            .map(|(method, us)| Measured {
                method: method.into(),
                mean_cull_us: us,
                median_cull_us: us,
                mean_pvs: 1.0,
                mean_pvs_triangles: 1.0,
            })
            .collect(),
    }
}
