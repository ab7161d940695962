//! Sessions over a real socket: deltas rebuild the answers, JSON and
//! `application/x-pvs` carry the same sets, dead sessions say why, frames
//! stay ordered, abandoned sessions stay within the caps, a WebSocket
//! client that stops reading stalls its own connection and nothing else.

mod common;

use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use common::router::{NO_BODY, call};
use common::server::{Held, Server, new_session, view_json, xpvs};
use common::{city_scene, fetch};
use futures_util::{SinkExt, StreamExt};
use http_body_util::BodyExt;
use pvsd::cull::{CullJob, MethodSpec, View};
use pvsd::eval::{WalkKind, WalkParams, walk};
use pvsd::geom::Camera;
use pvsd::scene::Scene;
use pvsd::server::{AppState, Limits, SessionLimits, app};
use pvsd_proto::json::{FrameResponse, VisibleResponse};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;
use tower::ServiceExt;

const ACCEPT_PVS: (&str, &str) = ("accept", "application/x-pvs");

fn street(scene: &Scene, frames: usize) -> Vec<Camera> {
    walk(
        scene,
        &WalkParams {
            kind: WalkKind::Street,
            frames,
            seed: 3,
            ..WalkParams::default()
        },
    )
    .unwrap()
}

async fn stateless(client: &reqwest::Client, s: &Server, cam: &Camera, method: &str) -> Vec<u32> {
    let mut body = view_json(cam);
    body["method"] = json!(method);
    let r: VisibleResponse = fetch(client.post(s.url("/scenes/city/visible")).json(&body)).await;
    r.visible
}

/// Sum of body bytes of delta frames (all but the first) and of full
/// frames of the same views (a second session that always names a base it
/// never got).
#[derive(Default)]
struct Bytes {
    delta: usize,
    full: usize,
}

impl Bytes {
    fn check(&self, what: &str) {
        let ratio = self.delta as f64 / self.full as f64;
        eprintln!(
            "{what}: deltas {} B, full {} B, ratio {ratio:.3}",
            self.delta, self.full
        );
        assert!(ratio < 0.3, "{what}: deltas are {ratio:.3} of full frames");
    }
}

