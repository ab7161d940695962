//! What a thin client needs beside visible sets, through the router: the
//! objects' triangles (`application/x-pvs-mesh`, with ETags and batches),
//! walks to replay, the viewer's files, and frames with their stats on the
//! WebSocket.

mod common;

use std::sync::Arc;

use axum::http::StatusCode;
use common::router::{NO_BODY, call, call_raw};
use common::server::{Held, Server, new_session};
use futures_util::{SinkExt, StreamExt};
use glam::DVec3;
use pvsd::scene::{Scene, SceneBuilder};
use pvsd::server::{AppState, Limits};
use pvsd_proto::mesh::{self, Meshes};
use pvsd_proto::xpvs::{self, Message as XMessage};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

fn city() -> AppState {
    AppState::new(
        vec![common::city_scene(60, 3, [1.0e6, 0.0, -2.0e6])],
        Limits::default(),
    )
    .unwrap()
}

/// The triangles of `meshes` in world coordinates, as f64.
fn world_triangles(meshes: &Meshes, at: usize) -> Vec<[DVec3; 3]> {
    let m = &meshes.meshes[at];
    let o = DVec3::from_array(meshes.origin);
    m.indices
        .chunks(3)
        .map(|t| {
            [0, 1, 2].map(|k| o + glam::Vec3::from_array(m.positions[t[k] as usize]).as_dvec3())
        })
        .collect()
}

/// The scene's own triangles of object `id`, world coordinates.
fn scene_triangles(scene: &Scene, id: u32) -> Vec<[DVec3; 3]> {
    scene
        .object_triangles(&scene.objects()[id as usize])
        .iter()
        .map(|t| t.map(|v| scene.origin + v.as_dvec3()))
        .collect()
}

#[tokio::test]
async fn an_objects_mesh_is_its_exact_triangles_with_a_strong_etag() {
    let state = city();
    let scene = state.scene("city").unwrap().scene().clone();
    for id in [0u32, 1, 7] {
        let uri = format!("/scenes/city/objects/{id}/mesh");
        let (status, headers, bytes) = call_raw(&state, "GET", &uri, NO_BODY, &[]).await;
        assert_eq!(status, StatusCode::OK);
        assert_eq!(headers["content-type"], mesh::CONTENT_TYPE);
        assert_eq!(headers["cache-control"], "no-cache");
        let tag = headers["etag"].to_str().unwrap().to_string();
        assert!(
            tag.starts_with('"') && tag.ends_with('"') && tag.len() == 34,
            "{tag}"
        );
        let decoded = mesh::decode(&bytes).unwrap();
        assert_eq!(decoded.meshes.len(), 1);
        assert_eq!(decoded.meshes[0].id, id);
        // Far from the world's origin (1e6, -2e6), still the very
        // triangles the methods cull with: positions are f32s about the
        // scene's origin.
        assert_eq!(world_triangles(&decoded, 0), scene_triangles(&scene, id));
        assert!(decoded.meshes[0].positions.len() < decoded.meshes[0].indices.len());

        // Revalidation: the same tag answers 304 without a body; another
        // (or a list holding it) as it should.
        let (status, headers, body) =
            call_raw(&state, "GET", &uri, NO_BODY, &[("if-none-match", &tag)]).await;
        assert_eq!(status, StatusCode::NOT_MODIFIED);
        assert_eq!(headers["etag"], tag.as_str());
        assert!(body.is_empty());
        let list = format!("\"0123\", {tag}");
        let (status, ..) =
            call_raw(&state, "GET", &uri, NO_BODY, &[("if-none-match", &list)]).await;
        assert_eq!(status, StatusCode::NOT_MODIFIED);
        let (status, ..) = call_raw(
            &state,
            "GET",
            &uri,
            NO_BODY,
            &[("if-none-match", "\"other\"")],
        )
        .await;
        assert_eq!(status, StatusCode::OK);
    }
    let (status, h0, _) =
        call_raw(&state, "GET", "/scenes/city/objects/1/mesh", NO_BODY, &[]).await;
    let (_, h1, _) = call_raw(&state, "GET", "/scenes/city/objects/2/mesh", NO_BODY, &[]).await;
    assert_eq!(status, StatusCode::OK);
    assert_ne!(h0["etag"], h1["etag"], "different bytes, different tags");
}

