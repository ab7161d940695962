//! The HTTP API: routes through `tower::ServiceExt::oneshot`, and a real
//! server on a real socket. Bad input gets a precise 4xx naming the problem
//! and the server answers the next request.

mod common;

use std::sync::Arc;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use common::router::{NO_BODY, call};
use common::{city_scene, fetch, shared_scene};
use http_body_util::BodyExt;
use pvsd::cull::{MethodSpec, View, VisibleSet};
use pvsd::geom::Camera;
use pvsd::server::{AppState, Limits, app};
use pvsd_proto::json::{ObjectInfo, SceneInfo, VisibleResponse};
use serde_json::{Value, json};
use tower::ServiceExt;

fn state() -> AppState {
    AppState::new(vec![city_scene(200, 3, [0.0; 3])], Limits::default()).unwrap()
}

const VIEW: &str = r#"{"eye":[0,1.7,0],"forward":[1,0,0.2],"up":[0,1,0],"fov_y_deg":60,"aspect":1.6,
    "near":0.1,"far":10000,"viewport":[1024,768],"method":"frustum","options":{}}"#;

#[tokio::test]
async fn health_scenes_and_objects() {
    let s = state();
    let (status, body) = call(&s, "GET", "/healthz", NO_BODY).await;
    assert_eq!((status, body), (StatusCode::OK, json!("ok")));
    let (status, body) = call(&s, "GET", "/scenes", NO_BODY).await;
    assert_eq!(status, StatusCode::OK);
    let scenes: Vec<SceneInfo> = serde_json::from_value(body).unwrap();
    assert_eq!(scenes.len(), 1);
    assert_eq!((scenes[0].id.as_str(), scenes[0].objects), ("city", 201));
    assert_eq!(scenes[0].up, [0.0, 1.0, 0.0]);
    // Registry order, which is DESIGN's; gpu where the machine has Vulkan.
    let gpu = pvsd::cull::gpu::Gpu::of_this_machine();
    let mut methods = vec!["frustum", "occlusion_tree", "supporting_planes", "horizon"];
    // ddo: a city is a height field, horizon's.
    let mut unsupported = vec!["ddo"];
    match &gpu {
        Ok(_) => methods.push("gpu"),
        Err(_) => unsupported.push("gpu"),
    }
    methods.push("raster");
    assert_eq!(scenes[0].methods, methods);
    // Every other method of DESIGN's list is there with its reason.
    let listed: Vec<&str> = scenes[0].unsupported.keys().map(String::as_str).collect();
    assert_eq!(listed, unsupported);
    for (method, why) in &scenes[0].unsupported {
        match &gpu {
            Err(reason) if method == "gpu" => assert_eq!(why, reason),
            _ if method == "ddo" => assert!(why.contains("height field"), "{why}"),
            _ => panic!("{method} unsupported: {why}"),
        }
    }
    let (status, body) = call(&s, "GET", "/scenes/city/objects", NO_BODY).await;
    assert_eq!(status, StatusCode::OK);
    let objects: Vec<ObjectInfo> = serde_json::from_value(body).unwrap();
    assert_eq!(objects.len(), 201);
    assert_eq!(objects[42].name, "building_0042");
    assert_eq!(objects[42].id, 42);
}

