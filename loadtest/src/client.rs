//! One virtual user: a walk, a way of asking (session, stateless,
//! WebSocket) and a schedule (closed or open loop). Answers come as
//! `application/x-pvs`; each is decoded and, for sessions, applied to the
//! set the user holds.

use std::fmt::Write as _;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use pvsd_proto::json::{Bounds, FrameResponse, SessionCreated, UserJoined};
use pvsd_proto::xpvs::{self, Message as PvsMessage};
use serde_json::{Map, Value, json};
use tokio_tungstenite::tungstenite::Message;

use crate::stats::{Recorder, UserRecorder};
use crate::walk::{Pose, Walk, WalkKind};

/// How frames are asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// `POST /sessions/{sid}/frames`: deltas.
    Session,
    /// `POST /scenes/{id}/visible`: whole sets, no server state.
    Stateless,
    /// `GET /sessions/{sid}/ws`: deltas over a WebSocket.
    Ws,
    /// Users in walkthroughs of `--group` users each, following one
    /// another along one path, frames by `POST /sessions/{sid}/frames`;
    /// `users_visible` is counted.
    Walkthrough,
}

/// What every user does.
pub struct Plan {
    /// Server base URL, no trailing slash.
    pub target: String,
    /// Scene id.
    pub scene: String,
    /// Method name.
    pub method: String,
    /// Method options.
    pub options: Map<String, Value>,
    /// How each user asks: user `u` takes `modes[u % modes.len()]`.
    pub modes: Vec<Mode>,
    /// Walkthrough mode: the walkthroughs, one per group of users.
    pub walkthroughs: Vec<String>,
    /// Walkthrough mode: users per walkthrough.
    pub group: u32,
    /// Frames a second per user (open loop), or `None` (closed loop).
    pub rate: Option<f64>,
    /// Open loop: requests a user has in flight at most.
    pub max_in_flight: usize,
    /// Path kind.
    pub walk: WalkKind,
    /// Metres per frame.
    pub step: f64,
    /// Session mode: frames after which a user's session is replaced by
    /// a new one (0: never).
    pub churn: u64,
    /// The region each answer is asked valid for; a user keeps its answer
    /// while it stays inside.
    pub region: Region,
    /// The scene's bounds.
    pub bounds: Bounds,
    /// When to stop sending.
    pub end: Instant,
}

impl Plan {
    /// How user `u` asks.
    pub fn mode(&self, u: u32) -> Mode {
        self.modes[u as usize % self.modes.len()]
    }

    /// Walkthrough mode: user `u`'s walkthrough (its index) and place in
    /// it.
    fn walkthrough_of(&self, u: u32) -> Option<(usize, u32)> {
        let nth = walker(&self.modes, u)?;
        Some(((nth / self.group) as usize, nth % self.group))
    }

    /// Walkthroughs needed for `users` users.
    pub fn groups(modes: &[Mode], users: u32, group: u32) -> u32 {
        let walkers = (0..users).filter_map(|u| walker(modes, u)).count() as u32;
        walkers.div_ceil(group)
    }
}

/// How many walkthrough users come before user `u`, if `u` is one.
fn walker(modes: &[Mode], u: u32) -> Option<u32> {
    let mode = |v: u32| modes[v as usize % modes.len()];
    (mode(u) == Mode::Walkthrough)
        .then(|| (0..u).filter(|&v| mode(v) == Mode::Walkthrough).count() as u32)
}

/// The body that makes a session or a walkthrough (and remakes a lost
/// walkthrough when a user rejoins it).
fn session_body(plan: &Plan) -> Value {
    json!({"scene": plan.scene, "method": plan.method, "options": plan.options})
}