#[tokio::test]
async fn a_batch_answers_in_the_order_asked_and_refuses_what_is_not_there() {
    let state = city();
    let scene = state.scene("city").unwrap().scene().clone();
    let body = json!({"ids": [5, 0, 5, 3]});
    let (status, headers, bytes) =
        call_raw(&state, "POST", "/scenes/city/meshes", Some(&body), &[]).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(headers["content-type"], mesh::CONTENT_TYPE);
    let decoded = mesh::decode(&bytes).unwrap();
    let ids: Vec<u32> = decoded.meshes.iter().map(|m| m.id).collect();
    assert_eq!(ids, [5, 0, 3], "a repeated id once, at its first place");
    for (at, &id) in ids.iter().enumerate() {
        assert_eq!(world_triangles(&decoded, at), scene_triangles(&scene, id));
    }
    // 1,024 repeats of one object are one mesh, not 1,024.
    let (_, _, repeated) = call_raw(
        &state,
        "POST",
        "/scenes/city/meshes",
        Some(json!({"ids": vec![5; 1024]})),
        &[],
    )
    .await;
    assert_eq!(mesh::decode(&repeated).unwrap().meshes.len(), 1);
    // The same mesh as one at a time.
    let (_, _, one) = call_raw(&state, "GET", "/scenes/city/objects/5/mesh", NO_BODY, &[]).await;
    let single = mesh::decode(&one).unwrap();
    assert_eq!(single.meshes[0], decoded.meshes[0]);

    // No ids: the scene's origin alone, which a client reads first.
    let (status, _, bytes) = call_raw(
        &state,
        "POST",
        "/scenes/city/meshes",
        Some(json!({"ids": []})),
        &[],
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(bytes.len(), mesh::HEADER_BYTES);
    assert_eq!(
        mesh::decode(&bytes).unwrap().origin,
        scene.origin.to_array()
    );

    let n = scene.objects().len();
    for (uri, body, want, code, names) in [
        (
            "/scenes/city/meshes",
            json!({"ids": [0, n]}),
            404,
            "unknown_object",
            n.to_string(),
        ),
        (
            "/scenes/city/meshes",
            json!({"ids": [-1]}),
            400,
            "malformed_json",
            "ids".to_string(),
        ),
        (
            "/scenes/city/meshes",
            json!({"id": [1]}),
            400,
            "malformed_json",
            "id".to_string(),
        ),
        (
            "/scenes/city/meshes",
            json!({"ids": vec![0; 1025]}),
            413,
            "body_too_complex",
            "1024".to_string(),
        ),
        (
            "/scenes/town/meshes",
            json!({"ids": [0]}),
            404,
            "unknown_scene",
            "town".to_string(),
        ),
    ] {
        let (status, v) = call(&state, "POST", uri, Some(&body)).await;
        assert_eq!(status.as_u16(), want, "{body}: {v}");
        assert_eq!(v["error"]["code"], code, "{body}: {v}");
        let message = v["error"]["message"].as_str().unwrap();
        assert!(message.contains(&names), "{message} should name {names}");
    }
    for (uri, code) in [
        (format!("/scenes/city/objects/{n}/mesh"), "unknown_object"),
        ("/scenes/city/objects/x/mesh".to_string(), "unknown_object"),
        ("/scenes/city/objects/-1/mesh".to_string(), "unknown_object"),
        ("/scenes/town/objects/0/mesh".to_string(), "unknown_scene"),
    ] {
        let (status, v) = call(&state, "GET", &uri, NO_BODY).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}: {v}");
        assert_eq!(v["error"]["code"], code, "{uri}");
    }
}