/// DESIGN/issue "done when": 60 frames through a 1k city by deltas hold
/// exactly the stateless answers, with deltas under 30% of the bytes of
/// full frames, over HTTP (JSON and x-pvs) and WebSocket (JSON and x-pvs).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_walk_by_deltas_holds_the_stateless_answers_over_http_and_websocket() {
    let scene = city_scene(1000, 1, [0.0; 3]);
    let cams = street(&scene, 60);
    let s = Server::with(vec![scene], Limits::default()).await;
    let c = reqwest::Client::new();
    let mut truth = Vec::new();
    for cam in &cams {
        truth.push(stateless(&c, &s, cam, "auto").await);
    }
    assert!(
        truth.iter().map(Vec::len).sum::<usize>() > 60 * 20,
        "the walk sees little"
    );

    for binary in [false, true] {
        let sid = new_session(&c, &s, json!({"scene": "city"})).await;
        let full_sid = new_session(&c, &s, json!({"scene": "city"})).await;
        let (mut held, mut bytes) = (Held::default(), Bytes::default());
        for (i, cam) in cams.iter().enumerate() {
            let post = |sid: &str, body: Value| {
                let r = c
                    .post(s.url(&format!("/sessions/{sid}/frames")))
                    .json(&body);
                if binary {
                    r.header(ACCEPT_PVS.0, ACCEPT_PVS.1)
                } else {
                    r
                }
            };
            let res = post(&sid, view_json(cam)).send().await.unwrap();
            assert_eq!(res.status(), 200);
            let body = res.bytes().await.unwrap();
            let f: FrameResponse = if binary {
                xpvs::frame(&body)
            } else {
                serde_json::from_slice(&body).unwrap()
            };
            assert_eq!(f.frame, i as u64 + 1);
            assert_eq!(f.base, (i > 0).then_some(i as u64));
            held.apply(&f);
            assert_eq!(held.sorted(), truth[i], "frame {}", i + 1);
            let mut full_view = view_json(cam);
            full_view["base"] = json!(u64::MAX);
            let full = post(&full_sid, full_view)
                .send()
                .await
                .unwrap()
                .bytes()
                .await
                .unwrap();
            if i > 0 {
                bytes.delta += body.len();
                bytes.full += full.len();
            }
        }
        bytes.check(if binary { "HTTP x-pvs" } else { "HTTP JSON" });
    }

    for binary in [false, true] {
        let sid = new_session(&c, &s, json!({"scene": "city"})).await;
        let full_sid = new_session(&c, &s, json!({"scene": "city"})).await;
        let q = if binary { "?encoding=x-pvs" } else { "" };
        let (mut ws, _) =
            tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws{q}")))
                .await
                .unwrap();
        let (mut full_ws, _) =
            tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{full_sid}/ws{q}")))
                .await
                .unwrap();
        let (mut held, mut bytes) = (Held::default(), Bytes::default());
        let decode = |m: Message| -> (FrameResponse, usize) {
            match m {
                Message::Binary(b) if binary => (xpvs::frame(&b), b.len()),
                Message::Text(t) if !binary => (serde_json::from_str(&t).unwrap(), t.len()),
                other => panic!("unexpected message {other:?}"),
            }
        };
        for (i, cam) in cams.iter().enumerate() {
            ws.send(Message::text(view_json(cam).to_string()))
                .await
                .unwrap();
            let (f, n) = decode(ws.next().await.unwrap().unwrap());
            held.apply(&f);
            assert_eq!(held.sorted(), truth[i], "ws frame {}", i + 1);
            let mut full_view = view_json(cam);
            full_view["base"] = json!(u64::MAX);
            full_ws
                .send(Message::text(full_view.to_string()))
                .await
                .unwrap();
            let (full, m) = decode(full_ws.next().await.unwrap().unwrap());
            assert_eq!(full.base, None);
            if i > 0 {
                bytes.delta += n;
                bytes.full += m;
            }
        }
        bytes.check(if binary {
            "WebSocket x-pvs"
        } else {
            "WebSocket JSON"
        });
        ws.close(None).await.unwrap();
        // Closing the socket does not end the session.
        let res = c
            .post(s.url(&format!("/sessions/{sid}/frames")))
            .json(&view_json(&cams[0]))
            .send()
            .await
            .unwrap();
        assert_eq!(res.status(), 200);
    }
}

/// Every method of the scene: a session's deltas rebuild exactly what one
/// library client with one cache answers over the same views (methods with
/// temporal state answer from it), and history-free methods equal the
/// stateless answers.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_method_rebuilds_its_own_answers_by_deltas() {
    let scene = city_scene(300, 5, [0.0; 3]);
    let cams = street(&scene, 30);
    let library = common::prepare(scene.clone());
    let names = library.names();
    assert!(names.len() >= 4, "{names:?}");
    let s = Server::with(vec![scene.clone()], Limits::default()).await;
    let c = reqwest::Client::new();
    for name in names {
        let spec: MethodSpec = name.parse().unwrap();
        let (method, cache) = library.prepare_client(&spec).unwrap();
        let sid = new_session(&c, &s, json!({"scene": "city", "method": name})).await;
        let mut held = Held::default();
        let mut job = Some(CullJob::new(View::new(cams[0], &scene).unwrap(), cache));
        for (i, cam) in cams.iter().enumerate() {
            let f: FrameResponse = fetch(
                c.post(s.url(&format!("/sessions/{sid}/frames")))
                    .json(&view_json(cam)),
            )
            .await;
            held.apply(&f);
            let mut next = job.take().unwrap();
            next.view = View::new(*cam, &scene).unwrap();
            let culled = library.cull(&method, next).await.unwrap();
            assert_eq!(
                held.sorted(),
                culled.job.out.ids(),
                "{name} frame {}",
                i + 1
            );
            job = Some(culled.job);
            if matches!(name, "frustum" | "horizon") {
                assert_eq!(held.sorted(), stateless(&c, &s, cam, name).await, "{name}");
            }
        }
    }
}

