//! What a run measured: latencies in an HDR histogram (microseconds, three
//! significant digits), requests, errors and lost frames by kind, bytes;
//! each user's own counts and the replicas that served it; and, for runs
//! split into phases (`--marks`), every frame's outcome in time.
//!
//! A frame is *answered*, *lost* (its session or the replica holding it
//! went away: soft state, mended by a new session, counted as a
//! reconnect), or an *error* (an answer that does not decode or chain, an
//! unexpected status, a timeout): errors are what must never happen.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;
use serde::Serialize;

use crate::client::Mode;

/// Counters every user adds to.
pub struct Recorder {
    latency: Mutex<Histogram<u64>>,
    requests: AtomicU64,
    bytes_in: AtomicU64,
    bytes_out: AtomicU64,
    errors: Mutex<BTreeMap<String, u64>>,
    reconnects: AtomicU64,
    churned: AtomicU64,
    kept: AtomicU64,
    lost: Mutex<BTreeMap<String, u64>>,
    users: Mutex<BTreeMap<u32, UserStats>>,
    /// When the run started, for samples.
    start: Instant,
    /// Every frame's (ms since start, outcome, latency µs), when phases are
    /// asked for.
    samples: Option<Mutex<Vec<(f64, Outcome, u64)>>>,
}

/// What became of one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Outcome {
    Answered,
    Lost,
    Error,
    Reconnect,
}

/// One user's counts.
#[derive(Clone, Debug, Default, Serialize)]
pub struct UserStats {
    /// The user's number.
    pub user: u32,
    /// How it asked.
    pub mode: Option<Mode>,
    /// The replicas that answered it (`x-pvsd-replica`), in order, each
    /// listed again only after another.
    pub replicas: Vec<String>,
    /// Frames answered.
    pub answered: u64,
    /// Frames lost with a session or replica.
    pub lost: u64,
    /// Errors.
    pub errors: u64,
    /// New sessions made after a loss.
    pub reconnects: u64,
    /// Answered frames that showed at least one other user (walkthroughs).
    pub saw_users: u64,
    /// Seconds into the run of each lost frame.
    pub lost_at_s: Vec<f64>,
    /// Longest time from a lost frame to the next answered one, ms.
    pub recovery_ms: Option<f64>,
    /// Answered frames after its last loss (recovered when > 0).
    pub answered_after_loss: u64,
    #[serde(skip)]
    lost_since: Option<Instant>,
}

/// One phase of a run split by `--marks`.
#[derive(Clone, Debug, Serialize)]
pub struct Phase {
    /// The mark that starts it (`start` for the first).
    pub label: String,
    /// Seconds into the run it starts and ends.
    pub from_s: f64,
    /// End.
    pub to_s: f64,
    /// Frames answered a second.
    pub fps: f64,
    /// Latency of its answered frames, ms.
    pub p50_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
    /// Frames lost with a session or replica.
    pub lost: u64,
    /// Errors.
    pub errors: u64,
    /// Sessions made again.
    pub reconnects: u64,
}

impl Recorder {
    /// Empty counters; with `samples`, every frame's outcome is kept for
    /// [`Recorder::phases`].
    pub fn with_samples(samples: bool) -> Recorder {
        Recorder {
            samples: samples.then(|| Mutex::new(Vec::new())),
            ..Recorder::new()
        }
    }

    /// Empty counters.
    pub fn new() -> Recorder {
        Recorder {
            // 1 µs to 1 h at 3 significant digits.
            latency: Mutex::new(
                Histogram::new_with_bounds(1, 3_600_000_000, 3).expect("valid bounds"),
            ),
            requests: AtomicU64::new(0),
            bytes_in: AtomicU64::new(0),
            bytes_out: AtomicU64::new(0),
            errors: Mutex::new(BTreeMap::new()),
            reconnects: AtomicU64::new(0),
            churned: AtomicU64::new(0),
            kept: AtomicU64::new(0),
            lost: Mutex::new(BTreeMap::new()),
            users: Mutex::new(BTreeMap::new()),
            start: Instant::now(),
            samples: None,
        }
    }

