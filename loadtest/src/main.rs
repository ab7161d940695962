//! `loadtest`: drives pvsd as real clients do. Each virtual user walks a
//! smooth path through a scene (made from the scene's bounds in `GET
//! /scenes`) and asks for each frame's visible set: through a session and
//! its deltas (`--mode session`, the default), statelessly
//! (`--mode stateless`), over a session's WebSocket (`--mode ws`), or as
//! users of shared walkthroughs (`--mode walkthrough`); `--mode
//! session,ws,walkthrough` mixes them. It rebuilds the visible set from the
//! answers and counts any answer that does not decode or does not chain as
//! an error. A session the server lost (a replica gone) is made again and
//! counted: frames lost, reconnects, per user and, with `--marks`, per
//! phase of the run (`proto/scale-out.md`).
//!
//! Without `--rate` each user sends its next frame when the last answer is
//! in (closed loop: measures capacity). With `--rate R` each user sends R
//! frames a second on a fixed schedule whether or not answers came back
//! (open loop), and latency is counted from when a frame was *due*, so a
//! server that falls behind shows it (no coordinated omission).

mod client;
mod stats;
mod walk;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::Parser;
use pvsd_proto::json::SceneInfo;

use client::{Mode, Plan};
use stats::Recorder;
use walk::WalkKind;

/// Walkthrough load generator for pvsd.
#[derive(Debug, Parser)]
#[command(version)]
struct Args {
    /// The server, e.g. http://127.0.0.1:8080.
    #[arg(long)]
    target: String,
    /// Scene id (as in GET /scenes).
    #[arg(long)]
    scene: String,
    /// Virtual users.
    #[arg(long, default_value_t = 16)]
    users: u32,
    /// Seconds to run.
    #[arg(long, default_value_t = 10.0)]
    duration: f64,
    /// Culling method with its options, e.g. frustum or occlusion_tree:k=32.
    #[arg(long, default_value = "frustum")]
    method: String,
    /// Frames a second per user, on a fixed schedule (open loop); without
    /// it each user sends as fast as answers come (closed loop).
    #[arg(long)]
    rate: Option<f64>,
    /// With --rate: requests (so connections) a user has in flight at
    /// most; later frames queue in the user and count their wait.
    #[arg(long, default_value_t = 4)]
    max_in_flight: usize,
    /// How frames are asked for; several, comma-separated, are dealt to
    /// the users in turn.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "session")]
    mode: Vec<Mode>,
    /// Walkthrough mode: users per walkthrough.
    #[arg(long, default_value_t = 4)]
    group: u32,
    /// A file of marks written while the run goes on, one `<unix ms>
    /// <label>` a line (e.g. when a replica was killed): the report splits
    /// the run into phases at them.
    #[arg(long)]
    marks: Option<PathBuf>,
    /// The kind of path each user walks.
    #[arg(long, value_enum, default_value_t = WalkKind::Street)]
    walk: WalkKind,
    /// Metres a user moves per frame.
    #[arg(long, default_value_t = 0.5)]
    step: f64,
    /// Walking speed, metres a second: with it each user moves
    /// `speed / rate` metres a frame (`--rate` defaults to 30 then),
    /// instead of `--step`.
    #[arg(long)]
    speed: Option<f64>,
    /// Ask for answers valid within this many metres of the eye: a user
    /// keeps its last answer (sends nothing) while its eye stays within
    /// the radius of the eye it asked for and its direction within
    /// `--angle`, and the report says how many frames that saved.
    #[arg(long, default_value_t = 0.0)]
    radius: f64,
    /// With `--radius` (or alone): answers valid within this many degrees
    /// of the direction asked for.
    #[arg(long, default_value_t = 0.0)]
    angle: f64,
    /// Session mode: each user ends its session and makes a new one every
    /// this many frames (users leaving and joining); 0: one session each.
    #[arg(long, default_value_t = 0)]
    churn: u64,
    /// Write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if args.users == 0 || !positive(args.duration) || !positive(args.step) {
        bail!("--users, --duration and --step must be > 0");
    }
    if args.max_in_flight == 0 {
        bail!("--max-in-flight must be at least 1");
    }
    if args.group == 0 {
        bail!("--group must be at least 1");
    }
    if args.rate.is_some_and(|r| !positive(r)) {
        bail!("--rate must be a number of frames per second > 0");
    }
    if args.speed.is_some_and(|v| !positive(v)) {
        bail!("--speed must be metres a second > 0");
    }
    if !(args.radius.is_finite() && args.radius >= 0.0) {
        bail!("--radius must be metres ≥ 0");
    }
    if !(args.angle.is_finite() && (0.0..=180.0).contains(&args.angle)) {
        bail!("--angle must be degrees in [0, 180]");
    }
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?
        .block_on(run(args))
}