/// Makes a walkthrough of the plan's scene and method; its id.
pub async fn create_walkthrough(plan: &Plan, http: &reqwest::Client) -> anyhow::Result<String> {
    let res = http
        .post(format!("{}/walkthroughs", plan.target))
        .json(&session_body(plan))
        .send()
        .await?;
    anyhow::ensure!(
        res.status().is_success(),
        "POST /walkthroughs answered {}: {}",
        res.status(),
        res.text().await.unwrap_or_default()
    );
    let made: pvsd_proto::json::WalkthroughCreated = res.json().await?;
    Ok(made.walkthrough)
}

/// `occlusion_tree:k=32` → (`occlusion_tree`, `{"k": "32"}`).
pub fn method_json(spec: &str) -> (String, Map<String, Value>) {
    let mut parts = spec.split(':');
    let name = parts.next().unwrap_or("auto").to_string();
    let options = parts
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.to_string(), Value::String(v.to_string())))
        .collect();
    (name, options)
}

/// The set a user holds, rebuilt from frames.
#[derive(Default)]
struct Held {
    frame: Option<u64>,
    /// Bit `id` set for each id held: O(1) per change, so checking the
    /// chain costs the load generator (on the server's cores) little.
    ids: Vec<u64>,
}

impl Held {
    /// Adds `id`; false when it was held already.
    fn insert(&mut self, id: u32) -> bool {
        let (w, bit) = (id as usize >> 6, 1u64 << (id & 63));
        if w >= self.ids.len() {
            self.ids.resize(w + 1, 0);
        }
        let new = self.ids[w] & bit == 0;
        self.ids[w] |= bit;
        new
    }

    /// Drops `id`; false when it was not held.
    fn remove(&mut self, id: u32) -> bool {
        let (w, bit) = (id as usize >> 6, 1u64 << (id & 63));
        match self.ids.get_mut(w) {
            Some(word) if *word & bit != 0 => {
                *word &= !bit;
                true
            }
            _ => false,
        }
    }
}

impl Held {
    /// Applies a frame; an older frame than the one held (answers
    /// overtaking each other in open loop) is skipped.
    fn apply(&mut self, f: &FrameResponse) -> Result<(), &'static str> {
        if self.frame.is_some_and(|held| f.frame <= held) {
            return Ok(());
        }
        match f.base {
            None => self.ids.fill(0),
            Some(b) if Some(b) == self.frame => {}
            // The answer was made against a frame this user has since
            // replaced (open loop): it cannot be applied, nor is it wrong.
            Some(b) if self.frame.is_some_and(|held| b < held) => return Ok(()),
            Some(_) => return Err("delta_base"),
        }
        for &id in &f.removed {
            if !self.remove(id) {
                return Err("delta_removes_unheld");
            }
        }
        for &id in &f.added {
            if !self.insert(id) {
                return Err("delta_adds_held");
            }
        }
        self.frame = Some(f.frame);
        Ok(())
    }
}

/// The region a user asks its answers valid for (`--radius`, `--angle`).
#[derive(Clone, Copy, Debug, Default)]
pub struct Region {
    radius: f64,
    angle: f64,
}

impl Region {
    /// A region of `radius` metres and `angle` degrees.
    pub fn new(radius: f64, angle: f64) -> Region {
        Region { radius, angle }
    }