#[tokio::test]
async fn visible_matches_the_library() {
    let s = state();
    let (status, body) = call(&s, "POST", "/scenes/city/visible", Some(VIEW)).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let got: VisibleResponse = serde_json::from_value(body.clone()).unwrap();
    for k in ["method", "cull_us", "nodes_tested", "in_frustum", "visible"] {
        assert!(body["stats"].get(k).is_some(), "stats.{k}");
    }
    let methods = common::prepare(city_scene(200, 3, [0.0; 3]));
    let cam = Camera {
        eye: glam::DVec3::new(0.0, 1.7, 0.0),
        forward: glam::DVec3::new(1.0, 0.0, 0.2),
        aspect: 1.6,
        viewport: [1024, 768],
        ..Camera::default()
    };
    let mut out = VisibleSet::new();
    methods
        .cull_once(
            &MethodSpec::named("frustum").unwrap(),
            &View::new(cam, methods.scene()).unwrap(),
            &mut out,
        )
        .unwrap();
    assert_eq!(got.visible, out.ids());
    assert!(!got.visible.is_empty());
    assert_eq!(got.stats.method, "frustum");
    assert_eq!(got.stats.visible as usize, got.visible.len());
    // A direction of huge or tiny length is still a direction.
    let (status, body) = call(
        &s,
        "POST",
        "/scenes/city/visible",
        Some(&VIEW.replace("[1,0,0.2]", "[1e200,0,2e199]")),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["visible"], json!(got.visible));
    // `auto` and defaults: only eye and forward are required.
    let (status, body) = call(
        &s,
        "POST",
        "/scenes/city/visible",
        Some(r#"{"eye":[0,1.7,0],"forward":[1,0,0.2]}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["stats"]["method"], "frustum");
    // Answers are written into pre-sized buffers, still as JSON.
    let req = Request::post("/scenes/city/visible")
        .body(Body::from(VIEW))
        .unwrap();
    let res = app(s.clone()).oneshot(req).await.unwrap();
    assert_eq!(res.headers()["content-type"], "application/json");
    let bytes = res.into_body().collect().await.unwrap().to_bytes();
    let again: VisibleResponse = serde_json::from_slice(&bytes).unwrap();
    assert_eq!(again.visible, got.visible);
}

/// Each bad request: its status, its code, a part of its message.
fn bad_requests() -> Vec<(&'static str, String, StatusCode, &'static str, &'static str)> {
    let view = |patch: Value| {
        let mut v: Value = serde_json::from_str(VIEW).unwrap();
        for (k, x) in patch.as_object().unwrap() {
            v[k] = x.clone();
        }
        v.to_string()
    };
    let bad = StatusCode::BAD_REQUEST;
    vec![
        (
            "/scenes/city/visible",
            VIEW.replace("[0,1.7,0]", "[0,NaN,0]"),
            bad,
            "invalid_view",
            "eye[1] is NaN",
        ),
        (
            "/scenes/city/visible",
            VIEW.replace("[1,0,0.2]", "[1,-Infinity,0.2]"),
            bad,
            "invalid_view",
            "forward[1] is infinite",
        ),
        (
            "/scenes/city/visible",
            view(json!({"eye": [0, "NaN", 0]})),
            bad,
            "invalid_view",
            "eye[1] is NaN",
        ),
        (
            "/scenes/city/visible",
            view(json!({"forward": [0, 0, 0]})),
            bad,
            "invalid_view",
            "forward is a zero vector",
        ),
        (
            "/scenes/city/visible",
            view(json!({"up": [0, 0, 0]})),
            bad,
            "invalid_view",
            "up is a zero vector",
        ),
        (
            "/scenes/city/visible",
            view(json!({"up": [2, 0, 0.4]})),
            bad,
            "invalid_view",
            "up is parallel to forward",
        ),
        (
            "/scenes/city/visible",
            view(json!({"fov_y_deg": 0})),
            bad,
            "invalid_view",
            "fov_y_deg",
        ),
        (
            "/scenes/city/visible",
            view(json!({"near": -1})),
            bad,
            "invalid_view",
            "near",
        ),
        (
            "/scenes/city/visible",
            view(json!({"far": 0.01})),
            bad,
            "invalid_view",
            "far",
        ),
        (
            "/scenes/city/visible",
            view(json!({"aspect": 0})),
            bad,
            "invalid_view",
            "aspect",
        ),
        (
            "/scenes/city/visible",
            view(json!({"viewport": [0, 10]})),
            bad,
            "invalid_view",
            "viewport[0]",
        ),
        (
            "/scenes/city/visible",
            view(json!({"aspect": 1e155})),
            bad,
            "invalid_view",
            "aspect makes the horizontal field of view too close to 180",
        ),
        (
            "/scenes/city/visible",
            view(json!({"eye": [1, 2]})),
            bad,
            "malformed_json",
            "eye",
        ),
        (
            "/scenes/city/visible",
            view(json!({"eye": "here"})),
            bad,
            "malformed_json",
            "eye",
        ),
        (
            "/scenes/city/visible",
            r#"{"forward":[1,0,0]}"#.into(),
            bad,
            "malformed_json",
            "missing field `eye`",
        ),
        (
            "/scenes/city/visible",
            VIEW.replace("\"forward\"", "\"foward\""),
            bad,
            "malformed_json",
            "foward",
        ),
        (
            "/scenes/city/visible",
            "{\"eye\":[0,1,".into(),
            bad,
            "malformed_json",
            "not valid JSON",
        ),
        (
            "/scenes/city/visible",
            "".into(),
            bad,
            "malformed_json",
            "not valid JSON",
        ),
        (
            "/scenes/city/visible",
            view(json!({"method": "octree"})),
            bad,
            "unknown_method",
            "unknown method 'octree'",
        ),
        (
            "/scenes/city/visible",
            view(json!({"method": "ddo"})),
            bad,
            "unsupported_method",
            "it supports: frustum",
        ),
        (
            "/scenes/city/visible",
            view(json!({"options": {"k": 32}})),
            bad,
            "unknown_option",
            "unknown option 'k'",
        ),
        (
            "/scenes/city/visible",
            view(json!({"options": {"k": [1]}})),
            bad,
            "malformed_json",
            "options.k",
        ),
        (
            "/scenes/nowhere/visible",
            VIEW.into(),
            StatusCode::NOT_FOUND,
            "unknown_scene",
            "no scene 'nowhere'; loaded scenes: city",
        ),
        (
            "/scenes/city/visible",
            format!("{{\"pad\":\"{}\"}}", "x".repeat(100_000)),
            StatusCode::PAYLOAD_TOO_LARGE,
            "body_too_large",
            "65536",
        ),
    ]
}

#[tokio::test]
async fn bad_input_is_a_precise_error_and_the_next_request_works() {
    let s = state();
    let (_, good) = call(&s, "POST", "/scenes/city/visible", Some(VIEW)).await;
    for (uri, body, status, code, message) in bad_requests() {
        let (got, err) = call(&s, "POST", uri, Some(&body)).await;
        assert_eq!(got, status, "{code}: {err}");
        assert_eq!(err["error"]["code"], code, "{err}");
        let m = err["error"]["message"].as_str().unwrap();
        assert!(m.contains(message), "'{m}' should contain '{message}'");
        let (ok, again) = call(&s, "POST", "/scenes/city/visible", Some(VIEW)).await;
        assert_eq!(ok, StatusCode::OK);
        assert_eq!(
            again["visible"], good["visible"],
            "state unchanged after {code}"
        );
    }
}

#[tokio::test]
async fn occlusion_methods_answer_over_http_with_a_subset_of_frustum() {
    let s = state();
    let (_, frustum) = call(&s, "POST", "/scenes/city/visible", Some(VIEW)).await;
    for method in ["occlusion_tree", "supporting_planes"] {
        let body = VIEW.replace(
            "\"method\":\"frustum\",\"options\":{}",
            &format!("\"method\":\"{method}\",\"options\":{{\"k\":16}}"),
        );
        let (status, v) = call(&s, "POST", "/scenes/city/visible", Some(&body)).await;
        assert_eq!(status, StatusCode::OK, "{v}");
        assert_eq!(v["stats"]["method"], method);
        assert_eq!(
            v["stats"]["in_frustum"],
            Value::Null,
            "occlusion methods do not count it"
        );
        let ids: Vec<u64> = v["visible"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap())
            .collect();
        let all: Vec<u64> = frustum["visible"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap())
            .collect();
        assert!(
            !ids.is_empty() && ids.iter().all(|i| all.contains(i)),
            "{method}: {ids:?} within {all:?}"
        );
        assert!(
            ids.len() < all.len(),
            "{method} culls something at street level"
        );
    }
}

#[tokio::test]
async fn horizon_answers_with_areas_when_asked_and_scenes_say_why_not() {
    let s = state();
    let body = VIEW.replace(
        "\"method\":\"frustum\",\"options\":{}",
        "\"method\":\"horizon\",\"options\":{\"areas\":true}",
    );
    let (status, v) = call(&s, "POST", "/scenes/city/visible", Some(&body)).await;
    assert_eq!(status, StatusCode::OK, "{v}");
    let answer: VisibleResponse = serde_json::from_value(v).unwrap();
    let areas = answer.areas.expect("areas asked for");
    assert_eq!(areas.len(), answer.visible.len());
    assert!(areas.iter().all(|&a| (0.0..=1024.0 * 768.0).contains(&a)));
    // Without the option the field is absent.
    let plain = VIEW.replace("\"method\":\"frustum\"", "\"method\":\"horizon\"");
    let (_, v) = call(&s, "POST", "/scenes/city/visible", Some(&plain)).await;
    assert!(v.get("areas").is_none(), "{v}");

    // A scene with no height field lists no horizon, and says why.
    let mut b = pvsd::scene::SceneBuilder::new("floating");
    b.begin_object("a", None);
    b.add_triangles(
        [
            [glam::DVec3::ZERO, glam::DVec3::X, glam::DVec3::Z],
            [glam::DVec3::Y, glam::DVec3::ONE, glam::DVec3::Z],
        ],
        false,
    );
    let s = AppState::new(vec![Arc::new(b.finish())], Limits::default()).unwrap();
    let (_, v) = call(&s, "GET", "/scenes", NO_BODY).await;
    let scenes: Vec<SceneInfo> = serde_json::from_value(v).unwrap();
    assert!(!scenes[0].methods.contains(&"horizon".to_string()));
    assert!(scenes[0].unsupported["horizon"].contains("height field"));
    let body = VIEW.replace("\"method\":\"frustum\"", "\"method\":\"horizon\"");
    let (status, v) = call(&s, "POST", "/scenes/floating/visible", Some(&body)).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{v}");
    assert_eq!(v["error"]["code"], "unsupported_method");
}

#[tokio::test]
async fn an_unknown_scene_is_404_whatever_the_body() {
    let s = state();
    let (status, body) = call(&s, "POST", "/scenes/nope/visible", Some("{")).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert_eq!(body["error"]["code"], "unknown_scene");
}

#[tokio::test]
async fn a_scene_without_triangles_has_null_bounds() {
    let empty = Arc::new(pvsd::scene::SceneBuilder::new("void").finish());
    let s = AppState::new(vec![empty], Limits::default()).unwrap();
    let (status, body) = call(&s, "GET", "/scenes", NO_BODY).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body[0]["bounds"], Value::Null, "{body}");
    let (status, body) = call(&s, "POST", "/scenes/void/visible", Some(VIEW)).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body["visible"], json!([]));
}