/// A base the session still keeps gets a delta against it; one it does
/// not keep gets the whole set; a stateless request refuses a base and a
/// frame refuses a method. Bad input does not advance or corrupt a session.
#[tokio::test]
async fn bases_bad_frames_and_binary_stateless_answers() {
    let scene = city_scene(200, 3, [0.0; 3]);
    let cams = street(&scene, 8);
    let s = Server::with(vec![scene], Limits::default()).await;
    let c = reqwest::Client::new();
    let sid = new_session(&c, &s, json!({"scene": "city", "method": "frustum"})).await;
    let frames = s.url(&format!("/sessions/{sid}/frames"));
    let mut sets = Vec::new();
    for cam in &cams[..6] {
        let f: FrameResponse = fetch(c.post(&frames).json(&view_json(cam))).await;
        sets.push(f);
    }
    let mut held = Held::default();
    sets.iter().for_each(|f| held.apply(f));
    // The client lost frame 6 and holds frame 3: a delta against 3.
    let mut held3 = Held::default();
    sets[..3].iter().for_each(|f| held3.apply(f));
    let mut v = view_json(&cams[6]);
    v["base"] = json!(3);
    let f: FrameResponse = fetch(c.post(&frames).json(&v)).await;
    assert_eq!((f.frame, f.base), (7, Some(3)));
    held3.apply(&f);
    assert_eq!(held3.sorted(), stateless(&c, &s, &cams[6], "frustum").await);
    // Frame 1 is no longer kept (4 are): the whole set.
    v["base"] = json!(1);
    let f: FrameResponse = fetch(c.post(&frames).json(&v)).await;
    assert_eq!((f.frame, f.base), (8, None));
    // Bad frames: named errors, no frame number used.
    for (body, code, needle) in [
        (
            json!({"eye": [0, "NaN", 0], "forward": [1, 0, 0]}),
            "invalid_view",
            "eye[1]",
        ),
        (
            json!({"eye": [0, 1, 0], "forward": [1, 0, 0], "method": "horizon"}),
            "malformed_json",
            "method",
        ),
        (
            json!({"eye": [0, 1, 0], "forward": [1, 0, 0], "bogus": 1}),
            "malformed_json",
            "bogus",
        ),
    ] {
        let res = c.post(&frames).json(&body).send().await.unwrap();
        assert_eq!(res.status(), 400);
        let e: Value = res.json().await.unwrap();
        assert_eq!(e["error"]["code"], code, "{e}");
        assert!(
            e["error"]["message"].as_str().unwrap().contains(needle),
            "{e}"
        );
    }
    let f: FrameResponse = fetch(c.post(&frames).json(&view_json(&cams[7]))).await;
    assert_eq!((f.frame, f.base), (9, Some(8)));
    // Stateless: a base is refused; x-pvs carries the JSON answer's ids.
    let mut sv = view_json(&cams[2]);
    sv["base"] = json!(1);
    let res = c
        .post(s.url("/scenes/city/visible"))
        .json(&sv)
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 400);
    let res = c
        .post(s.url("/scenes/city/visible"))
        .header(ACCEPT_PVS.0, ACCEPT_PVS.1)
        .json(&view_json(&cams[2]))
        .send()
        .await
        .unwrap();
    assert_eq!(res.headers()["content-type"], "application/x-pvs");
    let ids = xpvs::visible(&res.bytes().await.unwrap());
    assert_eq!(ids, stateless(&c, &s, &cams[2], "auto").await);
    assert!(!ids.is_empty());
    // Errors stay JSON whatever was accepted.
    let res = c
        .post(s.url("/scenes/nowhere/visible"))
        .header(ACCEPT_PVS.0, ACCEPT_PVS.1)
        .json(&view_json(&cams[2]))
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 404);
    assert!(res.json::<Value>().await.unwrap()["error"]["code"] == "unknown_scene");
}

fn limits(idle: Duration, max_sessions: u64, cache_bytes: u64) -> Limits {
    Limits {
        sessions: SessionLimits {
            idle,
            max_sessions,
            cache_bytes,
            ..SessionLimits::default()
        },
        ..Limits::default()
    }
}

