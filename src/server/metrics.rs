//! `/metrics`: Prometheus counters and histograms.
//!
//! Each [`Metrics`] has its own registry (not a process-global recorder), so
//! tests can run many servers in one process without sharing counts.

use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::middleware::Next;
use axum::response::Response;
use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;
use pvsd_proto::error::ErrorCode;

use super::state::AppState;
use crate::cull::CullStats;

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RouteLabels {
    route: String,
    method: String,
    status: u16,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RouteLatencyLabels {
    route: String,
    method: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct EvictionLabels {
    cause: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RefusalLabels {
    reason: &'static str,
}

/// Why the server refused a client: each is a label of
/// `pvsd_refused_total`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// A connection over `max_connections` (503 `overloaded`).
    Connections,
    /// A request head (or TLS handshake) slower than `header_timeout_ms`,
    /// or a keep-alive connection idle that long.
    HeaderTimeout,
    /// A body slower than `body_timeout_ms` (408).
    BodyTimeout,
    /// A body over `body_limit_bytes` (413).
    BodySize,
    /// A body deeper or wider than the JSON limits (413).
    JsonLimits,
    /// A client over its request rate (429).
    ClientRate,
    /// A WebSocket over its message rate.
    WebSocketRate,
    /// A WebSocket message over the body limit.
    WebSocketSize,
}

impl Refusal {
    /// The refusal an HTTP error answer stands for, if it is one.
    fn of(code: ErrorCode) -> Option<Refusal> {
        Some(match code {
            ErrorCode::BodyTooLarge => Refusal::BodySize,
            ErrorCode::BodyTooComplex => Refusal::JsonLimits,
            ErrorCode::BodyTimeout => Refusal::BodyTimeout,
            ErrorCode::RateLimited => Refusal::ClientRate,
            _ => return None,
        })
    }

    fn label(self) -> &'static str {
        match self {
            Refusal::Connections => "connections",
            Refusal::HeaderTimeout => "header_timeout",
            Refusal::BodyTimeout => "body_timeout",
            Refusal::BodySize => "body_size",
            Refusal::JsonLimits => "json_limits",
            Refusal::ClientRate => "client_rate",
            Refusal::WebSocketRate => "websocket_rate",
            Refusal::WebSocketSize => "websocket_size",
        }
    }
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct CullLabels {
    scene: String,
    method: String,
}

/// The server's metrics.
pub struct Metrics {
    registry: Registry,
    /// Requests by route template, HTTP method and status.
    requests: Family<RouteLabels, Counter>,
    /// Request latency by route template and HTTP method, seconds.
    latency: Family<RouteLatencyLabels, Histogram, fn() -> Histogram>,
    /// Cull time by scene and culling method, seconds.
    cull: Family<CullLabels, Histogram, fn() -> Histogram>,
    /// Size of answers by scene and culling method, objects.
    visible: Family<CullLabels, Histogram, fn() -> Histogram>,
    /// Culls a method failed, answered by frustum culling instead.
    fallbacks: Family<CullLabels, Counter>,
    /// Scenes loaded.
    scenes: Gauge,
    /// Live sessions.
    sessions: Gauge,
    /// Bytes the live sessions hold (their caches and kept frames).
    session_bytes: Gauge,
    /// Sessions ended by the server, by cause (`expired`, `evicted`).
    evictions: Family<EvictionLabels, Counter>,
    /// Live walkthroughs.
    walkthroughs: Gauge,
    /// Open WebSocket connections.
    websockets: Gauge,
    /// Clients refused by a limit, by reason.
    refused: Family<RefusalLabels, Counter>,
}

fn latency_histogram() -> Histogram {
    // 1 µs to ~16 s.
    Histogram::new(exponential_buckets(1e-6, 2.0, 25))
}

fn size_histogram() -> Histogram {
    // 1 to ~1M objects.
    Histogram::new(exponential_buckets(1.0, 2.0, 21))
}

impl Metrics {
    /// Fresh metrics in a registry of their own.
    pub fn new() -> Self {
        let mut registry = Registry::with_prefix("pvsd");
        let requests = Family::<RouteLabels, Counter>::default();
        let latency =
            Family::<RouteLatencyLabels, Histogram, fn() -> Histogram>::new_with_constructor(
                latency_histogram as fn() -> Histogram,
            );
        let cull = Family::<CullLabels, Histogram, fn() -> Histogram>::new_with_constructor(
            latency_histogram as fn() -> Histogram,
        );
        let visible = Family::<CullLabels, Histogram, fn() -> Histogram>::new_with_constructor(
            size_histogram as fn() -> Histogram,
        );
        let fallbacks = Family::<CullLabels, Counter>::default();
        let scenes = Gauge::default();
        let sessions = Gauge::default();
        let session_bytes = Gauge::default();
        let evictions = Family::<EvictionLabels, Counter>::default();
        let walkthroughs = Gauge::default();
        let websockets = Gauge::default();
        let refused = Family::<RefusalLabels, Counter>::default();
        registry.register(
            "refused",
            "Requests, connections and WebSocket messages refused by a limit, by reason",
            refused.clone(),
        );
        registry.register("sessions", "Live sessions", sessions.clone());
        registry.register(
            "session_cache_bytes",
            "Bytes held by live sessions (method caches and kept frames)",
            session_bytes.clone(),
        );
        registry.register(
            "session_evictions",
            "Sessions ended by the server, by cause",
            evictions.clone(),
        );
        registry.register("walkthroughs", "Live walkthroughs", walkthroughs.clone());
        registry.register(
            "websocket_connections",
            "Open WebSocket connections",
            websockets.clone(),
        );
        registry.register(
            "http_requests",
            "HTTP requests by route, method and status",
            requests.clone(),
        );
        registry.register(
            "http_request_duration_seconds",
            "HTTP request latency",
            latency.clone(),
        );
        registry.register(
            "cull_duration_seconds",
            "Time to cull one view",
            cull.clone(),
        );
        registry.register("visible_objects", "Objects in an answer", visible.clone());
        registry.register(
            "cull_fallbacks",
            "Culls a method failed, answered by frustum culling instead",
            fallbacks.clone(),
        );
        registry.register("scenes", "Scenes loaded", scenes.clone());
        Metrics {
            registry,
            requests,
            latency,
            cull,
            visible,
            fallbacks,
            scenes,
            sessions,
            session_bytes,
            evictions,
            walkthroughs,
            websockets,
            refused,
        }
    }

    /// A counter of server-ended sessions to hand to the session store:
    /// `true` counts an expiry, `false` an eviction.
    pub fn session_evictions(&self) -> impl Fn(bool) + Send + Sync + 'static {
        let evictions = self.evictions.clone();
        move |expired| {
            let cause = if expired { "expired" } else { "evicted" };
            evictions.get_or_create(&EvictionLabels { cause }).inc();
        }
    }

    /// Sets the session gauges.
    pub fn set_sessions(&self, live: u64, bytes: u64, walkthroughs: u64) {
        self.sessions.set(live as i64);
        self.session_bytes.set(bytes as i64);
        self.walkthroughs.set(walkthroughs as i64);
    }

    /// A WebSocket opened (`+1`) or closed (`-1`).
    pub fn websocket(&self, delta: i64) {
        self.websockets.inc_by(delta);
    }

    /// Counts one refusal.
    pub fn refused(&self, why: Refusal) {
        self.refused
            .get_or_create(&RefusalLabels {
                reason: why.label(),
            })
            .inc();
    }

    /// Records one cull: its time and size under the method that answered
    /// (so a failing method's histograms hold only its own answers), and a
    /// fallback under the method that was asked.
    pub fn observe_cull(&self, scene: &str, stats: &CullStats) {
        let labels = |method: &str| CullLabels {
            scene: scene.to_string(),
            method: method.to_string(),
        };
        let answered = labels(stats.fallback.as_ref().map_or(stats.method, |f| f.method));
        self.cull
            .get_or_create(&answered)
            .observe(stats.cull_us * 1e-6);
        self.visible
            .get_or_create(&answered)
            .observe(stats.visible as f64);
        if stats.fallback.is_some() {
            self.fallbacks.get_or_create(&labels(stats.method)).inc();
        }
    }

    /// Sets the number of scenes loaded.
    pub fn set_scenes(&self, n: usize) {
        self.scenes.set(n as i64);
    }

    /// The Prometheus text exposition.
    pub fn encode(&self) -> String {
        let mut out = String::new();
        prometheus_client::encoding::text::encode(&mut out, &self.registry)
            .expect("writing to a String");
        out
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

/// Middleware: counts every request and times it, by route template (so ids
/// in paths do not make new series) and HTTP method.
pub async fn track(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_string(), |p| p.as_str().to_string());
    // Extension methods are free text: label them all "other", so a client
    // cannot grow the number of series without bound.
    let method = match req.method().as_str() {
        m @ ("GET" | "POST" | "PUT" | "DELETE" | "HEAD" | "OPTIONS" | "PATCH") => m.to_string(),
        _ => "other".to_string(),
    };
    let start = Instant::now();
    let response = next.run(req).await;
    let m = state.metrics();
    if let Some(why) = response
        .extensions()
        .get::<ErrorCode>()
        .and_then(|&c| Refusal::of(c))
    {
        m.refused(why);
    }
    m.latency
        .get_or_create(&RouteLatencyLabels {
            route: route.clone(),
            method: method.clone(),
        })
        .observe(start.elapsed().as_secs_f64());
    m.requests
        .get_or_create(&RouteLabels {
            route,
            method,
            status: response.status().as_u16(),
        })
        .inc();
    response
}