    fn sample(&self, outcome: Outcome, latency_us: u64) {
        if let Some(samples) = &self.samples {
            let t = self.start.elapsed().as_secs_f64() * 1e3;
            samples.lock().unwrap().push((t, outcome, latency_us));
        }
    }

    fn user(&self, u: u32, mode: Mode, f: impl FnOnce(&mut UserStats)) {
        let mut users = self.users.lock().unwrap();
        let stats = users.entry(u).or_insert_with(|| UserStats {
            user: u,
            mode: Some(mode),
            ..UserStats::default()
        });
        f(stats);
    }

    /// One frame lost with its session or replica, by kind.
    pub fn lost(&self, kind: &str) {
        self.requests.fetch_add(1, Ordering::Relaxed);
        *self
            .lost
            .lock()
            .unwrap()
            .entry(kind.to_string())
            .or_default() += 1;
        self.sample(Outcome::Lost, 0);
    }

    /// The run split at `marks` (seconds into the run, label), each phase
    /// with its own rate, latency and losses.
    pub fn phases(&self, marks: &[(f64, String)], end_s: f64) -> Vec<Phase> {
        let Some(samples) = &self.samples else {
            return Vec::new();
        };
        let samples = samples.lock().unwrap();
        let mut bounds = vec![(0.0, "start".to_string())];
        bounds.extend(
            marks
                .iter()
                .filter(|(t, _)| *t > 0.0 && *t < end_s)
                .cloned(),
        );
        bounds.push((end_s, String::new()));
        bounds
            .windows(2)
            .map(|w| {
                let (from, to) = (w[0].0, w[1].0);
                let mut h =
                    Histogram::<u64>::new_with_bounds(1, 3_600_000_000, 3).expect("valid bounds");
                let (mut lost, mut errors, mut reconnects) = (0, 0, 0);
                for &(t, outcome, us) in samples.iter() {
                    if t < from * 1e3 || t >= to * 1e3 {
                        continue;
                    }
                    match outcome {
                        Outcome::Answered => h.record(us.clamp(1, 3_600_000_000)).expect("clamped"),
                        Outcome::Lost => lost += 1,
                        Outcome::Error => errors += 1,
                        Outcome::Reconnect => reconnects += 1,
                    }
                }
                let ms = |q: f64| h.value_at_quantile(q) as f64 / 1e3;
                Phase {
                    label: w[0].1.clone(),
                    from_s: from,
                    to_s: to,
                    fps: h.len() as f64 / (to - from).max(1e-9),
                    p50_ms: ms(0.5),
                    p99_ms: ms(0.99),
                    lost,
                    errors,
                    reconnects,
                }
            })
            .collect()
    }

    /// One answered request: its latency (from when it was due) and bytes.
    pub fn ok(&self, latency: Duration, sent: usize, received: usize) {
        self.requests.fetch_add(1, Ordering::Relaxed);
        self.bytes_out.fetch_add(sent as u64, Ordering::Relaxed);
        self.bytes_in.fetch_add(received as u64, Ordering::Relaxed);
        let us = (latency.as_micros() as u64).clamp(1, 3_600_000_000);
        self.latency
            .lock()
            .unwrap()
            .record(us)
            .expect("clamped into bounds");
        self.sample(Outcome::Answered, us);
    }

    /// One failed request, by kind (`http_404`, `connect`, `decode`, …).
    pub fn error(&self, kind: &str) {
        self.requests.fetch_add(1, Ordering::Relaxed);
        *self
            .errors
            .lock()
            .unwrap()
            .entry(kind.to_string())
            .or_default() += 1;
        self.sample(Outcome::Error, 0);
    }

    /// One session made again after the server lost it.
    pub fn reconnect(&self) {
        self.reconnects.fetch_add(1, Ordering::Relaxed);
        self.sample(Outcome::Reconnect, 0);
    }

    /// One session ended and replaced on purpose (`--churn`).
    pub fn churned(&self) {
        self.churned.fetch_add(1, Ordering::Relaxed);
    }

    /// One frame not sent: the user's last answer holds for its region.
    pub fn kept(&self) {
        self.kept.fetch_add(1, Ordering::Relaxed);
    }