const VIEW: &str = r#"{"eye":[0,1.7,0],"forward":[1,0,0.2]}"#;

#[tokio::test]
async fn unknown_and_deleted_sessions_are_404_expired_and_evicted_410() {
    let state = AppState::new(
        vec![city_scene(50, 2, [0.0; 3])],
        limits(Duration::from_millis(400), 2, 1 << 20),
    )
    .unwrap();
    let view: Value = serde_json::from_str(VIEW).unwrap();
    let make = || call(&state, "POST", "/sessions", Some(json!({"scene": "city"})));
    let frame = |sid: String| {
        let (state, view) = (state.clone(), view.clone());
        async move {
            let uri = format!("/sessions/{sid}/frames");
            call(&state, "POST", &uri, Some(view)).await
        }
    };
    let code = |v: &Value| v["error"]["code"].as_str().unwrap_or("").to_string();

    let (st, v) = frame("0123456789abcdef0123456789abcdef".into()).await;
    assert_eq!(
        (st, code(&v)),
        (StatusCode::NOT_FOUND, "unknown_session".into())
    );
    let (st, v) = call(&state, "POST", "/sessions", Some(json!({"scene": "nope"}))).await;
    assert_eq!(
        (st, code(&v)),
        (StatusCode::NOT_FOUND, "unknown_scene".into())
    );
    let (st, v) = call(
        &state,
        "POST",
        "/sessions",
        Some(json!({"scene": "city", "method": "ddo"})),
    )
    .await;
    assert_eq!(
        (st, code(&v)),
        (StatusCode::BAD_REQUEST, "unsupported_method".into())
    );

    let (st, v) = make().await;
    assert_eq!(st, StatusCode::CREATED);
    let sid = v["session"].as_str().unwrap().to_string();
    let (key, secret) = sid.split_once('-').unwrap();
    assert_eq!((key.len(), secret.len()), (16, 32));
    assert!(
        format!("{key}{secret}")
            .chars()
            .all(|c| c.is_ascii_hexdigit())
    );
    assert_eq!(frame(sid.clone()).await.0, StatusCode::OK);
    let (st, _) = call(&state, "DELETE", &format!("/sessions/{sid}"), NO_BODY).await;
    assert_eq!(st, StatusCode::NO_CONTENT);
    let (st, v) = frame(sid.clone()).await;
    assert_eq!(
        (st, code(&v)),
        (StatusCode::NOT_FOUND, "unknown_session".into())
    );
    let (st, _) = call(&state, "DELETE", &format!("/sessions/{sid}"), NO_BODY).await;
    assert_eq!(st, StatusCode::NOT_FOUND);

    // Idle past the limit: 410, and the message says why.
    let sid = make().await.1["session"].as_str().unwrap().to_string();
    tokio::time::sleep(Duration::from_millis(700)).await;
    let (st, v) = frame(sid.clone()).await;
    assert_eq!(
        (st, code(&v)),
        (StatusCode::GONE, "session_expired".into()),
        "{v}"
    );
    assert!(v["error"]["message"].as_str().unwrap().contains("expired"));

    // Past the cap of 2: the least recently used goes.
    let a = make().await.1["session"].as_str().unwrap().to_string();
    let b = make().await.1["session"].as_str().unwrap().to_string();
    assert_eq!(frame(a.clone()).await.0, StatusCode::OK);
    let c = make().await.1["session"].as_str().unwrap().to_string();
    state.sessions().usage();
    assert_eq!(frame(a).await.0, StatusCode::OK);
    assert_eq!(frame(c).await.0, StatusCode::OK);
    let (st, v) = frame(b).await;
    assert_eq!(
        (st, code(&v)),
        (StatusCode::GONE, "session_evicted".into()),
        "{v}"
    );
    let (_, metrics) = {
        let req = Request::builder()
            .uri("/metrics")
            .body(Body::empty())
            .unwrap();
        let res = app(state.clone()).oneshot(req).await.unwrap();
        let text = String::from_utf8(res.into_body().collect().await.unwrap().to_bytes().to_vec())
            .unwrap();
        ((), text)
    };
    for line in [
        "pvsd_sessions 2",
        "pvsd_session_evictions_total{cause=\"expired\"} 1",
        "pvsd_session_evictions_total{cause=\"evicted\"} 1",
    ] {
        assert!(metrics.contains(line), "no '{line}' in\n{metrics}");
    }
}

