//! Scale-out on this machine: three pvsd replicas behind a real nginx
//! (Debian's package), loadtest through it with sessions, WebSockets and
//! walkthroughs, one replica killed mid-run and one added later
//! (`deploy/local/replicas.sh` does it; this test checks what it wrote).
//!
//! Needs nginx; without it the test says so and checks nothing, unless
//! `PVSD_REQUIRE_NGINX` is set (CI sets it), when that is a failure.

mod common;

use std::path::Path;
use std::process::Command;

use serde_json::Value;

fn nginx() -> Option<String> {
    let found = ["/usr/sbin/nginx", "/usr/bin/nginx"]
        .into_iter()
        .find(|p| Path::new(p).exists())
        .map(String::from);
    if found.is_none() {
        assert!(
            std::env::var_os("PVSD_REQUIRE_NGINX").is_none(),
            "PVSD_REQUIRE_NGINX is set, but nginx is not installed (apt-get install nginx)"
        );
        eprintln!(
            "skipped: no nginx here (apt-get install nginx; PVSD_REQUIRE_NGINX=1 makes this a failure)"
        );
    }
    found
}

/// The phase of the run a time (seconds into it) falls in.
fn phase_of(phases: &[Value], t: f64) -> String {
    phases
        .iter()
        .rev()
        .find(|p| p["from_s"].as_f64().unwrap() <= t)
        .map_or("start".into(), |p| p["label"].as_str().unwrap().to_string())
}

#[test]
fn a_killed_replica_costs_only_its_own_clients_one_frame_and_a_reconnect() {
    let Some(nginx) = nginx() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/local/replicas.sh");
    let (users, rate) = (24u64, 20.0);
    let run = Command::new("bash")
        .arg(&script)
        .arg(out.path())
        .env("PVSD", common::pvsd_binary())
        .env("LOADTEST", env!("CARGO_BIN_EXE_loadtest"))
        .env("NGINX_BIN", &nginx)
        .env("USERS", users.to_string())
        .env("RATE", rate.to_string())
        .env("DURATION", "24")
        .output()
        .unwrap();
    let said = format!(
        "{}\n{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(run.status.success(), "replicas.sh failed:\n{said}");
    eprintln!("{said}");
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("report.json")).unwrap())
            .unwrap();
    let killed = std::fs::read_to_string(out.path().join("killed")).unwrap();
    let killed = killed.trim();
    let phases = r["phases"].as_array().unwrap().clone();
    let labels: Vec<&str> = phases
        .iter()
        .map(|p| p["label"].as_str().unwrap())
        .collect();
    assert_eq!(
        labels,
        [
            "start".to_string(),
            format!("kill-{killed}"),
            "add-r4".into()
        ],
        "{r}"
    );

    // Never a wrong answer, anywhere.
    assert_eq!(r["errors"], 0, "{}", r["errors_by_kind"]);
    // Before the kill, nothing is lost; every phase keeps the offered rate.
    assert_eq!(phases[0]["lost"], 0, "{phases:?}");
    for p in &phases {
        assert!(
            p["fps"].as_f64().unwrap() > 0.8 * users as f64 * rate,
            "a phase fell behind: {p}"
        );
    }

    let users_json = r["users"].as_array().unwrap();
    let on_killed = |u: &Value| {
        u["replicas"]
            .as_array()
            .unwrap()
            .iter()
            .any(|x| x == killed)
    };
    let mut hit = 0;
    for u in users_json {
        let kill_losses = u["lost_at_s"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|t| phase_of(&phases, t.as_f64().unwrap()) == labels[1])
            .count();
        // Losses at the kill: only clients of the killed replica, each one
        // frame (two at most: one in flight, one sent before it heard),
        // then a reconnect and answers again within a second.
        if kill_losses > 0 {
            hit += 1;
            assert!(
                on_killed(u),
                "a client of a surviving replica lost frames: {u}"
            );
            assert!(kill_losses <= 2, "{u}");
        }
        if u["lost"].as_u64().unwrap() > 0 {
            assert!(u["reconnects"].as_u64().unwrap() >= 1, "{u}");
            assert!(
                u["answered_after_loss"].as_u64().unwrap() > 0,
                "never recovered: {u}"
            );
            assert!(
                u["recovery_ms"].as_f64().unwrap() < 1000.0,
                "slow recovery: {u}"
            );
        }
        // Walkthrough users behind another (the first of each pair) whose
        // walkthrough never lived on the killed replica saw the one ahead
        // in nearly every frame, before and after the kill.
        let follower = u["mode"] == "walkthrough" && walkthrough_place(users_json, u) == 0;
        if follower && !on_killed(u) {
            let (saw, answered) = (
                u["saw_users"].as_f64().unwrap(),
                u["answered"].as_f64().unwrap(),
            );
            assert!(
                saw > 0.9 * answered,
                "walkthrough users stopped seeing each other: {u}"
            );
        }
    }
    assert!(hit > 0, "the kill reached no client: {r}");
    // The replica added later takes new sessions.
    let on_new = users_json
        .iter()
        .filter(|u| u["replicas"].as_array().unwrap().iter().any(|x| x == "r4"))
        .count();
    assert!(on_new > 0, "no session on the added replica: {r}");
}

/// A walkthrough user's place in its pair (0: behind, 1: ahead), as
/// loadtest deals them: walkthrough users in order, two a walkthrough.
fn walkthrough_place(users: &[Value], u: &Value) -> usize {
    let nth = users
        .iter()
        .filter(|v| v["mode"] == "walkthrough" && v["user"].as_u64() < u["user"].as_u64())
        .count();
    nth % 2
}