async fn run(mut args: Args) -> anyhow::Result<()> {
    if let Some(speed) = args.speed {
        let rate = *args.rate.get_or_insert(30.0);
        args.step = speed / rate;
    }
    let target = args.target.trim_end_matches('/').to_string();
    let http = reqwest::Client::builder()
        // Room to keep every connection a user may have open (one per
        // request in flight): a pool that closes the extras after a burst
        // reopens them at the next, and the closed ones wait out TIME_WAIT
        // until the machine runs out of ports.
        .pool_max_idle_per_host(args.users as usize * args.max_in_flight.max(2))
        .timeout(Duration::from_secs(30))
        // Below pvsd's header timeout (10 s by default), which also closes
        // idle keep-alive connections: the client lets an idle connection
        // go first, rather than send on one the server is closing.
        .pool_idle_timeout(Duration::from_secs(5))
        // pvsd never redirects; following redirects costs every request.
        .redirect(reqwest::redirect::Policy::none())
        .build()?;
    let scenes: Vec<SceneInfo> = http
        .get(format!("{target}/scenes"))
        .send()
        .await
        .with_context(|| format!("cannot reach {target}"))?
        .error_for_status()?
        .json()
        .await
        .context("GET /scenes is not a list of scenes")?;
    let Some(scene) = scenes.iter().find(|s| s.id == args.scene) else {
        let ids: Vec<&str> = scenes.iter().map(|s| s.id.as_str()).collect();
        bail!(
            "no scene '{}' on {target}; it serves: {}",
            args.scene,
            ids.join(", ")
        );
    };
    let bounds = scene
        .bounds
        .clone()
        .with_context(|| format!("scene '{}' has no geometry to walk through", scene.id))?;
    let (method, options) = client::method_json(&args.method);
    let recorder = Arc::new(Recorder::with_samples(args.marks.is_some()));
    let started_unix = std::time::SystemTime::now();
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(args.duration);
    let mut plan = Plan {
        target: target.clone(),
        scene: args.scene.clone(),
        method,
        options,
        modes: args.mode.clone(),
        walkthroughs: Vec::new(),
        group: args.group,
        rate: args.rate,
        max_in_flight: args.max_in_flight,
        walk: args.walk,
        step: args.step,
        churn: args.churn,
        region: client::Region::new(args.radius, args.angle),
        bounds,
        end,
    };
    for _ in 0..Plan::groups(&args.mode, args.users, args.group) {
        let wid = client::create_walkthrough(&plan, &http).await?;
        plan.walkthroughs.push(wid);
    }
    let plan = Arc::new(plan);
    let users: Vec<_> = (0..args.users)
        .map(|u| {
            tokio::spawn(client::user(
                u,
                plan.clone(),
                http.clone(),
                recorder.clone(),
            ))
        })
        .collect();
    let progress = {
        let recorder = recorder.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval_at(
                tokio::time::Instant::now() + Duration::from_secs(1),
                Duration::from_secs(1),
            );
            let mut last = 0;
            loop {
                tick.tick().await;
                let (requests, errors, lost, reconnects, p99) = recorder.progress();
                eprintln!(
                    "{:>4.0} s  {:>7} frames/s  p99 so far {:>8.3} ms  errors {}  lost {}  reconnects {}",
                    start.elapsed().as_secs_f64(),
                    requests - last,
                    p99,
                    errors,
                    lost,
                    reconnects
                );
                last = requests;
            }
        })
    };
    for u in users {
        u.await?;
    }
    progress.abort();
    let config = serde_json::json!({
        "target": target, "scene": args.scene, "users": args.users,
        "duration": args.duration, "method": args.method, "rate": args.rate,
        "max_in_flight": args.max_in_flight, "mode": args.mode, "group": args.group, "walk": args.walk, "step": args.step, "churn": args.churn,
        "speed": args.speed, "radius": args.radius, "angle": args.angle,
    });
    let elapsed = start.elapsed();
    let mut report = recorder.report(elapsed, config);
    if let Some(path) = &args.marks {
        let marks = read_marks(path, started_unix)?;
        report.phases = recorder.phases(&marks, elapsed.as_secs_f64());
    }
    print!("{}", report.table());
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&report)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// The marks file: `<unix ms> <label>` a line, as seconds into the run
/// that started at `started`; a missing file is no marks.
fn read_marks(
    path: &std::path::Path,
    started: std::time::SystemTime,
) -> anyhow::Result<Vec<(f64, String)>> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let start_ms = started
        .duration_since(std::time::UNIX_EPOCH)
        .context("the clock is before 1970")?
        .as_secs_f64()
        * 1e3;
    let mut marks = Vec::new();
    for (n, line) in text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
    {
        let (ms, label) = line.trim().split_once(' ').unwrap_or((line.trim(), ""));
        let ms: f64 = ms.parse().with_context(|| {
            format!("{}:{}: '{ms}' is no unix time in ms", path.display(), n + 1)
        })?;
        marks.push(((ms - start_ms) / 1e3, label.trim().to_string()));
    }
    marks.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(marks)
}
