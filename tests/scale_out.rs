//! What several replicas behind a load balancer rely on
//! (`proto/scale-out.md`): ids that carry their routing key, walkthroughs
//! that users rebuild after their replica is lost, readiness while loading
//! and draining, and the replica's name on every answer. The whole of it,
//! with nginx and killed replicas, is `loadtest/tests/replicas.rs`.

mod common;

use std::time::{Duration, Instant};

use axum::http::StatusCode;
use common::city_scene;
use common::router::{NO_BODY, call, call_raw};
use pvsd::server::{AppState, ConnectionLimits, Limits};
use serde_json::{Value, json};

const KEY: &str = "0123456789abcdef";
const VIEW: &str = r#"{"eye":[0,1.7,0],"forward":[1,0,0.2]}"#;

fn state() -> AppState {
    AppState::new(vec![city_scene(12, 3, [0.0; 3])], Limits::default()).unwrap()
}

fn code(v: &Value) -> &str {
    v["error"]["code"].as_str().unwrap_or("")
}

/// POSTs `body` to `uri` with the routing key header `key` (if any).
async fn post_keyed(
    state: &AppState,
    uri: &str,
    body: Value,
    key: Option<&str>,
) -> (StatusCode, Value) {
    let headers: Vec<(&str, &str)> = key.map(|k| ("x-pvsd-route", k)).into_iter().collect();
    let (status, _, bytes) = call_raw(state, "POST", uri, Some(body), &headers).await;
    (
        status,
        serde_json::from_slice(&bytes).unwrap_or(Value::Null),
    )
}

#[tokio::test]
async fn sessions_and_walkthroughs_are_minted_on_the_routing_key_they_are_given() {
    let s = state();
    let body = json!({"scene": "city", "method": "frustum"});
    let (st, v) = post_keyed(&s, "/sessions", body.clone(), Some(KEY)).await;
    assert_eq!(st, StatusCode::CREATED, "{v}");
    let sid = v["session"].as_str().unwrap();
    assert_eq!(sid.split_once('-').unwrap().0, KEY);
    // Without the header (one replica, no proxy): a random key.
    let (_, a) = post_keyed(&s, "/sessions", body.clone(), None).await;
    let (_, b) = post_keyed(&s, "/sessions", body.clone(), None).await;
    let key_of = |v: &Value, field: &str| v[field].as_str().unwrap()[..16].to_string();
    assert_ne!(key_of(&a, "session"), key_of(&b, "session"));

    // A walkthrough's users get sessions on the walkthrough's key, so their
    // frames meet on its replica; user ids (shown to others) are no ids of
    // sessions.
    let (st, w) = post_keyed(&s, "/walkthroughs", body.clone(), Some(KEY)).await;
    assert_eq!(st, StatusCode::CREATED, "{w}");
    let wid = w["walkthrough"].as_str().unwrap().to_string();
    assert!(wid.starts_with(&format!("{KEY}-")));
    let other = "fedcba9876543210";
    // The header does not move a user off the walkthrough's key; `{}` is
    // a plain join, as no body is; an unknown field is refused.
    let users = format!("/walkthroughs/{wid}/users");
    let (st, bad) = post_keyed(&s, &users, json!({"scen": "city"}), None).await;
    assert_eq!(
        (st, code(&bad)),
        (StatusCode::BAD_REQUEST, "malformed_json"),
        "{bad}"
    );
    let (st, _) = post_keyed(&s, &users, json!({}), Some(other)).await;
    assert_eq!(st, StatusCode::CREATED);
    let (st, _, bytes) = call_raw(&s, "POST", &users, NO_BODY, &[("x-pvsd-route", other)]).await;
    assert_eq!(st, StatusCode::CREATED);
    let joined: Value = serde_json::from_slice(&bytes).unwrap();
    let session = joined["session"].as_str().unwrap();
    assert!(session.starts_with(&format!("{KEY}-")), "{joined}");
    assert_ne!(session, wid);
    assert!(!joined["user"].as_str().unwrap().contains(KEY));
    assert_eq!(joined.get("recreated"), None, "{joined}");

    // A malformed key is refused, naming the header; nothing is made.
    for bad in [
        "0123",
        "0123456789ABCDEF",
        "0123456789abcdeg",
        "0123456789abcdef0",
    ] {
        for uri in ["/sessions", "/walkthroughs"] {
            let (st, v) = post_keyed(&s, uri, body.clone(), Some(bad)).await;
            assert_eq!(
                (st, code(&v)),
                (StatusCode::BAD_REQUEST, "invalid_route"),
                "{bad}"
            );
            assert!(
                v["error"]["message"]
                    .as_str()
                    .unwrap()
                    .contains("x-pvsd-route")
            );
        }
    }
    let (_, m) = call(&s, "GET", "/metrics", NO_BODY).await;
    let m = m.as_str().unwrap();
    assert!(m.contains("pvsd_sessions 5\n"), "{m}");
    assert!(m.contains("pvsd_walkthroughs 1\n"), "{m}");
}