    /// The request fields (`,"radius":…,"angle":…`), empty for a point.
    fn fields(&self) -> String {
        if self.radius == 0.0 && self.angle == 0.0 {
            return String::new();
        }
        format!(r#","radius":{},"angle":{}"#, self.radius, self.angle)
    }

    /// Whether an answer asked for at `asked` still holds at `pose`: the
    /// eye within the radius, the camera frame (up +Y, as the server
    /// takes it) turned by at most the angle — the rotation between the
    /// two frames, roll included, as the server's region is defined.
    fn holds(&self, asked: Option<Pose>, pose: Pose) -> bool {
        if self.radius == 0.0 && self.angle == 0.0 {
            return false;
        }
        let Some((eye, forward)) = asked else {
            return false;
        };
        let e = pose.0;
        let dist =
            ((e[0] - eye[0]).powi(2) + (e[1] - eye[1]).powi(2) + (e[2] - eye[2]).powi(2)).sqrt();
        let (Some(a), Some(b)) = (frame(forward), frame(pose.1)) else {
            return false;
        };
        let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        let trace = dot(a[0], b[0]) + dot(a[1], b[1]) + dot(a[2], b[2]);
        let turn = ((trace - 1.0) * 0.5).clamp(-1.0, 1.0).acos().to_degrees();
        // Slightly inside both, so that rounding never keeps an answer a
        // step too long.
        dist <= self.radius * (1.0 - 1e-9) && turn <= self.angle * (1.0 - 1e-9)
    }
}

/// The camera frame (right, up, forward) of a forward direction with +Y
/// up; `None` for a zero or vertical forward.
fn frame(f: [f64; 3]) -> Option<[[f64; 3]; 3]> {
    let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
    if !n.is_finite() || n <= 0.0 {
        return None;
    }
    let f = [f[0] / n, f[1] / n, f[2] / n];
    // right = f × +Y
    let r = [-f[2], 0.0, f[0]];
    let rn = (r[0] * r[0] + r[2] * r[2]).sqrt();
    if rn < 1e-9 {
        return None;
    }
    let r = [r[0] / rn, 0.0, r[2] / rn];
    // up = right × f
    let u = [
        r[1] * f[2] - r[2] * f[1],
        r[2] * f[0] - r[0] * f[2],
        r[0] * f[1] - r[1] * f[0],
    ];
    Some([r, u, f])
}

/// A view body: the pose, then `extra` (`,"key":value…`, or empty).
/// Written straight into a string: the generator shares the server's
/// cores, so it builds no JSON tree per frame.
fn view(pose: ([f64; 3], [f64; 3]), extra: &str) -> String {
    let ([x, y, z], [fx, fy, fz]) = pose;
    let mut body = String::with_capacity(160 + extra.len());
    write!(
        body,
        r#"{{"eye":[{x},{y},{z}],"forward":[{fx},{fy},{fz}],"viewport":[1024,768]{extra}}}"#
    )
    .expect("writing to a String");
    body
}

/// Runs user `u` until the plan's end.
pub async fn user(u: u32, plan: Arc<Plan>, http: reqwest::Client, rec: Arc<Recorder>) {
    let mode = plan.mode(u);
    let rec = UserRecorder::new(rec, u, mode);
    // A walkthrough's users walk one path, each `LAG` frames behind the
    // next: the ones behind see the ones ahead.
    const LAG: u32 = 4;
    let walkthrough = plan.walkthrough_of(u);
    let walk = match walkthrough {
        Some((group, place)) => {
            let seed = 10_001 + group as u64;
            let mut walk = Walk::new(plan.walk, &plan.bounds, seed, plan.step);
            for _ in 0..place * LAG {
                walk.next_pose();
            }
            walk
        }
        None => Walk::new(plan.walk, &plan.bounds, u64::from(u) + 1, plan.step),
    };
    let origin = match walkthrough.and_then(|(group, _)| plan.walkthroughs.get(group)) {
        Some(wid) => Origin::Walkthrough(wid.clone()),
        None => Origin::Session,
    };
    let session = match mode {
        Mode::Stateless => None,
        Mode::Session | Mode::Ws | Mode::Walkthrough => {
            match origin.create(&plan, &http, &rec).await {
                Ok(sid) => Some(Arc::new(SessionLink::new(&plan, origin, sid))),
                Err(kind) => {
                    rec.error(kind);
                    return;
                }
            }
        }
    };
    // Open loop: users keep the same rate at different phases, spread by
    // the golden ratio, as independent clients are; in step, all of them
    // would arrive in one burst per period.
    let phase = plan
        .rate
        .map_or(0.0, |r| (f64::from(u) * 0.618_033_988_75).fract() / r);
    let start = Instant::now() + Duration::from_secs_f64(phase);
    match (mode, &session) {
        (Mode::Ws, Some(link)) => ws_user(&plan, link, walk, start, &http, &rec).await,
        _ => http_user(&plan, session.clone(), walk, start, &http, &rec).await,
    }
    if let Some(link) = session {
        let _ = http
            .delete(format!("{}/sessions/{}", plan.target, link.sid()))
            .send()
            .await;
    }
}

/// Where a user's sessions come from.
enum Origin {
    /// `POST /sessions`.
    Session,
    /// `POST /walkthroughs/{wid}/users`, with the scene and method so that
    /// a walkthrough lost with its replica is made again.
    Walkthrough(String),
}

impl Origin {
    /// A new session; notes the replica that made it.
    async fn create(
        &self,
        plan: &Plan,
        http: &reqwest::Client,
        rec: &UserRecorder,
    ) -> Result<String, &'static str> {
        let url = match self {
            Origin::Session => format!("{}/sessions", plan.target),
            Origin::Walkthrough(wid) => format!("{}/walkthroughs/{wid}/users", plan.target),
        };
        let res = http
            .post(url)
            .json(&session_body(plan))
            .send()
            .await
            .map_err(|_| "create_session")?;
        if !res.status().is_success() {
            return Err("create_session");
        }
        rec.replica(res.headers());
        let sid = match self {
            Origin::Session => {
                let created: SessionCreated = res.json().await.map_err(|_| "create_session")?;
                created.session
            }
            Origin::Walkthrough(_) => {
                let joined: UserJoined = res.json().await.map_err(|_| "create_session")?;
                joined.session
            }
        };
        Ok(sid)
    }
}

