//! A thin client in Rust, on `pvsd-proto` alone: it walks a scene's street
//! walk over a session's WebSocket (`x-pvs` frames with stats), fetches the
//! triangles of each object the first time it is in the set
//! (`POST /scenes/{id}/meshes`, `application/x-pvs-mesh`), and holds them in
//! a byte-bounded LRU, as the web viewer does. At the end it prints what the
//! walk cost in geometry bytes; with `--whole` it also fetches every mesh
//! of the scene to compare.
//!
//! ```text
//! pvsd gen city --buildings 10000 --seed 7 -o city10k.glb
//! pvsd serve --scene city10k.glb &
//! cargo run --release --example stream_walk -- --scene city10k --method horizon \
//!     --seconds 60 --speed 10 --whole
//! ```
//!
//! Copy it: everything a client needs is here — apply `removed` then
//! `added` to the set held for `base`, ask for what is missing, keep what
//! left the set a while, and make a new session if the server forgets
//! this one (sessions are soft state, `proto/wire-format.md`).

use std::collections::{BTreeSet, HashMap, VecDeque};
use std::time::{Duration, Instant};

use clap::Parser;
use futures_util::{SinkExt, StreamExt};
use pvsd_proto::json::{SessionCreated, WalkResponse};
use pvsd_proto::mesh::{self, Mesh};
use pvsd_proto::xpvs::{self, Message as XMessage};
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

#[derive(Parser)]
struct Args {
    /// The server.
    #[arg(long, default_value = "http://127.0.0.1:8080")]
    server: String,
    /// The scene's id.
    #[arg(long, default_value = "city")]
    scene: String,
    /// The culling method.
    #[arg(long, default_value = "auto")]
    method: String,
    /// Seconds of walking.
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// Walking speed, metres a second.
    #[arg(long, default_value_t = 10.0)]
    speed: f64,
    /// Frames a second.
    #[arg(long, default_value_t = 30.0)]
    rate: f64,
    /// Which walk (`street`, `random`, `orbit`).
    #[arg(long, default_value = "street")]
    walk: String,
    /// Most geometry held, MiB (least recently visible let go first).
    #[arg(long, default_value_t = 256)]
    budget_mib: usize,
    /// Send frames as fast as answered instead of at `rate`.
    #[arg(long)]
    unpaced: bool,
    /// Also fetch every mesh of the scene, to compare.
    #[arg(long)]
    whole: bool,
    /// The viewport.
    #[arg(long, num_args = 2, default_values_t = [1024, 640])]
    viewport: Vec<u32>,
}

/// The geometry a client holds: meshes by id, least recently visible first.
struct Held {
    meshes: HashMap<u32, Mesh>,
    order: VecDeque<u32>,
    bytes: usize,
    budget: usize,
    fetched: usize,
}

fn mesh_bytes(m: &Mesh) -> usize {
    mesh::encoded_len(&m.as_ref())
}

impl Held {
    /// Marks `visible` as just seen and lets go of the least recently seen
    /// others while over budget.
    fn touch_and_trim(&mut self, visible: &BTreeSet<u32>) {
        self.order.retain(|id| !visible.contains(id));
        self.order
            .extend(visible.iter().filter(|id| self.meshes.contains_key(id)));
        while self.bytes > self.budget {
            let Some(&oldest) = self.order.front() else {
                break;
            };
            if visible.contains(&oldest) {
                break;
            }
            self.order.pop_front();
            if let Some(m) = self.meshes.remove(&oldest) {
                self.bytes -= mesh_bytes(&m);
            }
        }
    }
}

async fn fetch_meshes(
    http: &reqwest::Client,
    args: &Args,
    ids: &[u32],
) -> anyhow::Result<(Vec<Mesh>, usize)> {
    let (mut out, mut bytes) = (Vec::new(), 0);
    // The server's default JSON array limit; a server with a lower one
    // answers 413, and the batch is halved.
    let mut size = 1024;
    let mut rest = ids;
    while !rest.is_empty() {
        let batch = &rest[..size.min(rest.len())];
        let res = http
            .post(format!("{}/scenes/{}/meshes", args.server, args.scene))
            .json(&json!({ "ids": batch }))
            .send()
            .await?;
        if res.status() == reqwest::StatusCode::PAYLOAD_TOO_LARGE && size > 1 {
            size /= 2;
            continue;
        }
        let body = res.error_for_status()?.bytes().await?;
        bytes += body.len();
        out.extend(mesh::decode(&body)?.meshes);
        rest = &rest[batch.len()..];
    }
    Ok((out, bytes))
}

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// A new session of the scene and method, and its WebSocket.
async fn open_session(
    http: &reqwest::Client,
    args: &Args,
) -> anyhow::Result<(SessionCreated, Socket)> {
    let created: SessionCreated = http
        .post(format!("{}/sessions", args.server))
        .json(&json!({ "scene": args.scene, "method": args.method }))
        .send()
        .await?
        .error_for_status()?
        .json()
        .await?;
    let url = format!(
        "{}/sessions/{}/ws?encoding=x-pvs&stats=true",
        args.server.replacen("http", "ws", 1),
        created.session
    );
    let (ws, _) = tokio_tungstenite::connect_async(url).await?;
    Ok((created, ws))
}