#[tokio::test]
async fn unknown_routes_and_methods_are_json_errors() {
    let s = state();
    let (status, body) = call(&s, "GET", "/nope", NO_BODY).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert_eq!(body["error"]["code"], "not_found");
    let (status, body) = call(&s, "GET", "/scenes/city/visible", NO_BODY).await;
    assert_eq!(status, StatusCode::METHOD_NOT_ALLOWED);
    assert_eq!(body["error"]["code"], "method_not_allowed");
    let (status, body) = call(&s, "GET", "/scenes/ghost/objects", NO_BODY).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert_eq!(body["error"]["code"], "unknown_scene");
    // Made-up HTTP methods are answered, and do not each get a metric series.
    for m in ["BREW", "WHEN", "XYZZY"] {
        let (status, _) = call(&s, m, "/scenes", NO_BODY).await;
        assert_eq!(status, StatusCode::METHOD_NOT_ALLOWED);
    }
    let (_, metrics) = call(&s, "GET", "/metrics", NO_BODY).await;
    let text = metrics.as_str().unwrap();
    assert!(
        text.contains(r#"route="/scenes",method="other",status="405"} 3"#),
        "{text}"
    );
    assert!(!text.contains("BREW"));
}

#[tokio::test]
async fn metrics_count_requests_by_route_and_culls_by_method() {
    let s = state();
    call(&s, "POST", "/scenes/city/visible", Some(VIEW)).await;
    call(&s, "POST", "/scenes/city/visible", Some("{")).await;
    let (status, body) = call(&s, "GET", "/metrics", NO_BODY).await;
    assert_eq!(status, StatusCode::OK);
    let text = body.as_str().unwrap();
    assert!(
        text.contains(
            r#"pvsd_http_requests_total{route="/scenes/{id}/visible",method="POST",status="200"} 1"#
        ),
        "{text}"
    );
    assert!(text.contains(
        r#"pvsd_http_requests_total{route="/scenes/{id}/visible",method="POST",status="400"} 1"#
    ));
    assert!(text.contains(r#"pvsd_cull_duration_seconds_count{scene="city",method="frustum"} 1"#));
    assert!(text.contains("pvsd_http_request_duration_seconds_bucket"));
    assert!(text.contains("pvsd_scenes 1"));
}

/// A request body that never finishes arriving (a stalled or slow-loris client).
struct Stalled;

impl http_body::Body for Stalled {
    type Data = axum::body::Bytes;
    type Error = std::convert::Infallible;
    fn poll_frame(
        self: std::pin::Pin<&mut Self>,
        _: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        std::task::Poll::Pending
    }
}

#[tokio::test]
async fn a_request_over_the_timeout_is_a_503_and_the_next_one_works() {
    let limits = Limits {
        request_timeout: std::time::Duration::from_millis(100),
        ..Limits::default()
    };
    let s = AppState::new(vec![city_scene(50, 3, [0.0; 3])], limits).unwrap();
    let req = Request::post("/scenes/city/visible")
        .body(Body::new(Stalled))
        .unwrap();
    let res = app(s.clone()).oneshot(req).await.unwrap();
    assert_eq!(res.status(), StatusCode::SERVICE_UNAVAILABLE);
    let body: Value =
        serde_json::from_slice(&res.into_body().collect().await.unwrap().to_bytes()).unwrap();
    assert_eq!(body["error"]["code"], "timeout");
    assert_eq!(
        body["error"]["message"],
        "the request took longer than 100 ms"
    );
    let (status, _) = call(&s, "POST", "/scenes/city/visible", Some(VIEW)).await;
    assert_eq!(status, StatusCode::OK);
}

#[test]
fn duplicate_scene_ids_are_refused() {
    let s = city_scene(10, 1, [0.0; 3]);
    let e = AppState::new(vec![s.clone(), s], Limits::default())
        .err()
        .unwrap();
    assert!(e.to_string().contains("two scenes are called 'city'"));
}

#[tokio::test]
async fn real_socket_serves_survives_bad_input_and_shuts_down() {
    let state = AppState::new(
        vec![city_scene(200, 3, [0.0; 3]), shared_scene("Sponza")],
        Limits::default(),
    )
    .unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(pvsd::server::run(listener, state, async {
        stopped.await.ok();
    }));
    let client = reqwest::Client::new();
    let url = |p: &str| format!("http://{addr}{p}");
    let scenes: Vec<SceneInfo> = fetch(client.get(url("/scenes"))).await;
    assert_eq!(
        scenes.iter().map(|s| s.id.as_str()).collect::<Vec<_>>(),
        ["Sponza", "city"]
    );
    // Inside Sponza's atrium, looking along it.
    let view = json!({"eye": [0.0, 6.0, 0.0], "forward": [1.0, 0.0, 0.0]});
    let first: VisibleResponse =
        fetch(client.post(url("/scenes/Sponza/visible")).json(&view)).await;
    assert!(first.visible.len() > 10, "{first:?}");
    let bad = client
        .post(url("/scenes/Sponza/visible"))
        .body("{\"eye\":[0,NaN,0],\"forward\":[1,0,0]}")
        .send()
        .await
        .unwrap();
    assert_eq!(bad.status(), 400);
    let huge = client
        .post(url("/scenes/Sponza/visible"))
        .body(vec![b' '; 1 << 20])
        .send()
        .await;
    if let Ok(r) = huge {
        assert_eq!(r.status(), 413);
    }
    let again: VisibleResponse =
        fetch(client.post(url("/scenes/Sponza/visible")).json(&view)).await;
    assert_eq!(again.visible, first.visible);
    // Many clients at once.
    let mut tasks = Vec::new();
    for i in 0..32 {
        let (client, u) = (client.clone(), url("/scenes/city/visible"));
        tasks.push(tokio::spawn(async move {
            let v = json!({"eye": [i as f64, 1.7, 0.0], "forward": [1.0, 0.0, 0.1]});
            client.post(u).json(&v).send().await.unwrap().status()
        }));
    }
    for t in tasks {
        assert_eq!(t.await.unwrap(), 200);
    }
    stop.send(()).unwrap();
    server.await.unwrap().unwrap();
    assert!(
        client.get(url("/healthz")).send().await.is_err(),
        "stopped after shutdown"
    );
}
