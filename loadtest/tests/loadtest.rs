//! The `loadtest` binary against servers started here: a real pvsd (zero
//! errors in every mode, a complete JSON report with ordered percentiles),
//! and a deliberately slow server that shows open-loop latency is counted
//! from the schedule.
//!
//! loadtest shares only `pvsd-proto` with the server, so the real pvsd is
//! its binary, run as an operator would (`pvsd gen`, `pvsd serve`); the
//! test builds it first with the cargo that runs the tests (a no-op when it
//! is fresh), so it is never a stale one.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

mod common;

use common::pvsd_binary;

use axum::Json;
use axum::routing::{get, post};
use serde_json::{Value, json};

/// Serves `router` on a loopback port from a thread of its own (the
/// loadtest process runs while this test blocks on it).
fn serve(router: axum::Router) -> String {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Runtime::new().unwrap();
        rt.block_on(async move {
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
            tx.send(listener.local_addr().unwrap()).unwrap();
            axum::serve(listener, router).await.unwrap();
        });
    });
    format!("http://{}", rx.recv().unwrap())
}

/// A `pvsd serve` process, killed when dropped.
struct Pvsd {
    child: Child,
    /// Where it listens, `http://host:port`.
    url: String,
    /// Holds the scene file for the server's lifetime.
    _dir: tempfile::TempDir,
}

impl Drop for Pvsd {
    fn drop(&mut self) {
        self.child.kill().ok();
        self.child.wait().ok();
    }
}

/// `pvsd serve` on a loopback port with a generated city of 100 buildings,
/// served as `city`.
fn pvsd_server() -> Pvsd {
    pvsd_city(100)
}

/// `pvsd serve` on a loopback port with a generated city of `buildings`.
fn pvsd_city(buildings: u32) -> Pvsd {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("city.glb");
    let status = Command::new(pvsd_binary())
        .args(["gen", "city", "--buildings", &buildings.to_string(), "-o"])
        .arg(&scene)
        .stderr(Stdio::null())
        .status()
        .unwrap();
    assert!(status.success(), "pvsd gen city failed");
    let (child, url) = serve_scene(&scene, "127.0.0.1:0");
    Pvsd {
        child,
        url,
        _dir: dir,
    }
}

/// `pvsd serve --scene scene --addr addr`, once it is ready, and its URL.
fn serve_scene(scene: &Path, addr: &str) -> (Child, String) {
    let mut child = Command::new(pvsd_binary())
        .args(["serve", "--addr", addr, "--scene"])
        .arg(scene)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut addr = None;
    let addr = loop {
        assert!(Instant::now() < deadline, "pvsd serve said no 'ready'");
        let line = lines.next().expect("pvsd serve exited early").unwrap();
        if let Some(rest) = line.split("listening on http://").nth(1) {
            addr = rest.split_whitespace().next().map(str::to_string);
        }
        if line.contains("ready: every scene is loaded") {
            break addr.expect("a 'listening on' line before 'ready'");
        }
    };
    // Keep reading its log, so a full pipe never blocks the server.
    std::thread::spawn(move || lines.for_each(drop));
    (child, format!("http://{addr}"))
}

fn loadtest(args: &[&str]) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report.json");
    let status = Command::new(env!("CARGO_BIN_EXE_loadtest"))
        .args(args)
        .arg("--json")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success(), "loadtest {args:?} failed");
    serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap()
}