/// A user's session, made again when the server has lost it: pvsd's
/// sessions are soft state (`proto/scale-out.md`), so a frame answered
/// `404 unknown_session`, `410`, a proxy's `502`/`504`, or not at all
/// (the replica is gone) means: make a new session (or rejoin the
/// walkthrough) and go on; its first frame is the whole set.
struct SessionLink {
    origin: Origin,
    /// The session's generation (0 for the first) and its frames' URL.
    current: Mutex<(u64, String, reqwest::Url)>,
    /// One renewal at a time, and not more often than every 100 ms while
    /// the server is away.
    renewing: tokio::sync::Mutex<Option<Instant>>,
}

impl SessionLink {
    fn new(plan: &Plan, origin: Origin, sid: String) -> SessionLink {
        let url = Self::frames_url(plan, &sid);
        SessionLink {
            origin,
            current: Mutex::new((0, sid, url)),
            renewing: tokio::sync::Mutex::new(None),
        }
    }

    fn frames_url(plan: &Plan, sid: &str) -> reqwest::Url {
        reqwest::Url::parse(&format!("{}/sessions/{sid}/frames", plan.target))
            .expect("the target was parsed before")
    }

    fn sid(&self) -> String {
        self.current.lock().unwrap().1.clone()
    }

    /// The generation and URL frames go to now.
    fn url(&self) -> (u64, reqwest::Url) {
        let c = self.current.lock().unwrap();
        (c.0, c.2.clone())
    }

    /// Ends the session and makes a new one, as a user leaving and another
    /// joining would; the user's held set starts over.
    async fn churn(
        &self,
        plan: &Plan,
        http: &reqwest::Client,
        held: &Mutex<Held>,
        rec: &UserRecorder,
    ) {
        let _guard = self.renewing.lock().await;
        let old = self.sid();
        let _ = http
            .delete(format!("{}/sessions/{old}", plan.target))
            .send()
            .await;
        // A failed make (the replica went away as the user left) is not
        // counted: the next frame finds the old session gone and the user
        // makes a new one (soft state).
        if let Ok(sid) = self.origin.create(plan, http, rec).await {
            let url = Self::frames_url(plan, &sid);
            let mut c = self.current.lock().unwrap();
            *c = (c.0 + 1, sid, url);
            *held.lock().unwrap() = Held::default();
            rec.churned();
        }
    }