/// A walkthrough lost with its replica: its users rejoin it by id with the
/// scene and method, the first one makes it again under the same id, the
/// others join that one, and they see each other again.
#[tokio::test]
async fn users_rejoining_a_lost_walkthrough_meet_again_under_its_id() {
    let s = state();
    let wid = format!("{KEY}-{}", "5".repeat(32));
    let users = format!("/walkthroughs/{wid}/users");
    let (st, v) = call(&s, "POST", &users, NO_BODY).await;
    assert_eq!(
        (st, code(&v)),
        (StatusCode::NOT_FOUND, "unknown_walkthrough")
    );
    let body = json!({"scene": "city", "method": "frustum"});
    let (st, first) = call(&s, "POST", &users, Some(&body)).await;
    assert_eq!(st, StatusCode::CREATED, "{first}");
    assert_eq!(first["recreated"], true);
    assert!(
        first["session"]
            .as_str()
            .unwrap()
            .starts_with(&format!("{KEY}-"))
    );
    let (st, second) = call(&s, "POST", &users, Some(&body)).await;
    assert_eq!(st, StatusCode::CREATED);
    assert_eq!(
        second.get("recreated"),
        None,
        "joined, not made again: {second}"
    );
    // The body is only what to remake a lost walkthrough from: a live one
    // is joined whatever it says.
    let (st, third) = call(&s, "POST", &users, Some(json!({"scene": "nowhere"}))).await;
    assert_eq!(st, StatusCode::CREATED, "{third}");
    let (_, info) = call(&s, "GET", &format!("/walkthroughs/{wid}"), NO_BODY).await;
    assert_eq!(info["walkthrough"], wid);
    assert_eq!(info["users"].as_array().unwrap().len(), 3, "{info}");
    // They see each other: the second looks at the first from 5 m.
    let view = |x: f64| json!({"eye": [x, 1.7, -30.0], "forward": [1.0, 0.0, 0.0]});
    let frame = |sid: &str| format!("/sessions/{sid}/frames");
    let (st, _) = call(
        &s,
        "POST",
        &frame(first["session"].as_str().unwrap()),
        Some(view(5.0)),
    )
    .await;
    assert_eq!(st, StatusCode::OK);
    let (_, f) = call(
        &s,
        "POST",
        &frame(second["session"].as_str().unwrap()),
        Some(view(0.0)),
    )
    .await;
    assert_eq!(f["users_visible"], json!([first["user"]]), "{f}");

    // An id no replica could have minted is not made; nor is a walkthrough
    // of a scene that is not here, or a bad method.
    for (wid, body, want) in [
        ("not-an-id", body.clone(), "unknown_walkthrough"),
        (
            &format!("{}-{}", KEY, "5".repeat(31))[..],
            body.clone(),
            "unknown_walkthrough",
        ),
        (
            &format!("{KEY}-{}", "6".repeat(32))[..],
            json!({"scene": "nowhere"}),
            "unknown_scene",
        ),
        (
            &format!("{KEY}-{}", "7".repeat(32))[..],
            json!({"scene": "city", "method": "bogus"}),
            "unknown_method",
        ),
    ] {
        let (_, v) = call(
            &s,
            "POST",
            &format!("/walkthroughs/{wid}/users"),
            Some(&body),
        )
        .await;
        assert_eq!(code(&v), want, "{wid}: {v}");
    }
    let (_, m) = call(&s, "GET", "/metrics", NO_BODY).await;
    assert!(m.as_str().unwrap().contains("pvsd_walkthroughs 1\n"));
}

