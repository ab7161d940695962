//! The execution modes and the one dispatch, over a real socket. A device
//! method (frustum culling run on a device queue's thread) answers
//! stateless requests, session frames, WebSocket frames and walkthrough
//! frames with frustum culling's ids; jobs that wait together run as one
//! batch; a full queue answers 503 with `Retry-After` and loses nothing
//! else; a method that fails at run time (a lost device, a panic on the
//! blocking pool) is answered by frustum culling, says so in its stats,
//! and is counted in `/metrics`.

mod common;

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

use common::city_scene;
use common::server::{Held, Server, view_json};
use futures_util::{SinkExt, StreamExt};
use pvsd::cull::frustum::FrustumCulling;
use pvsd::cull::{
    BatchItem, CullCounters, CullError, CullMethod, DeviceLimits, DeviceQueue, Execution,
    MethodContext, MethodEntry, MethodError, MethodOptions, Occludees, Preparation, Registry, View,
    VisibleSet,
};
use pvsd::geom::Camera;
use pvsd::server::{AppState, Limits};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

/// What the device method saw, and the switches a test turns.
#[derive(Default)]
struct Probe {
    /// Sizes of the batches it culled.
    batches: Mutex<Vec<usize>>,
    /// Names of the threads it culled on.
    threads: Mutex<BTreeSet<String>>,
    /// Jobs it has begun.
    begun: AtomicUsize,
    /// While set, the device waits before culling (a slow device).
    hold: AtomicBool,
    /// While set, the device answers every job with a failure (a lost device).
    lost: AtomicBool,
    /// While set, the device panics in its batch.
    panics: AtomicBool,
}

/// The probe of `on_device`, the first test's device method.
fn probe() -> &'static Probe {
    static PROBE: OnceLock<Probe> = OnceLock::new();
    PROBE.get_or_init(Probe::default)
}

/// The probe of `on_hung_device`, the deadline test's (tests run in
/// parallel: each turns only its own switches).
fn hung_probe() -> &'static Probe {
    static PROBE: OnceLock<Probe> = OnceLock::new();
    PROBE.get_or_init(Probe::default)
}

/// Frustum culling on a device's thread, in batches.
struct OnDevice {
    name: &'static str,
    inner: FrustumCulling,
    queue: Arc<DeviceQueue>,
    probe: &'static Probe,
}

impl CullMethod for OnDevice {
    type State = ();
    fn name(&self) -> &'static str {
        self.name
    }
    fn new_state(&self, options: &MethodOptions) -> Result<(), MethodError> {
        options.reader(self.name, &[]).finish()
    }
    fn is_conservative(&self, _: &()) -> bool {
        true
    }
    fn execution(&self) -> Execution {
        Execution::Device(self.queue.clone())
    }
    fn cull(
        &self,
        view: &View,
        state: &mut (),
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        if self.probe.lost.load(Ordering::SeqCst) {
            return Err(CullError::Failed {
                method: self.name,
                reason: "device lost".into(),
            });
        }
        self.inner.cull(view, state, out, occludees)
    }
    fn cull_batch(&self, batch: &mut [BatchItem<'_, ()>]) -> Vec<Result<CullCounters, CullError>> {
        let p = self.probe;
        p.begun.fetch_add(batch.len(), Ordering::SeqCst);
        while p.hold.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert!(!p.panics.load(Ordering::SeqCst), "the device caught fire");
        p.batches.lock().unwrap().push(batch.len());
        let thread = std::thread::current().name().unwrap_or("").to_string();
        p.threads.lock().unwrap().insert(thread);
        batch
            .iter_mut()
            .map(|b| self.cull(b.view, b.state, b.out, b.occludees))
            .collect()
    }
}

/// Frustum culling on the blocking pool that panics: a bug in a method.
struct Panicky;

impl CullMethod for Panicky {
    type State = ();
    fn name(&self) -> &'static str {
        "panicky"
    }
    fn new_state(&self, _: &MethodOptions) -> Result<(), MethodError> {
        Ok(())
    }
    fn is_conservative(&self, _: &()) -> bool {
        true
    }
    fn cull(
        &self,
        _: &View,
        _: &mut (),
        _: &mut VisibleSet,
        _: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        panic!("an index out of bounds")
    }
}