/// 100k sessions made and never used again: the store stays within its
/// caps on count and bytes, and its byte count is exact (all freed at the end).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn abandoned_sessions_stay_within_the_caps() {
    let cap_bytes = 8 << 20;
    let state = AppState::new(
        vec![city_scene(50, 2, [0.0; 3])],
        limits(Duration::from_secs(600), 5_000, cap_bytes),
    )
    .unwrap();
    let view: Value = serde_json::from_str(VIEW).unwrap();
    let mut peak = (0, 0);
    for i in 0..100_000u32 {
        let method = if i % 2 == 0 { "frustum" } else { "horizon" };
        let (st, v) = call(
            &state,
            "POST",
            "/sessions",
            Some(json!({"scene": "city", "method": method})),
        )
        .await;
        assert_eq!(st, StatusCode::CREATED);
        if i % 10 == 0 {
            // Some use a frame or two, so they hold frames and caches.
            let sid = v["session"].as_str().unwrap();
            let (st, _) = call(
                &state,
                "POST",
                &format!("/sessions/{sid}/frames"),
                Some(view.clone()),
            )
            .await;
            assert_eq!(st, StatusCode::OK);
        }
        if i % 5_000 == 4_999 {
            let (live, bytes) = state.sessions().usage();
            assert!(live <= 5_000, "{live} sessions live");
            assert!(bytes <= cap_bytes, "{bytes} bytes live");
            peak = (peak.0.max(live), peak.1.max(bytes));
        }
    }
    eprintln!("peak: {} sessions, {} bytes", peak.0, peak.1);
    assert!(peak.0 > 100, "the cap let almost nothing live: {peak:?}");
}

/// A burst of frames on one session, all at once on many connections: each
/// gets its own frame number, deltas chain in that order, and each rebuilt
/// set is the stateless answer for that request's own view.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_on_one_session_stays_ordered() {
    let scene = city_scene(200, 4, [0.0; 3]);
    let cams = street(&scene, 40);
    let s = Server::with(vec![scene], Limits::default()).await;
    let c = reqwest::Client::new();
    let sid = new_session(&c, &s, json!({"scene": "city", "method": "horizon"})).await;
    let url = s.url(&format!("/sessions/{sid}/frames"));
    let tasks: Vec<_> = cams
        .iter()
        .map(|cam| {
            let (c, url, body) = (c.clone(), url.clone(), view_json(cam));
            tokio::spawn(async move { fetch::<FrameResponse>(c.post(url).json(&body)).await })
        })
        .collect();
    let mut answers = Vec::new();
    for (i, t) in tasks.into_iter().enumerate() {
        answers.push((t.await.unwrap(), i));
    }
    answers.sort_by_key(|(f, _)| f.frame);
    let mut held = Held::default();
    for (n, (f, i)) in answers.iter().enumerate() {
        assert_eq!(
            f.frame,
            n as u64 + 1,
            "frame numbers are 1..=40 with no gap"
        );
        held.apply(f);
        assert_eq!(held.sorted(), stateless(&c, &s, &cams[*i], "horizon").await);
    }
}