#[tokio::test]
async fn see_through_triangles_come_last_and_are_counted_apart() {
    let mut b = SceneBuilder::new("plants");
    b.begin_object("pot", None);
    let (p, q, r) = (DVec3::ZERO, DVec3::X, DVec3::Y);
    b.add_triangles([[p, q, r]], true);
    b.add_triangles([[p, r, DVec3::Z], [q, r, DVec3::Z]], false);
    b.add_triangles([[p, q, DVec3::Z]], true);
    let state = AppState::new(vec![Arc::new(b.finish())], Limits::default()).unwrap();
    let (_, _, bytes) =
        call_raw(&state, "GET", "/scenes/plants/objects/0/mesh", NO_BODY, &[]).await;
    let m = &mesh::decode(&bytes).unwrap().meshes[0];
    assert_eq!(m.indices.len(), 12);
    assert_eq!(
        m.opaque, 2,
        "two opaque triangles, then the two see-through ones"
    );
    assert_eq!(m.positions.len(), 4, "vertices shared");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_walk_is_the_evals_path_at_the_step_asked() {
    let state = city();
    let (status, w) = call(&state, "GET", "/scenes/city/walk", NO_BODY).await;
    assert_eq!(status, StatusCode::OK, "{w}");
    assert_eq!(w["kind"], "street");
    assert_eq!(w["step"], Value::Null);
    assert_eq!(w["views"].as_array().unwrap().len(), 600);
    let (_, again) = call(&state, "GET", "/scenes/city/walk", NO_BODY).await;
    assert_eq!(w, again, "deterministic");

    let (status, w) = call(
        &state,
        "GET",
        "/scenes/city/walk?frames=50&step=0.25&seed=4",
        NO_BODY,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{w}");
    let eyes: Vec<DVec3> = w["views"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| DVec3::from_array(serde_json::from_value(v["eye"].clone()).unwrap()))
        .collect();
    assert_eq!(eyes.len(), 50);
    // Even steps, a little shorter only where the path turns a corner.
    let steps: Vec<f64> = eyes.windows(2).map(|p| p[0].distance(p[1])).collect();
    assert!(steps.iter().all(|&s| s <= 0.25 + 1e-9), "{steps:?}");
    assert!(
        steps.iter().filter(|&&s| s > 0.2499).count() >= 40,
        "{steps:?}"
    );
    let v = &w["views"][0];
    let f: [f64; 3] = serde_json::from_value(v["forward"].clone()).unwrap();
    assert!((DVec3::from_array(f).length() - 1.0).abs() < 1e-12);
    assert!(v["near"].as_f64().unwrap() > 0.0 && v["far"].as_f64().unwrap() > 100.0);

    for (q, names) in [
        ("kind=flying", "flying"),
        ("frames=0", "frames"),
        ("frames=10001", "frames"),
        ("step=0", "step"),
        ("step=nan", "step"),
        ("step=1000", "step"),
        ("pace=3", "pace"),
    ] {
        let (status, v) = call(&state, "GET", &format!("/scenes/city/walk?{q}"), NO_BODY).await;
        assert_eq!(status, StatusCode::BAD_REQUEST, "{q}: {v}");
        assert_eq!(v["error"]["code"], "invalid_query", "{q}");
        assert!(
            v["error"]["message"].as_str().unwrap().contains(names),
            "{q}: {v}"
        );
    }
    // A scene with no geometry has no walk: a named 422.
    let mut b = SceneBuilder::new("void");
    b.begin_object("nothing", None);
    let empty = AppState::new(vec![Arc::new(b.finish())], Limits::default()).unwrap();
    let (status, v) = call(&empty, "GET", "/scenes/void/walk", NO_BODY).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{v}");
    assert_eq!(v["error"]["code"], "no_walk");
}

#[tokio::test]
async fn the_viewer_is_served_from_the_binary() {
    let state = city();
    for uri in ["/", "/viewer", "/viewer?scene=city&method=horizon"] {
        let (status, headers, body) = call_raw(&state, "GET", uri, NO_BODY, &[]).await;
        assert_eq!(status, StatusCode::OK, "{uri}");
        assert_eq!(headers["content-type"], "text/html; charset=utf-8");
        let html = String::from_utf8(body.to_vec()).unwrap();
        assert!(html.contains("<title>pvsd viewer</title>"));
        // Every file the page names is served.
        for file in ["/viewer/viewer.js", "/viewer/viewer.css"] {
            assert!(html.contains(file), "{file}");
        }
    }
    for (file, kind, cache) in [
        ("viewer.js", "text/javascript; charset=utf-8", "no-cache"),
        ("protocol.js", "text/javascript; charset=utf-8", "no-cache"),
        ("viewer.css", "text/css; charset=utf-8", "no-cache"),
        (
            "three-0.170.0.module.min.js",
            "text/javascript; charset=utf-8",
            "public, max-age=31536000, immutable",
        ),
    ] {
        let (status, headers, body) =
            call_raw(&state, "GET", &format!("/viewer/{file}"), NO_BODY, &[]).await;
        assert_eq!(status, StatusCode::OK, "{file}");
        assert_eq!(headers["content-type"], kind, "{file}");
        assert_eq!(headers["cache-control"], cache, "{file}");
        assert!(!body.is_empty());
    }
    // The scripts import only what is served (no network at run time).
    let (_, _, js) = call_raw(&state, "GET", "/viewer/viewer.js", NO_BODY, &[]).await;
    let js = String::from_utf8(js.to_vec()).unwrap();
    for line in js.lines().filter(|l| l.starts_with("import ")) {
        let target = line.split('\'').nth(1).unwrap();
        let (status, ..) = call_raw(
            &state,
            "GET",
            &format!("/viewer/{}", target.trim_start_matches("./")),
            NO_BODY,
            &[],
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{line}");
        assert!(!target.contains("//"), "{line}");
    }
    for uri in [
        "/viewer/nope.js",
        "/viewer/..%2FCargo.toml",
        "/viewer/THREE-LICENSE.txt",
    ] {
        let (status, v) = call(&state, "GET", uri, NO_BODY).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
        assert_eq!(v["error"]["code"], "not_found");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn websocket_frames_carry_their_stats_when_asked() {
    let s = Server::start(city()).await;
    let c = reqwest::Client::new();
    let walk: Value = common::fetch(c.get(s.url("/scenes/city/walk?frames=3"))).await;
    for (query, binary, stats) in [
        ("?encoding=x-pvs&stats=true", true, true),
        ("?stats=true", false, true),
        ("?encoding=x-pvs", true, false),
        ("?encoding=x-pvs&stats=false", true, false),
    ] {
        let sid = new_session(&c, &s, json!({"scene": "city", "method": "horizon"})).await;
        let (mut ws, _) =
            tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws{query}")))
                .await
                .unwrap();
        let mut view = walk["views"][0].clone();
        view["viewport"] = json!([640, 400]);
        ws.send(Message::text(view.to_string())).await.unwrap();
        let frame = match ws.next().await.unwrap().unwrap() {
            Message::Binary(b) if binary => match xpvs::decode(&b).unwrap() {
                XMessage::Frame(f) => f,
                other => panic!("{other:?}"),
            },
            Message::Text(t) if !binary => serde_json::from_str(&t).unwrap(),
            other => panic!("{query}: {other:?}"),
        };
        assert_eq!(frame.frame, 1);
        match (&frame.stats, stats) {
            (Some(st), true) => {
                assert_eq!(st.method, "horizon", "{query}");
                assert!(st.cull_us > 0.0, "{query}");
                assert_eq!(st.visible as usize, frame.added.len(), "{query}");
            }
            (None, false) => {}
            (got, _) => panic!("{query}: stats {got:?}"),
        }
    }
    // A bad value is a named refusal of the upgrade.
    let sid = new_session(&c, &s, json!({"scene": "city"})).await;
    let res = c
        .get(s.url(&format!("/sessions/{sid}/ws?stats=maybe")))
        .header("connection", "upgrade")
        .header("upgrade", "websocket")
        .header("sec-websocket-version", "13")
        .header("sec-websocket-key", "dGhlIHNhbXBsZSBub25jZQ==")
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), StatusCode::BAD_REQUEST);
    let v: Value = res.json().await.unwrap();
    assert_eq!(v["error"]["code"], "invalid_query");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenes_list_the_options_each_method_takes() {
    let state = city();
    let (_, scenes) = call(&state, "GET", "/scenes", NO_BODY).await;
    let city = &scenes[0];
    let options = city["options"].as_object().unwrap();
    let mut methods: Vec<&str> = city["methods"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap())
        .collect();
    methods.push("auto");
    let listed: Vec<&str> = options.keys().map(String::as_str).collect();
    let mut sorted = methods.clone();
    sorted.sort_unstable();
    assert_eq!(listed, sorted, "every supported method and auto, no other");
    assert_eq!(options["frustum"], json!([]));
    assert_eq!(
        options["supporting_planes"],
        json!(["k", "lambda", "min_cost", "temporal"])
    );
    // Each listed key is one the method reads (a bad value is refused as
    // invalid, never as unknown), and an unlisted one is unknown.
    for m in methods {
        for key in options[m].as_array().unwrap() {
            let body =
                json!({"scene": "city", "method": m, "options": {key.as_str().unwrap(): "?"}});
            let (_, v) = call(&state, "POST", "/sessions", Some(&body)).await;
            assert_ne!(v["error"]["code"], "unknown_option", "{m} {key}: {v}");
        }
        let body = json!({"scene": "city", "method": m, "options": {"no_such_knob": 1}});
        let (_, v) = call(&state, "POST", "/sessions", Some(&body)).await;
        assert_eq!(v["error"]["code"], "unknown_option", "{m}: {v}");
    }
}

/// The measure at the 1k city's scale, as a thin client streams
/// it: a 60-second street walk (1,800 frames, 10 m/s) over a session's
/// WebSocket, fetching each object's mesh the first time it is in the set,
/// costs a small share of the scene file (docs/viewer.md has the 10k
/// city's figures and the browser's).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_street_walk_streams_a_small_share_of_the_scene_file() {
    let options = pvsd::scene::generate::CityOptions {
        seed: 7,
        buildings: 1000,
        ..Default::default()
    };
    let file = pvsd::scene::generate::city(&options).to_glb().len();
    let s = Server::start(
        AppState::new(
            vec![common::city_scene(1000, 7, [0.0; 3])],
            Limits::default(),
        )
        .unwrap(),
    )
    .await;
    let c = reqwest::Client::new();
    let walk: Value =
        common::fetch(c.get(s.url("/scenes/city/walk?frames=1800&step=0.3333"))).await;
    let sid = new_session(&c, &s, json!({"scene": "city", "method": "horizon"})).await;
    let (mut ws, _) =
        tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws?encoding=x-pvs")))
            .await
            .unwrap();
    // `visible`: the set held; `meshes`: the ids whose triangles are held.
    let (mut visible, mut meshes) = (Held::default(), std::collections::BTreeSet::new());
    let mut fetched = 0;
    for v in walk["views"].as_array().unwrap() {
        let mut view = v.clone();
        view["viewport"] = json!([1024, 640]);
        view["base"] = json!(visible.frame);
        ws.send(Message::text(view.to_string())).await.unwrap();
        let Some(Ok(Message::Binary(b))) = ws.next().await else {
            panic!("no frame");
        };
        let XMessage::Frame(f) = xpvs::decode(&b).unwrap() else {
            panic!("not a frame");
        };
        visible.apply(&f);
        let missing: Vec<u32> = visible.ids.difference(&meshes).copied().collect();
        if !missing.is_empty() {
            let bytes = c
                .post(s.url("/scenes/city/meshes"))
                .json(&json!({ "ids": missing }))
                .send()
                .await
                .unwrap()
                .bytes()
                .await
                .unwrap();
            assert_eq!(mesh::decode(&bytes).unwrap().meshes.len(), missing.len());
            fetched += bytes.len();
            meshes.extend(missing);
        }
    }
    let share = fetched as f64 / file as f64;
    eprintln!(
        "1,800 frames: {} objects fetched, {fetched} bytes = {:.2}% of the {file}-byte file",
        meshes.len(),
        share * 100.0
    );
    assert!(fetched > 0 && share < 0.10, "{share}");
}