/// An `OnDevice` method named `name` on the context's device, reporting to `probe`.
fn on_device(
    p: &Preparation<'_>,
    name: &'static str,
    probe: &'static Probe,
) -> Result<Arc<dyn pvsd::cull::Culler>, String> {
    Ok(Arc::new(OnDevice {
        name,
        inner: FrustumCulling::new(p.scene().clone(), p.kd_tree()),
        queue: p.context().device.clone().ok_or("no device")?,
        probe,
    }))
}

fn registry() -> Registry {
    Registry::standard()
        .with(MethodEntry {
            name: "on_device",
            purpose: "frustum culling on a device's thread (a test's device)",
            checked_with: &[],
            options: &[],
            regions: None,
            build: |p| on_device(p, "on_device", probe()),
        })
        .with(MethodEntry {
            name: "on_hung_device",
            purpose: "frustum culling on a device that may hang (a test's device)",
            checked_with: &[],
            options: &[],
            regions: None,
            build: |p| on_device(p, "on_hung_device", hung_probe()),
        })
        .with(MethodEntry {
            name: "panicky",
            purpose: "a method with a bug",
            checked_with: &[],
            options: &[],
            regions: None,
            build: |_| Ok(Arc::new(Panicky)),
        })
}

fn camera(i: usize) -> Camera {
    Camera {
        eye: glam::DVec3::new(2.0 + i as f64, 1.7, 1.0),
        forward: glam::DVec3::new(1.0, -0.05, 0.3 + 0.01 * i as f64),
        ..Camera::default()
    }
}

fn view(i: usize, method: Option<&str>) -> Value {
    let mut v = view_json(&camera(i));
    if let Some(m) = method {
        v["method"] = json!(m);
    }
    v
}

async fn post(c: &reqwest::Client, url: String, body: Value) -> (u16, Option<String>, Value) {
    let res = c.post(url).json(&body).send().await.unwrap();
    let status = res.status().as_u16();
    let retry = res
        .headers()
        .get("retry-after")
        .map(|v| v.to_str().unwrap().to_string());
    (status, retry, res.json().await.unwrap())
}

/// [`post`] on a task of its own.
fn spawn_post(
    c: &reqwest::Client,
    url: &str,
    body: Value,
) -> tokio::task::JoinHandle<(u16, Option<String>, Value)> {
    let (c, url) = (c.clone(), url.to_string());
    tokio::spawn(async move { post(&c, url, body).await })
}