    /// Makes a new session if generation `seen` is still the current one;
    /// the user's held set starts over. True when the current session is
    /// newer than `seen` afterwards.
    async fn renew(
        &self,
        seen: u64,
        plan: &Plan,
        http: &reqwest::Client,
        held: &Mutex<Held>,
        rec: &UserRecorder,
    ) -> bool {
        let mut last = self.renewing.lock().await;
        if self.current.lock().unwrap().0 != seen {
            return true;
        }
        if last.is_some_and(|t| t.elapsed() < Duration::from_millis(100)) {
            return false;
        }
        *last = Some(Instant::now());
        let Ok(sid) = self.origin.create(plan, http, rec).await else {
            return false;
        };
        let url = Self::frames_url(plan, &sid);
        *self.current.lock().unwrap() = (seen + 1, sid, url);
        *held.lock().unwrap() = Held::default();
        rec.reconnect();
        true
    }
}

/// When frame `k` is due: on the schedule (open loop) or now (closed);
/// `None` once past the end.
async fn due(plan: &Plan, start: Instant, k: u64) -> Option<Instant> {
    let due = match plan.rate {
        Some(r) => {
            let due = start + Duration::from_secs_f64(k as f64 / r);
            tokio::time::sleep_until(due.into()).await;
            due
        }
        None => Instant::now(),
    };
    (due < plan.end).then_some(due)
}

/// Whether a WebSocket text message is the server saying the session
/// ended (`{"error": {"code": "unknown_session" | "session_expired" |
/// "session_evicted", …}}`).
fn ended_session(text: &str) -> bool {
    serde_json::from_str::<Value>(text).is_ok_and(|v| {
        matches!(
            v["error"]["code"].as_str(),
            Some("unknown_session" | "session_expired" | "session_evicted")
        )
    })
}

/// Whether a failed frame means its session (or the replica holding it)
/// is gone, which a new session mends: soft state, not an error.
fn session_lost(kind: &str) -> bool {
    matches!(
        kind,
        "http_404" | "http_410" | "http_502" | "http_504" | "connect" | "read" | "ws_closed"
    )
}