#[test]
fn every_mode_runs_without_errors_and_reports_every_field() {
    let server = pvsd_server();
    let target = server.url.clone();
    for (mode, rate) in [
        ("session", None),
        ("stateless", None),
        ("ws", None),
        ("session", Some("50")),
        ("ws", Some("50")),
        ("walkthrough", None),
        ("session,ws,walkthrough", Some("50")),
    ] {
        let mut args = vec![
            "--target",
            &target,
            "--scene",
            "city",
            "--users",
            "4",
            "--duration",
            "1.5",
            "--mode",
            mode,
        ];
        if let Some(r) = rate {
            args.extend(["--rate", r]);
        }
        let r = loadtest(&args);
        for field in [
            "requests",
            "errors",
            "errors_by_kind",
            "rps",
            "p50_ms",
            "p95_ms",
            "p99_ms",
            "p999_ms",
            "max_ms",
            "bytes_in",
            "bytes_out",
            "lost",
            "lost_by_kind",
            "reconnects",
            "users",
        ] {
            assert!(r.get(field).is_some(), "{mode}: no '{field}' in {r}");
        }
        assert_eq!(r["errors"], 0, "{mode} {rate:?}: {r}");
        assert_eq!(r["lost"], 0, "{mode} {rate:?}: {r}");
        let users = r["users"].as_array().unwrap();
        assert_eq!(users.len(), 4, "{mode}: {r}");
        if mode == "walkthrough" {
            // One walkthrough of four users, each behind the next: the
            // three behind see someone in most frames.
            let seeing = users
                .iter()
                .filter(|u| u["saw_users"].as_u64().unwrap() * 2 > u["answered"].as_u64().unwrap())
                .count();
            assert!(seeing >= 3, "{r}");
        }
        assert!(r["requests"].as_u64().unwrap() > 20, "{mode}: {r}");
        let p: Vec<f64> = ["p50_ms", "p95_ms", "p99_ms", "p999_ms", "max_ms"]
            .iter()
            .map(|k| r[k].as_f64().unwrap())
            .collect();
        assert!(
            p.windows(2).all(|w| w[0] <= w[1]),
            "{mode}: percentiles out of order {p:?}"
        );
        assert!(p[0] > 0.0);
        assert!(r["bytes_in"].as_u64().unwrap() > 0 && r["bytes_out"].as_u64().unwrap() > 0);
        if let Some(rate) = rate {
            // 4 users × 50/s × 1.5 s, on schedule.
            let expected = 4.0 * rate.parse::<f64>().unwrap() * 1.5;
            let n = r["requests"].as_f64().unwrap();
            assert!(
                (n - expected).abs() <= 8.0,
                "{mode}: {n} frames, not ~{expected}"
            );
        }
    }
}

#[test]
fn errors_are_counted_by_kind() {
    let server = pvsd_server();
    let target = server.url.clone();
    // A method the scene does not support: every session fails to start.
    let r = loadtest(&[
        "--target",
        &target,
        "--scene",
        "city",
        "--users",
        "2",
        "--duration",
        "0.5",
        "--method",
        "ddo",
    ]);
    assert_eq!(r["errors_by_kind"]["create_session"], 2, "{r}");
    let status = Command::new(env!("CARGO_BIN_EXE_loadtest"))
        .args([
            "--target",
            &target,
            "--scene",
            "nowhere",
            "--duration",
            "0.5",
        ])
        .output()
        .unwrap();
    assert!(!status.status.success());
    assert!(String::from_utf8_lossy(&status.stderr).contains("no scene 'nowhere'"));
}

/// A server listing one scene, `slow`, to which tests add its routes.
fn slow_scene() -> axum::Router {
    axum::Router::new().route(
        "/scenes",
        get(|| async {
            Json(json!([{"id": "slow", "objects": 1, "triangles": 2,
                "bounds": {"min": [0, 0, 0], "max": [10, 1, 10]},
                "up": [0, 1, 0], "methods": ["frustum"], "unsupported": {}}]))
        }),
    )
}

/// A server that answers one request at a time, each after 100 ms: 5
/// frames a second offered to a server that serves 10 a second at most is
/// fine, 20 a second is not. Closed loop would hide it (each user waits,
/// latency stays ~100 ms); open loop counts from the schedule, so the
/// queue shows in the percentiles.
#[test]
fn open_loop_latency_counts_from_the_schedule() {
    let lock = Arc::new(tokio::sync::Mutex::new(()));
    let slow = {
        let lock = lock.clone();
        move || {
            let lock = lock.clone();
            async move {
                let _one_at_a_time = lock.lock().await;
                tokio::time::sleep(Duration::from_millis(100)).await;
                axum::body::Bytes::from_static(&[b'V', 0])
            }
        }
    };
    let target = serve(slow_scene().route("/scenes/slow/visible", post(slow)));
    let run = |rate: Option<&str>| {
        let mut args = vec![
            "--target",
            &target,
            "--scene",
            "slow",
            "--users",
            "1",
            "--duration",
            "3",
            "--mode",
            "stateless",
        ];
        if let Some(r) = rate {
            args.extend(["--rate", r]);
        }
        loadtest(&args)
    };
    let closed = run(None);
    let under = run(Some("5"));
    let over = run(Some("20"));
    let p99 = |r: &Value| r["p99_ms"].as_f64().unwrap();
    eprintln!(
        "p99: closed {} ms, open 5/s {} ms, open 20/s {} ms",
        p99(&closed),
        p99(&under),
        p99(&over)
    );
    assert!(p99(&closed) < 400.0, "{closed}");
    assert!(p99(&under) < 400.0, "{under}");
    // 60 frames due in 3 s, served at 10/s: the last waits ~3 s.
    assert!(p99(&over) > 1500.0, "open loop hid the queue: {over}");
    assert_eq!(over["errors"], 0);
}