/// [`open_session`] again and again, waiting longer each time (a server
/// restarting takes a while), for up to a minute.
async fn reopen(http: &reqwest::Client, args: &Args) -> anyhow::Result<(SessionCreated, Socket)> {
    let mut wait = Duration::from_millis(250);
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        match open_session(http, args).await {
            Ok(opened) => return Ok(opened),
            Err(e) if Instant::now() < deadline => {
                eprintln!("no session yet ({e}); again in {wait:?}");
                tokio::time::sleep(wait).await;
                wait = (wait * 2).min(Duration::from_secs(4));
            }
            Err(e) => return Err(e),
        }
    }
}

/// Sends one view and reads its answer; `Err` says why the session is lost
/// (its error, a close, a broken socket).
async fn ask(ws: &mut Socket, view: &serde_json::Value) -> Result<Vec<u8>, String> {
    ws.send(Message::text(view.to_string()))
        .await
        .map_err(|e| e.to_string())?;
    match ws.next().await {
        Some(Ok(Message::Binary(b))) => Ok(b.to_vec()),
        Some(Ok(Message::Text(error))) => Err(error.to_string()),
        other => Err(format!("the socket gave {other:?}")),
    }
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let http = reqwest::Client::new();
    let frames = (args.seconds * args.rate).round().max(1.0) as usize;
    let walk: WalkResponse = http
        .get(format!(
            "{}/scenes/{}/walk?kind={}&frames={frames}&step={}",
            args.server,
            args.scene,
            args.walk,
            args.speed / args.rate
        ))
        .send()
        .await?
        .error_for_status()?
        .json()
        .await?;
    let (mut created, mut ws) = open_session(&http, &args).await?;
    let mut reconnects = 0;

    let mut visible = BTreeSet::new();
    let mut held = Held {
        meshes: HashMap::new(),
        order: VecDeque::new(),
        bytes: 0,
        budget: args.budget_mib << 20,
        fetched: 0,
    };
    let (mut frame, mut pvs_sum, mut cull_us, mut ever) = (None, 0, 0.0, BTreeSet::new());
    let start = Instant::now();
    let period = Duration::from_secs_f64(1.0 / args.rate);
    for (i, v) in walk.views.iter().enumerate() {
        if !args.unpaced {
            tokio::time::sleep_until((start + period * i as u32).into()).await;
        }
        let view = json!({
            "eye": v.eye, "forward": v.forward, "up": v.up, "fov_y_deg": v.fov_y_deg,
            "near": v.near, "far": v.far, "viewport": args.viewport, "base": frame,
        });
        let answer = match ask(&mut ws, &view).await {
            Ok(answer) => answer,
            Err(lost) => {
                // Sessions are soft state: a server that forgot this one
                // (restarted, expired it) gets a new one, whose first
                // answer is the whole set.
                eprintln!("frame {i}: {lost}; making a new session");
                (created, ws) = reopen(&http, &args).await?;
                reconnects += 1;
                let mut whole = view.clone();
                whole["base"] = serde_json::Value::Null;
                ask(&mut ws, &whole).await.map_err(anyhow::Error::msg)?
            }
        };
        let XMessage::Frame(f) = xpvs::decode(&answer)? else {
            anyhow::bail!("frame {i}: not a frame message");
        };
        if f.base.is_none() {
            visible.clear();
        }
        for id in &f.removed {
            visible.remove(id);
        }
        visible.extend(&f.added);
        frame = Some(f.frame);
        cull_us += f.stats.as_ref().map_or(0.0, |s| s.cull_us);
        let missing: Vec<u32> = visible
            .iter()
            .copied()
            .filter(|id| !held.meshes.contains_key(id))
            .collect();
        let (meshes, bytes) = fetch_meshes(&http, &args, &missing).await?;
        held.fetched += bytes;
        for m in meshes {
            held.bytes += mesh_bytes(&m);
            held.meshes.insert(m.id, m);
        }
        held.touch_and_trim(&visible);
        pvs_sum += visible.len();
        ever.extend(visible.iter().copied());
    }
    let n = walk.views.len();
    println!(
        "{n} frames of a {:.0} s {} walk at {} m/s ({:.1} s taken), method {}",
        args.seconds,
        args.walk,
        args.speed,
        start.elapsed().as_secs_f64(),
        created.method
    );
    println!(
        "mean PVS {:.1} objects, {} objects seen over the walk, mean cull {:.0} µs",
        pvs_sum as f64 / n as f64,
        ever.len(),
        cull_us / n as f64
    );
    println!(
        "geometry fetched: {} bytes; held at the end: {} bytes in {} meshes; {reconnects} reconnects",
        held.fetched,
        held.bytes,
        held.meshes.len()
    );
    if args.whole {
        let objects: Vec<serde_json::Value> = http
            .get(format!("{}/scenes/{}/objects", args.server, args.scene))
            .send()
            .await?
            .error_for_status()?
            .json()
            .await?;
        let ids: Vec<u32> = (0..objects.len() as u32).collect();
        let (_, whole) = fetch_meshes(&http, &args, &ids).await?;
        println!(
            "every mesh of the scene: {whole} bytes; the walk fetched {:.2}% of it",
            100.0 * held.fetched as f64 / whole as f64
        );
    }
    Ok(())
}