async fn http_user(
    plan: &Arc<Plan>,
    session: Option<Arc<SessionLink>>,
    mut walk: Walk,
    start: Instant,
    http: &reqwest::Client,
    rec: &UserRecorder,
) {
    // Parsed once: reqwest would parse a string on every request.
    let Ok(stateless) =
        reqwest::Url::parse(&format!("{}/scenes/{}/visible", plan.target, plan.scene))
    else {
        rec.error("bad_target");
        return;
    };
    let method = match session {
        Some(_) => plan.region.fields(),
        None => format!(
            r#","method":{},"options":{}{}"#,
            json!(plan.method),
            Value::Object(plan.options.clone()),
            plan.region.fields()
        ),
    };
    // The pose of the last frame sent, whose answer holds within the
    // region; forgotten when that frame fails, so the next one asks again.
    let asked: Arc<Mutex<Option<Pose>>> = Arc::new(Mutex::new(None));
    let held = Arc::new(Mutex::new(Held::default()));
    // Open loop: at most `max_in_flight` requests (connections) per user;
    // later frames wait their turn, as a browser queues past its
    // connections per host, and their latency still counts from when they
    // were due. Unbounded, a stall made each late frame open a connection
    // of its own (thousands), and the server drowned in handshakes.
    let slots = Arc::new(tokio::sync::Semaphore::new(plan.max_in_flight));
    let mut in_flight = Vec::new();
    for k in 0.. {
        let Some(due) = due(plan, start, k).await else {
            break;
        };
        if let Some(link) = &session
            && plan.churn > 0
            && k > 0
            && k % plan.churn == 0
        {
            // A user leaving waits for its frames in flight, as a client
            // closing a view would, so none is answered by a session it
            // has already ended.
            let all = plan.max_in_flight as u32;
            let Ok(_idle) = slots.acquire_many(all).await else {
                break;
            };
            link.churn(plan, http, &held, rec).await;
        }
        let pose = walk.next_pose();
        if plan.region.holds(*asked.lock().unwrap(), pose) {
            rec.kept();
            continue;
        }
        *asked.lock().unwrap() = Some(pose);
        let asked = asked.clone();
        let (http, stateless, method) = (http.clone(), stateless.clone(), method.clone());
        let (held, rec, slots) = (held.clone(), rec.clone(), slots.clone());
        let (session, shared_plan) = (session.clone(), plan.clone());
        let exchange = async move {
            let Ok(_slot) = slots.acquire_owned().await else {
                return;
            };
            let (generation, url) = session.as_ref().map_or((0, stateless), |s| s.url());
            // The base is read when the frame is sent, not when it was due.
            let held_frame = held.lock().unwrap().frame;
            // A user holding nothing yet names base 0, never a frame, so
            // that each answer until its first arrives is a whole set: with
            // no base the server would answer a delta against a frame
            // still on its way to the user.
            let body = match (held_frame, &session) {
                (Some(b), Some(_)) => view(pose, &format!(r#","base":{b}{method}"#)),
                (None, Some(_)) => view(pose, &format!(r#","base":0{method}"#)),
                (_, None) => view(pose, &method),
            };
            let sent = body.len();
            let request = http
                .post(url)
                .header("accept", xpvs::CONTENT_TYPE)
                .header("content-type", "application/json")
                .body(body);
            let answer = match request.send().await {
                Ok(res) if res.status().is_success() => {
                    rec.replica(res.headers());
                    res.bytes().await.map_err(|_| "read")
                }
                Ok(res) => Err(status_kind(res.status().as_u16())),
                Err(e) if e.is_timeout() => Err("timeout"),
                Err(_) => Err("connect"),
            };
            // An answer of a session the user has since replaced (the
            // server lost it) belongs to no set the user holds now.
            let stale = || session.as_ref().is_some_and(|s| s.url().0 != generation);
            let checked = answer.and_then(|b| {
                if stale() {
                    return Ok((b.len(), 0, false));
                }
                check(&b, session.is_some(), &held).map(|users| (b.len(), users, true))
            });
            if checked.is_err() {
                let mut a = asked.lock().unwrap();
                if *a == Some(pose) {
                    *a = None;
                }
            }
            match checked {
                Ok((n, users, current)) => rec.ok(due.elapsed(), sent, n, users, current),
                Err(kind) => match &session {
                    Some(link) if session_lost(kind) => {
                        rec.lost(kind);
                        let renewed = link
                            .renew(generation, &shared_plan, &http, &held, &rec)
                            .await;
                        if !renewed {
                            // The server is away: wait before the next
                            // frame rather than spin on a dead session.
                            tokio::time::sleep(Duration::from_millis(100)).await;
                        }
                    }
                    _ => rec.error(kind),
                },
            }
        };
        if plan.rate.is_some() {
            in_flight.push(tokio::spawn(exchange));
            in_flight.retain(|t| !t.is_finished());
        } else {
            exchange.await;
        }
    }
    for t in in_flight {
        let _ = t.await;
    }
}

fn status_kind(status: u16) -> &'static str {
    match status {
        404 => "http_404",
        410 => "http_410",
        400..=499 => "http_4xx",
        300..=399 => "http_3xx",
        502 => "http_502",
        503 => "http_503",
        504 => "http_504",
        _ => "http_5xx",
    }
}

/// Decodes an answer and, for a session, applies it; the number of other
/// users it says are visible (walkthroughs).
fn check(bytes: &[u8], session: bool, held: &Mutex<Held>) -> Result<usize, &'static str> {
    match (xpvs::decode(bytes).map_err(|_| "decode")?, session) {
        (PvsMessage::Frame(f), true) => held
            .lock()
            .unwrap()
            .apply(&f)
            .map(|()| f.users_visible.as_ref().map_or(0, Vec::len)),
        (PvsMessage::Visible(_), false) => Ok(0),
        _ => Err("decode"),
    }
}

/// A WebSocket user: a socket on its session; when the socket dies (the
/// replica went away) the frames on it are lost, and the user makes a new
/// session and a new socket and walks on.
async fn ws_user(
    plan: &Arc<Plan>,
    link: &SessionLink,
    mut walk: Walk,
    start: Instant,
    http: &reqwest::Client,
    rec: &UserRecorder,
) {
    let mut k = 0;
    let held = Mutex::new(Held::default());
    loop {
        let (generation, _) = link.url();
        let url = format!(
            "{}/sessions/{}/ws?encoding=x-pvs",
            plan.target.replacen("http", "ws", 1),
            link.sid()
        );
        // A connection the server never answers is given up on (and a
        // new session made) rather than waited for past the run's end.
        let connecting = tokio_tungstenite::connect_async(&url);
        if let Ok(Ok((socket, response))) =
            tokio::time::timeout(Duration::from_secs(5), connecting).await
        {
            rec.replica(response.headers());
            let ended = ws_frames(plan, socket, &mut walk, start, &mut k, rec).await;
            if ended {
                return;
            }
        }
        // The socket died before the run's end: a new session, a new
        // socket (retried while the server is away, until the end).
        while !link.renew(generation, plan, http, &held, rec).await {
            if Instant::now() >= plan.end {
                return;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

/// Walks on one socket from frame `k` until the run's end (true) or until
/// the socket dies (false, its unanswered frames counted lost).
async fn ws_frames(
    plan: &Arc<Plan>,
    socket: tokio_tungstenite::WebSocketStream<
        tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>,
    >,
    walk: &mut Walk,
    start: Instant,
    k: &mut u64,
    rec: &UserRecorder,
) -> bool {
    let (mut tx, mut rx) = socket.split();
    // Due times of frames sent and not yet answered, in order: the server
    // answers a socket's frames in the order they were sent.
    let (dues_tx, mut dues_rx) = tokio::sync::mpsc::unbounded_channel::<(Instant, usize)>();
    // Closed loop: the reader says when an answer is in.
    let (answered_tx, mut answered_rx) = tokio::sync::mpsc::channel::<()>(1);
    let reader = {
        let rec = rec.clone();
        tokio::spawn(async move {
            // A new socket is a new session: its first frame is whole.
            let held = Mutex::new(Held::default());
            while let Some((due, sent)) = dues_rx.recv().await {
                // Pings are no answers (tungstenite answers them itself).
                let got = loop {
                    match tokio::time::timeout(Duration::from_secs(30), rx.next()).await {
                        Ok(Some(Ok(Message::Ping(_) | Message::Pong(_)))) => continue,
                        other => break other,
                    }
                };
                let bytes = match got {
                    Ok(Some(Ok(Message::Binary(b)))) => Some(b),
                    // The server ended the session (it says why, then
                    // closes) or is shutting down (`1001`): soft state.
                    Ok(Some(Ok(Message::Text(t)))) if ended_session(&t) => None,
                    // Another error message, or a raw frame: no answer
                    // (`decode` below names it).
                    Ok(Some(Ok(Message::Text(_) | Message::Frame(_)))) => Some(Default::default()),
                    // Closed (`1001` at shutdown, `1008` with a reason) or
                    // dropped (the replica died).
                    Ok(_) => None,
                    Err(_) => {
                        rec.error("timeout");
                        return false;
                    }
                };
                let Some(bytes) = bytes else {
                    // This frame and every one queued behind it.
                    rec.lost("ws_closed");
                    while dues_rx.try_recv().is_ok() {
                        rec.lost("ws_closed");
                    }
                    return false;
                };
                match check(&bytes, true, &held) {
                    Ok(users) => rec.ok(due.elapsed(), sent, bytes.len(), users, true),
                    // Not a frame (an error message, an empty one):
                    // `decode` names it.
                    Err(kind) => rec.error(kind),
                }
                let _ = answered_tx.try_send(());
            }
            true
        })
    };
    let mut ended = true;
    let fields = plan.region.fields();
    let mut asked: Option<Pose> = None;
    loop {
        let Some(due) = due(plan, start, *k).await else {
            break;
        };
        let pose = walk.next_pose();
        if plan.region.holds(asked, pose) {
            rec.kept();
            *k += 1;
            continue;
        }
        asked = Some(pose);
        let text = view(pose, &fields);
        let sent = text.len();
        // Queued before it is sent, so a fast answer finds its due time.
        if dues_tx.send((due, sent)).is_err() {
            ended = false;
            break;
        }
        *k += 1;
        if tx.send(Message::text(text)).await.is_err() {
            ended = false;
            break;
        }
        if plan.rate.is_none() && answered_rx.recv().await.is_none() {
            ended = false;
            break;
        }
    }
    drop(dues_tx);
    let read_all = reader.await.unwrap_or(false);
    let _ = tx.close().await;
    ended && read_all || Instant::now() >= plan.end
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(frame: u64, base: Option<u64>, added: &[u32], removed: &[u32]) -> FrameResponse {
        FrameResponse {
            frame,
            base,
            added: added.to_vec(),
            removed: removed.to_vec(),
            users_visible: None,
            stats: None,
        }
    }

    #[test]
    fn a_held_set_follows_the_chain_and_refuses_what_does_not_chain() {
        let mut held = Held::default();
        held.apply(&frame(1, None, &[3, 70, 200], &[])).unwrap();
        held.apply(&frame(2, Some(1), &[4], &[70])).unwrap();
        // A full frame starts over, whatever was held: 3 may come again.
        held.apply(&frame(3, None, &[3, 9], &[])).unwrap();
        let ids: Vec<u32> = (0..256).filter(|&id| held.remove(id)).collect();
        assert_eq!(ids, [3, 9]);
        held.apply(&frame(4, None, &[9], &[])).unwrap();
        assert_eq!(
            held.apply(&frame(5, Some(4), &[], &[10])),
            Err("delta_removes_unheld")
        );
        // A newer frame made against one already replaced (open loop):
        // skipped, neither applied nor an error.
        assert_eq!(held.apply(&frame(6, Some(2), &[9], &[])), Ok(()));
        assert!(held.remove(9) && !held.remove(9));
        let mut held = Held::default();
        held.apply(&frame(1, None, &[9], &[])).unwrap();
        assert_eq!(
            held.apply(&frame(2, Some(1), &[9], &[])),
            Err("delta_adds_held")
        );
        let mut held = Held::default();
        held.apply(&frame(5, None, &[1], &[])).unwrap();
        assert_eq!(held.apply(&frame(7, Some(6), &[], &[])), Err("delta_base"));
        // An answer older than the one held is skipped (open loop).
        assert_eq!(held.apply(&frame(4, Some(3), &[1], &[])), Ok(()));
    }

    #[test]
    fn view_bodies_are_json_the_server_reads() {
        let body = view(([1.5, -2.0, 1e7], [0.0, 0.0, 1.0]), r#","base":4"#);
        let req: pvsd_proto::json::ViewRequest = serde_json::from_str(&body).unwrap();
        assert_eq!(req.eye.unwrap().map(|n| n.0), [1.5, -2.0, 1e7]);
        assert_eq!(req.forward.unwrap().map(|n| n.0), [0.0, 0.0, 1.0]);
        assert_eq!(req.viewport, Some([1024, 768]));
        assert_eq!(req.base, Some(4));
    }
}
