//! What a run measured: latencies in an HDR histogram (microseconds, three
//! significant digits), requests, errors by kind and bytes, shared by every
//! virtual user.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use hdrhistogram::Histogram;
use serde::Serialize;

/// Counters every user adds to.
pub struct Recorder {
    latency: Mutex<Histogram<u64>>,
    requests: AtomicU64,
    bytes_in: AtomicU64,
    bytes_out: AtomicU64,
    errors: Mutex<BTreeMap<String, u64>>,
    reconnects: AtomicU64,
    churned: AtomicU64,
}

impl Recorder {
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
        }
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
    }

    /// One session made again after the server lost it.
    pub fn reconnect(&self) {
        self.reconnects.fetch_add(1, Ordering::Relaxed);
    }

    /// One session ended and replaced on purpose (`--churn`).
    pub fn churned(&self) {
        self.churned.fetch_add(1, Ordering::Relaxed);
    }

    /// Requests and errors so far, and the p99 so far in milliseconds.
    pub fn progress(&self) -> (u64, u64, f64) {
        let errors = self.errors.lock().unwrap().values().sum();
        let p99 = self.latency.lock().unwrap().value_at_quantile(0.99) as f64 / 1e3;
        (self.requests.load(Ordering::Relaxed), errors, p99)
    }

    /// The final report over `elapsed`.
    pub fn report(&self, elapsed: Duration, config: serde_json::Value) -> Report {
        let h = self.latency.lock().unwrap();
        let errors_by_kind = self.errors.lock().unwrap().clone();
        let requests = self.requests.load(Ordering::Relaxed);
        let ms = |q: f64| h.value_at_quantile(q) as f64 / 1e3;
        Report {
            config,
            requests,
            errors: errors_by_kind.values().sum(),
            errors_by_kind,
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
        }
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
}

impl Report {
    /// The table printed at the end.
    pub fn table(&self) -> String {
        let mut t = format!(
            "requests {}  errors {}  {:.1} s  {:.0} frames/s\n\
             latency ms  p50 {:.3}  p95 {:.3}  p99 {:.3}  p99.9 {:.3}  max {:.3}\n\
             bytes  in {}  out {}  reconnects {}  churned {}\n",
            self.requests,
            self.errors,
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
        for (kind, n) in &self.errors_by_kind {
            t.push_str(&format!("errors {kind}: {n}\n"));
        }
        t
    }
}