/// Open loop keeps at most `--max-in-flight` requests per user in flight
/// (a stall must not open a connection per late frame): a server that
/// answers in 50 ms never sees more at once, and the frames that queued
/// in the users show their wait in the latency.
#[test]
fn open_loop_bounds_the_requests_in_flight() {
    let (now, most) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicUsize::new(0)));
    let slow = {
        let (now, most) = (now.clone(), most.clone());
        move || {
            let (now, most) = (now.clone(), most.clone());
            async move {
                most.fetch_max(now.fetch_add(1, Ordering::SeqCst) + 1, Ordering::SeqCst);
                tokio::time::sleep(Duration::from_millis(50)).await;
                now.fetch_sub(1, Ordering::SeqCst);
                axum::body::Bytes::from_static(&[b'V', 0])
            }
        }
    };
    let target = serve(slow_scene().route("/scenes/slow/visible", post(slow)));
    let run = |cap: &str| {
        loadtest(&[
            "--target",
            &target,
            "--scene",
            "slow",
            "--users",
            "2",
            "--duration",
            "1.5",
            "--mode",
            "stateless",
            "--rate",
            "100",
            "--max-in-flight",
            cap,
        ])
    };
    // 150 frames due per user, answered 40 a second each (2 slots, 50 ms):
    // a queue of seconds.
    let capped = run("2");
    let seen = most.swap(0, Ordering::SeqCst);
    assert!(
        seen <= 4,
        "2 users x 2 in flight, the server saw {seen} at once"
    );
    assert!(capped["p99_ms"].as_f64().unwrap() > 1000.0, "{capped}");
    assert_eq!(capped["errors"], 0);
    assert_eq!(capped["config"]["max_in_flight"], 2);
    run("16");
    let seen = most.load(Ordering::SeqCst);
    assert!(seen > 4, "a wider cap was not used: {seen} at once");
}

/// A server killed (SIGKILL) and started again on its address while users
/// walk: their sessions are gone (404, or no answer while it is down), each
/// user makes a new one and goes on; the chain of deltas never breaks, and
/// neither side crashes.
#[test]
fn a_server_killed_and_restarted_mid_run_costs_sessions_not_the_run() {
    let mut server = pvsd_server();
    let target = server.url.clone();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report.json");
    let mut run = Command::new(env!("CARGO_BIN_EXE_loadtest"))
        .args(["--target", &target, "--scene", "city", "--users", "4"])
        .args(["--duration", "6", "--rate", "40", "--json"])
        .arg(&out)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(2));
    server.child.kill().unwrap();
    server.child.wait().unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let scene = server._dir.path().join("city.glb");
    let (restarted, _) = serve_scene(&scene, target.trim_start_matches("http://"));
    server.child = restarted;
    assert!(run.wait().unwrap().success(), "loadtest failed");
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let reconnects = r["reconnects"].as_u64().unwrap();
    assert!(reconnects >= 4, "every user makes a new session: {r}");
    // Frames lost while the server was away, or to the dead sessions; never
    // an answer that does not decode or chain.
    assert_eq!(r["errors"], 0, "{r}");
    assert!(r["lost"].as_u64().unwrap() >= 4, "{r}");
    for (kind, _) in r["lost_by_kind"].as_object().unwrap() {
        assert!(
            ["connect", "read", "http_404"].contains(&kind.as_str()),
            "lost '{kind}': {r}"
        );
    }
    let answered = r["requests"].as_u64().unwrap() - r["lost"].as_u64().unwrap();
    assert!(answered > 4 * 40 * 3, "few frames answered: {r}");
}

/// What `/proc` says of a process: resident memory (KiB) and open files.
fn rss_and_fds(pid: u32) -> (u64, usize) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let rss = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap();
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .unwrap()
        .count();
    (rss, fds)
}