#[tokio::test]
async fn ready_only_when_loaded_and_not_draining_live_throughout() {
    let s = state();
    let get = |path: &'static str| {
        let s = s.clone();
        async move { call(&s, "GET", path, NO_BODY).await }
    };
    assert_eq!(get("/healthz/live").await.0, StatusCode::OK);
    assert_eq!(
        get("/healthz/ready").await,
        (StatusCode::OK, json!("ready"))
    );
    // Not ready, saying why.
    let not_ready = |(st, v): (StatusCode, Value), why: &str| {
        assert_eq!(
            (st, code(&v)),
            (StatusCode::SERVICE_UNAVAILABLE, "not_ready")
        );
        let message = v["error"]["message"].as_str().unwrap();
        assert!(message.contains(why), "{message}");
    };
    // Two scenes to load, then rank: not ready until all of it is done.
    s.readiness().loading(2, true);
    for _ in 0..2 {
        not_ready(get("/healthz/ready").await, "still loading");
        assert_eq!(get("/healthz/live").await.0, StatusCode::OK);
        s.readiness().scene_loaded();
    }
    for _ in 0..2 {
        not_ready(get("/healthz/ready").await, "ranking");
        s.readiness().scene_ranked();
    }
    assert_eq!(get("/healthz/ready").await.0, StatusCode::OK);
    s.readiness().drain();
    not_ready(get("/healthz/ready").await, "draining");
    // Draining still serves.
    assert_eq!(get("/healthz/live").await.0, StatusCode::OK);
    assert_eq!(get("/scenes").await.0, StatusCode::OK);
}

#[tokio::test]
async fn a_configured_scene_not_yet_loaded_is_loading_not_unknown() {
    let s = AppState::new(Vec::new(), Limits::default())
        .unwrap()
        .with_scene_files(vec!["/scenes/city.glb".into()]);
    let (st, _, bytes) = call_raw(&s, "POST", "/scenes/city/visible", Some(VIEW), &[]).await;
    let v: Value = serde_json::from_slice(&bytes).unwrap();
    assert_eq!(
        (st, code(&v)),
        (StatusCode::SERVICE_UNAVAILABLE, "scene_loading"),
        "{v}"
    );
    let (st, headers, _) = call_raw(&s, "GET", "/scenes/city/objects", NO_BODY, &[]).await;
    assert_eq!(st, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(headers["retry-after"], "1");
    let (st, v) = call(&s, "POST", "/scenes/other/visible", Some(VIEW)).await;
    assert_eq!((st, code(&v)), (StatusCode::NOT_FOUND, "unknown_scene"));
    s.add_scene(city_scene(4, 1, [0.0; 3])).unwrap();
    let (st, _) = call(&s, "POST", "/scenes/city/visible", Some(VIEW)).await;
    assert_eq!(st, StatusCode::OK);
    // Once.
    assert!(s.add_scene(city_scene(4, 1, [0.0; 3])).is_err());
}

#[tokio::test]
async fn every_answer_names_the_replica_when_it_has_a_name() {
    let named = state().with_replica(Some("pvsd-2".into()));
    for (method, uri) in [
        ("GET", "/healthz"),
        ("GET", "/nowhere"),
        ("POST", "/sessions"),
    ] {
        let (_, headers, _) = call_raw(&named, method, uri, NO_BODY, &[]).await;
        assert_eq!(headers["x-pvsd-replica"], "pvsd-2", "{method} {uri}");
    }
    let (_, headers, _) = call_raw(&state(), "GET", "/healthz", NO_BODY, &[]).await;
    assert!(headers.get("x-pvsd-replica").is_none());
}

/// Told to stop, a server drains: not ready at once, but it goes on
/// accepting and answering for the drain period, then closes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_told_to_stop_serves_on_while_draining_then_closes() {
    let drain = Duration::from_millis(800);
    let limits = Limits {
        connections: ConnectionLimits {
            drain,
            ..ConnectionLimits::default()
        },
        ..Limits::default()
    };
    let state = AppState::new(vec![city_scene(4, 1, [0.0; 3])], limits).unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(pvsd::server::run(listener, state, async {
        stopped.await.ok();
    }));
    // A fresh connection for each request: new connections are what a
    // draining server must still take.
    let client = || {
        reqwest::Client::builder()
            .pool_max_idle_per_host(0)
            .build()
            .unwrap()
    };
    let url = |p: &str| format!("http://{addr}{p}");
    assert_eq!(
        client()
            .get(url("/healthz/ready"))
            .send()
            .await
            .unwrap()
            .status(),
        200
    );
    let told = Instant::now();
    stop.send(()).unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let r = client().get(url("/healthz/ready")).send().await.unwrap();
    assert_eq!(r.status(), 503);
    let r = client()
        .post(url("/scenes/city/visible"))
        .body(VIEW)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200, "a draining server still answers");
    server.await.unwrap().unwrap();
    assert!(told.elapsed() >= drain, "closed before the drain period");
    assert!(client().get(url("/healthz/live")).send().await.is_err());
}