fn ids(v: &Value, field: &str) -> Vec<u64> {
    v[field]
        .as_array()
        .unwrap_or_else(|| panic!("no {field} in {v}"))
        .iter()
        .map(|x| x.as_u64().unwrap())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_dispatch_serves_every_route_from_a_device_and_falls_back() {
    let limits = DeviceLimits {
        capacity: 4,
        max_batch: 16,
        retry_after: Duration::from_millis(200),
        deadline: Duration::from_secs(10),
    };
    let queue = DeviceQueue::start("test", limits).unwrap();
    let context = MethodContext {
        device: Some(queue),
        ..MethodContext::default()
    };
    let state = AppState::with_methods(
        vec![city_scene(200, 3, [0.0; 3])],
        Limits::default(),
        &registry(),
        &context,
    )
    .unwrap();
    let s = Server::start(state).await;
    let c = reqwest::Client::new();
    let p = probe();

    // Stateless: the device's answer is frustum culling's, culled on the device's thread.
    let url = s.url("/scenes/city/visible");
    let (status, _, device) = post(&c, url.clone(), view(0, Some("on_device"))).await;
    assert_eq!(status, 200, "{device}");
    let (_, _, frustum) = post(&c, url.clone(), view(0, Some("frustum"))).await;
    assert!(!ids(&frustum, "visible").is_empty());
    assert_eq!(ids(&device, "visible"), ids(&frustum, "visible"));
    assert_eq!(device["stats"]["method"], "on_device");
    assert!(device["stats"].get("fallback").is_none(), "{device}");
    assert_eq!(
        p.threads.lock().unwrap().iter().collect::<Vec<_>>(),
        ["pvsd-device-test"]
    );

    // A session's frames, over HTTP and over its WebSocket.
    let (status, _, created) = post(
        &c,
        s.url("/sessions"),
        json!({"scene": "city", "method": "on_device"}),
    )
    .await;
    assert_eq!(status, 201, "{created}");
    let sid = created["session"].as_str().unwrap().to_string();
    let frames_url = s.url(&format!("/sessions/{sid}/frames"));
    let mut held = Held::default();
    let (status, _, frame) = post(&c, frames_url.clone(), view(0, None)).await;
    assert_eq!(status, 200, "{frame}");
    assert_eq!(ids(&frame, "added"), ids(&frustum, "visible"));
    held.apply(&serde_json::from_value(frame).unwrap());
    let (mut ws, _) = tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws")))
        .await
        .unwrap();
    ws.send(Message::text(view(1, None).to_string()))
        .await
        .unwrap();
    let Some(Ok(Message::Text(text))) = ws.next().await else {
        panic!("no frame over the WebSocket")
    };
    let frame: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(frame["frame"], 2, "{frame}");
    held.apply(&serde_json::from_value(frame).unwrap());

    // Walkthrough users' frames: one user stands ahead of the other's
    // view (avatars are tested as the job's occludees on the device).
    let (_, _, w) = post(
        &c,
        s.url("/walkthroughs"),
        json!({"scene": "city", "method": "on_device"}),
    )
    .await;
    let wid = w["walkthrough"].as_str().unwrap().to_string();
    let join = || post(&c, s.url(&format!("/walkthroughs/{wid}/users")), json!({}));
    let (_, _, a) = join().await;
    let (_, _, b) = join().await;
    let frame_of = |user: &Value| {
        s.url(&format!(
            "/sessions/{}/frames",
            user["session"].as_str().unwrap()
        ))
    };
    let ahead = json!({"eye": [10.0, 1.7, 2.92], "forward": [-1, 0, 0]});
    let (status, _, frame) = post(&c, frame_of(&b), ahead).await;
    assert_eq!(status, 200, "{frame}");
    let (status, _, frame) = post(&c, frame_of(&a), view(2, None)).await;
    assert_eq!(status, 200, "{frame}");
    assert_eq!(frame["users_visible"], json!([b["user"]]), "{frame}");
    let culled_so_far = p.begun.load(Ordering::SeqCst);
    assert!(
        culled_so_far >= 4,
        "every route went through the device: {culled_so_far}"
    );

    // A slow device: one job in its hands, four wait (one batch later), the
    // rest are refused at once with 503 and Retry-After.
    p.hold.store(true, Ordering::SeqCst);
    let first = spawn_post(&c, &url, view(3, Some("on_device")));
    while p.begun.load(Ordering::SeqCst) == culled_so_far {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let rest: Vec<_> = (0..10)
        .map(|i| spawn_post(&c, &url, view(4 + i, Some("on_device"))))
        .collect();
    // The refusals come back while the device still holds.
    let mut answers = Vec::new();
    let mut pending = rest;
    while answers.len() < 6 {
        let (done, _, others) = futures_util::future::select_all(pending).await;
        answers.push(done.unwrap());
        pending = others;
    }
    // The queue is full now: a session's frame is refused too, and takes
    // no frame number.
    answers.push(post(&c, frames_url.clone(), view(5, None)).await);
    for (status, retry, body) in &answers {
        assert_eq!(*status, 503, "{body}");
        assert_eq!(retry.as_deref(), Some("1"));
        assert_eq!(body["error"]["code"], "busy", "{body}");
    }
    p.hold.store(false, Ordering::SeqCst);
    assert_eq!(first.await.unwrap().0, 200);
    for task in pending {
        let (status, _, body) = task.await.unwrap();
        assert_eq!(status, 200, "{body}");
    }
    let batches = p.batches.lock().unwrap().clone();
    assert!(
        batches.contains(&4),
        "the four that waited ran as one batch: {batches:?}"
    );

    // A lost device: frustum culling answers, and says so; its time is
    // observed under frustum, not under the method that failed.
    let counted = |method: &str| {
        format!("pvsd_cull_duration_seconds_count{{scene=\"city\",method=\"{method}\"}}")
    };
    let device_culls = s.metric(&c, &counted("on_device")).await;
    let frustum_culls = s.metric(&c, &counted("frustum")).await;
    assert!(device_culls > 0.0 && frustum_culls > 0.0);
    p.lost.store(true, Ordering::SeqCst);
    let (status, _, lost) = post(&c, url.clone(), view(0, Some("on_device"))).await;
    assert_eq!(s.metric(&c, &counted("on_device")).await, device_culls);
    assert_eq!(s.metric(&c, &counted("frustum")).await, frustum_culls + 1.0);
    assert_eq!(status, 200, "{lost}");
    assert_eq!(lost["stats"]["method"], "on_device");
    assert_eq!(lost["stats"]["fallback"], "frustum");
    assert_eq!(lost["stats"]["fallback_reason"], "device lost");
    assert_eq!(ids(&lost, "visible"), ids(&frustum, "visible"));
    // The session goes on past the refusal and the failure: its deltas
    // chain from the last frame answered and rebuild frustum's set.
    let (status, _, frame) = post(&c, frames_url.clone(), view(0, None)).await;
    assert_eq!(status, 200, "{frame}");
    assert_eq!(
        (&frame["frame"], &frame["base"]),
        (&json!(3), &json!(2)),
        "{frame}"
    );
    held.apply(&serde_json::from_value(frame).unwrap());
    let want: Vec<u32> = ids(&frustum, "visible").iter().map(|&i| i as u32).collect();
    assert_eq!(held.sorted(), want);
    p.lost.store(false, Ordering::SeqCst);

    // A device whose batch panics, and a method that panics on the
    // blocking pool: both answered by frustum culling.
    p.panics.store(true, Ordering::SeqCst);
    let (status, _, burnt) = post(&c, url.clone(), view(0, Some("on_device"))).await;
    p.panics.store(false, Ordering::SeqCst);
    assert_eq!(status, 200, "{burnt}");
    assert_eq!(burnt["stats"]["fallback"], "frustum");
    let (status, _, bug) = post(&c, url.clone(), view(0, Some("panicky"))).await;
    assert_eq!(status, 200, "{bug}");
    assert_eq!(bug["stats"]["fallback"], "frustum");
    // What panicked stays in the server's log.
    assert_eq!(
        bug["stats"]["fallback_reason"],
        pvsd::cull::dispatch::PANICKED
    );
    // The device still works after its panic.
    let (_, _, again) = post(&c, url.clone(), view(0, Some("on_device"))).await;
    assert!(again["stats"].get("fallback").is_none(), "{again}");

    let fallbacks =
        |method: &str| format!("pvsd_cull_fallbacks_total{{scene=\"city\",method=\"{method}\"}}");
    assert_eq!(s.metric(&c, &fallbacks("on_device")).await, 3.0);
    assert_eq!(s.metric(&c, &fallbacks("panicky")).await, 1.0);
}

/// `/scenes` lists the test's methods, and the device method is
/// unsupported, with the reason, where there is no device.
#[tokio::test]
async fn without_a_device_a_device_method_is_unsupported_with_the_reason() {
    let state = AppState::with_methods(
        vec![city_scene(20, 3, [0.0; 3])],
        Limits::default(),
        &registry(),
        &MethodContext::default(),
    )
    .unwrap();
    let s = Server::start(state).await;
    let scenes: Value = reqwest::get(s.url("/scenes"))
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(scenes[0]["unsupported"]["on_device"], "no device");
    assert!(
        scenes[0]["methods"]
            .as_array()
            .unwrap()
            .contains(&json!("panicky"))
    );
    let c = reqwest::Client::new();
    let (status, _, body) = post(
        &c,
        s.url("/scenes/city/visible"),
        view(0, Some("on_device")),
    )
    .await;
    assert_eq!(status, 400, "{body}");
    assert_eq!(body["error"]["code"], "unsupported_method");
}

/// A device that does not answer within its deadline: the caller is
/// answered by frustum culling, avatars included, and the device's late
/// answer goes nowhere; once it answers again, so does the method.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hung_device_is_answered_by_frustum_culling_at_its_deadline() {
    let limits = DeviceLimits {
        deadline: Duration::from_secs(1),
        ..DeviceLimits::default()
    };
    let context = MethodContext {
        device: Some(DeviceQueue::start("hung", limits).unwrap()),
        ..MethodContext::default()
    };
    let state = AppState::with_methods(
        vec![city_scene(200, 3, [0.0; 3])],
        Limits::default(),
        &registry(),
        &context,
    )
    .unwrap();
    let s = Server::start(state).await;
    let c = reqwest::Client::new();
    let p = hung_probe();
    let (_, _, w) = post(
        &c,
        s.url("/walkthroughs"),
        json!({"scene": "city", "method": "on_hung_device"}),
    )
    .await;
    let wid = w["walkthrough"].as_str().unwrap().to_string();
    let join = || post(&c, s.url(&format!("/walkthroughs/{wid}/users")), json!({}));
    let (_, _, a) = join().await;
    let (_, _, b) = join().await;
    let frame_of = |user: &Value| {
        s.url(&format!(
            "/sessions/{}/frames",
            user["session"].as_str().unwrap()
        ))
    };
    let (status, _, _) = post(
        &c,
        frame_of(&b),
        json!({"eye": [10.0, 1.7, 2.92], "forward": [-1, 0, 0]}),
    )
    .await;
    assert_eq!(status, 200);

    p.hold.store(true, Ordering::SeqCst);
    let started = std::time::Instant::now();
    let (status, _, frame) = post(&c, frame_of(&a), view(2, None)).await;
    let waited = started.elapsed();
    p.hold.store(false, Ordering::SeqCst);
    assert_eq!(status, 200, "{frame}");
    assert!(waited >= Duration::from_secs(1), "{waited:?}");
    assert_eq!(frame["users_visible"], json!([b["user"]]), "{frame}");
    let (_, _, frustum) = post(&c, s.url("/scenes/city/visible"), view(2, Some("frustum"))).await;
    assert_eq!(ids(&frame, "added"), ids(&frustum, "visible"));
    let (_, _, stateless) = post(
        &c,
        s.url("/scenes/city/visible"),
        view(2, Some("on_hung_device")),
    )
    .await;
    assert!(stateless["stats"].get("fallback").is_none(), "{stateless}");
    // Two stateless requests while the device hangs: one in its hands,
    // one waiting in its queue; both answered by frustum culling at the
    // deadline. Once the device is back it finishes the first and skips the
    // second, which nobody waits for any more.
    let url = s.url("/scenes/city/visible");
    p.hold.store(true, Ordering::SeqCst);
    let begun = p.begun.load(Ordering::SeqCst);
    let held = spawn_post(&c, &url, view(2, Some("on_hung_device")));
    while p.begun.load(Ordering::SeqCst) == begun {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let queued = spawn_post(&c, &url, view(3, Some("on_hung_device")));
    for late in [held.await.unwrap().2, queued.await.unwrap().2] {
        assert_eq!(late["stats"]["fallback"], "frustum", "{late}");
        let reason = late["stats"]["fallback_reason"].as_str().unwrap();
        assert!(reason.starts_with("no answer within"), "{late}");
    }
    p.hold.store(false, Ordering::SeqCst);
    let (_, _, back) = post(&c, url.clone(), view(4, Some("on_hung_device"))).await;
    assert!(back["stats"].get("fallback").is_none(), "{back}");
    assert_eq!(
        p.begun.load(Ordering::SeqCst),
        begun + 2,
        "the stale queued job was culled"
    );
}