    /// Requests, errors, lost frames and reconnects so far, and the p99
    /// so far in milliseconds.
    pub fn progress(&self) -> (u64, u64, u64, u64, f64) {
        let errors = self.errors.lock().unwrap().values().sum();
        let lost = self.lost.lock().unwrap().values().sum();
        let p99 = self.latency.lock().unwrap().value_at_quantile(0.99) as f64 / 1e3;
        (
            self.requests.load(Ordering::Relaxed),
            errors,
            lost,
            self.reconnects.load(Ordering::Relaxed),
            p99,
        )
    }

    /// The final report over `elapsed`.
    pub fn report(&self, elapsed: Duration, config: serde_json::Value) -> Report {
        let h = self.latency.lock().unwrap();
        let errors_by_kind = self.errors.lock().unwrap().clone();
        let lost_by_kind = self.lost.lock().unwrap().clone();
        let requests = self.requests.load(Ordering::Relaxed);
        let ms = |q: f64| h.value_at_quantile(q) as f64 / 1e3;
        Report {
            config,
            requests,
            errors: errors_by_kind.values().sum(),
            errors_by_kind,
            lost: lost_by_kind.values().sum(),
            lost_by_kind,
            seconds: elapsed.as_secs_f64(),
            rps: requests as f64 / elapsed.as_secs_f64(),
            p50_ms: ms(0.50),
            p95_ms: ms(0.95),
            p99_ms: ms(0.99),
            p999_ms: ms(0.999),
            max_ms: h.max() as f64 / 1e3,
            bytes_in: self.bytes_in.load(Ordering::Relaxed),
            bytes_out: self.bytes_out.load(Ordering::Relaxed),
            reconnects: self.reconnects.load(Ordering::Relaxed),
            churned: self.churned.load(Ordering::Relaxed),
            kept: self.kept.load(Ordering::Relaxed),
            requests_saved: {
                let kept = self.kept.load(Ordering::Relaxed);
                let asked = requests + kept;
                if asked > 0 {
                    kept as f64 / asked as f64
                } else {
                    0.0
                }
            },
            users: self.users.lock().unwrap().values().cloned().collect(),
            phases: Vec::new(),
        }
    }
}

/// A user's handle on the recorder: what it counts is also counted as its.
#[derive(Clone)]
pub struct UserRecorder {
    all: Arc<Recorder>,
    user: u32,
    mode: Mode,
}

impl UserRecorder {
    /// User `user`'s handle.
    pub fn new(all: Arc<Recorder>, user: u32, mode: Mode) -> UserRecorder {
        UserRecorder { all, user, mode }
    }

    /// One answered frame, with the number of other users it showed;
    /// `current`: answered for the user's session now (not an answer of a
    /// session it has since replaced, which mends no loss).
    pub fn ok(
        &self,
        latency: Duration,
        sent: usize,
        received: usize,
        users_visible: usize,
        current: bool,
    ) {
        self.all.ok(latency, sent, received);
        self.all.user(self.user, self.mode, |u| {
            u.answered += 1;
            u.saw_users += u64::from(users_visible > 0);
            if !current {
                return;
            }
            if let Some(since) = u.lost_since.take() {
                let ms = since.elapsed().as_secs_f64() * 1e3;
                u.recovery_ms = Some(u.recovery_ms.map_or(ms, |m| m.max(ms)));
                u.answered_after_loss = 0;
            }
            u.answered_after_loss += 1;
        });
    }

    /// One frame lost with its session or replica.
    pub fn lost(&self, kind: &str) {
        self.all.lost(kind);
        let at = self.all.start.elapsed().as_secs_f64();
        self.all.user(self.user, self.mode, |u| {
            u.lost += 1;
            u.lost_at_s.push((at * 1e3).round() / 1e3);
            u.lost_since.get_or_insert_with(Instant::now);
        });
    }

    /// One error.
    pub fn error(&self, kind: &str) {
        self.all.error(kind);
        self.all.user(self.user, self.mode, |u| u.errors += 1);
    }

    /// A new session after a loss.
    pub fn reconnect(&self) {
        self.all.reconnect();
        self.all.user(self.user, self.mode, |u| u.reconnects += 1);
    }

    /// A session replaced on purpose (`--churn`).
    pub fn churned(&self) {
        self.all.churned();
    }