/// A WebSocket client that sends and never reads: the server answers until
/// the socket's buffers are full, then waits; it reads no more, so the
/// client's sends stall, and what it culled stops growing. Other clients
/// are served meanwhile, and the stalled session resumes when read.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_websocket_client_that_stops_reading_stalls_only_itself() {
    let scene = city_scene(200, 4, [0.0; 3]);
    let s = Server::with(vec![scene.clone()], Limits::default()).await;
    let c = reqwest::Client::new();
    let sid = new_session(&c, &s, json!({"scene": "city", "method": "frustum"})).await;
    let (ws, _) = tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws")))
        .await
        .unwrap();
    let (mut tx, mut rx) = ws.split();
    // From above, everything in view, never a kept base: big answers.
    let b = scene.to_world(&scene.bounds());
    let centre = (b.0 + b.1) * 0.5;
    let view = json!({"eye": [centre.x, b.1.y + 200.0, centre.z], "forward": [0.01, -1.0, 0.0],
                      "fov_y_deg": 120, "base": 999_999_999u64})
    .to_string();
    let culls = || async {
        s.metric(
            &c,
            "pvsd_cull_duration_seconds_count{scene=\"city\",method=\"frustum\"}",
        )
        .await as u64
    };
    let mut sent = 0u64;
    // Until a send has waited 1.5 s (a send that times out stays queued).
    while let Ok(r) = tokio::time::timeout(
        Duration::from_millis(1500),
        tx.send(Message::text(view.clone())),
    )
    .await
    {
        r.unwrap();
        sent += 1;
        assert!(sent < 200_000, "the server never stopped reading");
    }
    let first = culls().await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let second = culls().await;
    eprintln!("sent {sent} views before the send stalled; the server culled {first}");
    assert_eq!(
        first, second,
        "the server kept working for a client that does not read"
    );
    assert!(first < sent, "every view answered though none was read");
    // Others are served meanwhile.
    let r = c
        .post(s.url("/scenes/city/visible"))
        .body(VIEW)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    // Reading resumes the session: every view gets its answer, in order.
    let reader = tokio::spawn(async move {
        let mut last = 0;
        for _ in 0..sent {
            let m = rx.next().await.unwrap().unwrap();
            let f: FrameResponse = serde_json::from_str(m.to_text().unwrap()).unwrap();
            assert_eq!(f.frame, last + 1);
            last = f.frame;
        }
        last
    });
    tokio::time::timeout(Duration::from_secs(60), async {
        // The stalled send completes once the server reads again.
        tx.send(Message::text(view.clone())).await.unwrap();
    })
    .await
    .unwrap();
    assert_eq!(reader.await.unwrap(), sent);
}

#[tokio::test]
async fn websocket_errors_keep_the_socket_and_dead_sessions_are_refused() {
    let s = Server::with(vec![city_scene(50, 2, [0.0; 3])], Limits::default()).await;
    let c = reqwest::Client::new();
    // Not an upgrade, a dead session, a bad query: plain HTTP errors.
    let r = c.get(s.url("/sessions/ffff/ws")).send().await.unwrap();
    assert_eq!(r.status(), 404);
    let sid = new_session(&c, &s, json!({"scene": "city"})).await;
    let r = c
        .get(s.url(&format!("/sessions/{sid}/ws")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 426);
    assert!(
        tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws?encoding=xml")))
            .await
            .is_err()
    );
    let (mut ws, _) = tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws")))
        .await
        .unwrap();
    ws.send(Message::text(r#"{"eye":[0,NaN,0],"forward":[1,0,0]}"#))
        .await
        .unwrap();
    let e: Value =
        serde_json::from_str(ws.next().await.unwrap().unwrap().to_text().unwrap()).unwrap();
    assert_eq!(e["error"]["code"], "invalid_view", "{e}");
    ws.send(Message::binary(vec![1u8, 2, 3])).await.unwrap();
    let e: Value =
        serde_json::from_str(ws.next().await.unwrap().unwrap().to_text().unwrap()).unwrap();
    assert_eq!(e["error"]["code"], "malformed_json", "{e}");
    ws.send(Message::text(VIEW)).await.unwrap();
    let f: FrameResponse =
        serde_json::from_str(ws.next().await.unwrap().unwrap().to_text().unwrap()).unwrap();
    assert_eq!((f.frame, f.base), (1, None));
    // The session is deleted under the socket: an error, then a close.
    let r = c
        .delete(s.url(&format!("/sessions/{sid}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    ws.send(Message::text(VIEW)).await.unwrap();
    let e: Value =
        serde_json::from_str(ws.next().await.unwrap().unwrap().to_text().unwrap()).unwrap();
    assert_eq!(e["error"]["code"], "unknown_session", "{e}");
    assert!(matches!(
        ws.next().await,
        Some(Ok(Message::Close(_))) | None
    ));
}