/// The soak's short form (`scripts/soak.sh` is the 30-minute one): a minute
/// of users walking at a fixed rate with sessions churning, the server's
/// memory and open files sampled: no errors, memory flat after warm-up,
/// files back where they started once the users are gone.
#[test]
fn a_minute_of_churning_sessions_leaves_memory_and_files_bounded() {
    let server = pvsd_city(1000);
    let pid = server.child.id();
    let target = server.url.clone();
    std::thread::sleep(Duration::from_secs(3));
    let (_, fds_before) = rss_and_fds(pid);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report.json");
    let started = Instant::now();
    let mut run = Command::new(env!("CARGO_BIN_EXE_loadtest"))
        .args(["--target", &target, "--scene", "city", "--users", "32"])
        .args(["--duration", "60", "--rate", "20", "--churn", "100"])
        .args(["--method", "horizon", "--json"])
        .arg(&out)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut samples = Vec::new();
    while run.try_wait().unwrap().is_none() {
        samples.push((started.elapsed().as_secs_f64(), rss_and_fds(pid)));
        std::thread::sleep(Duration::from_secs(2));
    }
    assert!(run.wait().unwrap().success());
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    eprintln!("samples (s, (rss KiB, fds)): {samples:?}");
    assert_eq!(r["errors"], 0, "{r}");
    assert!(r["churned"].as_u64().unwrap() > 300, "{r}");
    let warm = samples
        .iter()
        .find(|(t, _)| *t >= 20.0)
        .map(|(_, (rss, _))| *rss)
        .expect("a sample after warm-up");
    let peak = samples
        .iter()
        .filter(|(t, _)| *t >= 20.0)
        .map(|(_, (rss, _))| *rss)
        .max()
        .unwrap();
    assert!(
        peak <= warm + warm / 5,
        "memory grew after warm-up: {warm} KiB at 20 s, {peak} KiB at most"
    );
    let most_fds = samples.iter().map(|(_, (_, f))| *f).max().unwrap();
    // At most a connection per frame in flight (4) and one for the user's
    // churn, per user.
    assert!(
        most_fds <= fds_before + 32 * 5 + 16,
        "{most_fds} files open"
    );
    std::thread::sleep(Duration::from_secs(1));
    let (_, fds_after) = rss_and_fds(pid);
    assert!(
        fds_after <= fds_before + 2,
        "{fds_after} files open after, {fds_before} before"
    );
}

/// SIGTERM under load: the server stops taking connections, answers what
/// is in flight, closes WebSockets with a reason and exits cleanly, well
/// within its grace period; the users see the server go, nothing worse.
#[test]
fn sigterm_under_load_drains_and_exits_within_the_grace_period() {
    let mut server = pvsd_server();
    let target = server.url.clone();
    let runs: Vec<Child> = ["session", "ws"]
        .iter()
        .map(|mode| {
            Command::new(env!("CARGO_BIN_EXE_loadtest"))
                .args(["--target", &target, "--scene", "city", "--users", "4"])
                .args(["--duration", "4", "--mode", mode])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap()
        })
        .collect();
    std::thread::sleep(Duration::from_millis(1500));
    let status = Command::new("kill")
        .args(["-TERM", &server.child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let asked = Instant::now();
    let exited = loop {
        if let Some(status) = server.child.try_wait().unwrap() {
            break status;
        }
        assert!(
            asked.elapsed() < Duration::from_secs(10),
            "still running after the 10 s grace period"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(exited.success(), "exit status {exited}");
    assert!(
        asked.elapsed() < Duration::from_secs(3),
        "{:?}",
        asked.elapsed()
    );
    for mut run in runs {
        assert!(run.wait().unwrap().success(), "loadtest failed");
    }
}

/// `--radius 1 --speed 1.4` at 30 frames a second: users send a frame only
/// when they leave the ball of their last answer, in every mode, with no
/// error; against `--radius 0` that saves most requests (a new one about
/// every 21st frame, and at each turn of the street walk).
#[test]
fn a_radius_saves_the_frames_a_walker_spends_inside_its_ball() {
    let pvsd = pvsd_server();
    let run = |radius: &str, mode: &str| {
        loadtest(&[
            "--target",
            &pvsd.url,
            "--scene",
            "city",
            "--users",
            "4",
            "--duration",
            "3",
            "--mode",
            mode,
            "--method",
            "horizon",
            "--speed",
            "1.4",
            "--radius",
            radius,
        ])
    };
    let point = run("0", "session");
    assert_eq!(point["errors"], 0, "{point}");
    assert_eq!(point["kept"], 0, "{point}");
    for mode in ["stateless", "session", "ws", "walkthrough"] {
        let region = run("1", mode);
        assert_eq!(region["errors"], 0, "{mode}: {region}");
        let saved = region["requests_saved"].as_f64().unwrap();
        assert!(saved > 2.0 / 3.0, "{mode}: saved only {saved}: {region}");
        assert_eq!(region["config"]["radius"], 1.0);
    }
}