    /// One frame not sent: the user's last answer holds for its region.
    pub fn kept(&self) {
        self.all.kept();
    }

    /// Notes the replica an answer names (`x-pvsd-replica`), if any.
    pub fn replica(&self, headers: &reqwest::header::HeaderMap) {
        let Some(name) = headers.get("x-pvsd-replica").and_then(|v| v.to_str().ok()) else {
            return;
        };
        self.all.user(self.user, self.mode, |u| {
            if u.replicas.last().map(String::as_str) != Some(name) {
                u.replicas.push(name.to_string());
            }
        });
    }
}

/// `--json`'s contents.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// What was run.
    pub config: serde_json::Value,
    /// Requests sent (answered or failed).
    pub requests: u64,
    /// Failed requests.
    pub errors: u64,
    /// Failed requests by kind.
    pub errors_by_kind: BTreeMap<String, u64>,
    /// Frames lost with their session or replica (soft state: each cost
    /// its user a new session, counted in `reconnects`).
    pub lost: u64,
    /// Lost frames by kind (`http_404`, `http_502`, `connect`, `ws_closed`, …).
    pub lost_by_kind: BTreeMap<String, u64>,
    /// Length of the run, seconds.
    pub seconds: f64,
    /// Requests per second.
    pub rps: f64,
    /// Latency percentiles, milliseconds (answered requests only).
    pub p50_ms: f64,
    /// 95th percentile.
    pub p95_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
    /// 99.9th percentile.
    pub p999_ms: f64,
    /// Slowest answer.
    pub max_ms: f64,
    /// Response body bytes received.
    pub bytes_in: u64,
    /// Request body bytes sent.
    pub bytes_out: u64,
    /// Sessions made again after the server lost them (restarted, or
    /// evicted them): each cost its user one failed frame or more.
    pub reconnects: u64,
    /// Sessions ended and replaced on purpose (`--churn`).
    pub churned: u64,
    /// Frames not sent because the user's last answer held for its region
    /// (`--radius`, `--angle`).
    pub kept: u64,
    /// The share of frames that were not sent (kept over kept + requests):
    /// the requests the region saved against `--radius 0`.
    pub requests_saved: f64,
    /// Each user's counts.
    pub users: Vec<UserStats>,
    /// The run split at `--marks`, when given.
    pub phases: Vec<Phase>,
}

impl Report {
    /// The table printed at the end.
    pub fn table(&self) -> String {
        let mut t = format!(
            "requests {}  errors {}  lost {}  {:.1} s  {:.0} frames/s\n\
             latency ms  p50 {:.3}  p95 {:.3}  p99 {:.3}  p99.9 {:.3}  max {:.3}\n\
             bytes  in {}  out {}  reconnects {}  churned {}\n",
            self.requests,
            self.errors,
            self.lost,
            self.seconds,
            self.rps,
            self.p50_ms,
            self.p95_ms,
            self.p99_ms,
            self.p999_ms,
            self.max_ms,
            self.bytes_in,
            self.bytes_out,
            self.reconnects,
            self.churned
        );
        if self.kept > 0 {
            t += &format!(
                "frames kept (the answer held for its region): {}  requests saved {:.1}%\n",
                self.kept,
                self.requests_saved * 100.0
            );
        }
        for (kind, n) in &self.errors_by_kind {
            t.push_str(&format!("errors {kind}: {n}\n"));
        }
        for (kind, n) in &self.lost_by_kind {
            t.push_str(&format!("lost {kind}: {n}\n"));
        }
        if !self.phases.is_empty() {
            t.push_str(&format!(
                "{:<16} {:>7} {:>7} {:>9} {:>9} {:>6} {:>6} {:>10}\n",
                "phase", "from s", "to s", "frames/s", "p99 ms", "lost", "errors", "reconnects"
            ));
            for p in &self.phases {
                t.push_str(&format!(
                    "{:<16} {:>7.1} {:>7.1} {:>9.0} {:>9.3} {:>6} {:>6} {:>10}\n",
                    p.label, p.from_s, p.to_s, p.fps, p.p99_ms, p.lost, p.errors, p.reconnects
                ));
            }
        }
        t
    }
}
