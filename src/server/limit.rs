//! Rates: how many requests a client (an IP address) and how many messages
//! a WebSocket may send a second, as token buckets (GCRA, the `governor`
//! crate, as `tower_governor` uses it); past the rate, `429 rate_limited`
//! with `Retry-After`.
//!
//! The client rate is off unless configured: behind a proxy every client
//! has the proxy's address, so the operator decides. The WebSocket rate is
//! always on: a socket bypasses the HTTP limits once upgraded.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::num::NonZeroU32;
use std::time::Duration;

use axum::extract::connect_info::ConnectInfo;
use axum::extract::{Request, State};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use governor::clock::{Clock, DefaultClock};
use governor::{DefaultDirectRateLimiter, DefaultKeyedRateLimiter, NotUntil, Quota, RateLimiter};

use super::error::ApiError;
use super::state::{AppState, Rate};

fn quota(rate: Rate) -> Quota {
    let period = Duration::from_secs_f64(1.0 / rate.per_s).max(Duration::from_nanos(1));
    Quota::with_period(period)
        .expect("a rate > 0 has a period > 0")
        .allow_burst(NonZeroU32::new(rate.burst).unwrap_or(NonZeroU32::MIN))
}

fn refusal(rate: Rate, not_until: &NotUntil<<DefaultClock as Clock>::Instant>) -> ApiError {
    let wait = not_until.wait_time_from(DefaultClock::default().now());
    ApiError::RateLimited {
        per_s: rate.per_s,
        // Whole seconds, at least one: what `Retry-After` can say.
        retry_after_s: wait.as_secs_f64().ceil().max(1.0) as u64,
    }
}

/// Each client's request rate, by IP address.
pub struct ClientRate {
    rate: Rate,
    buckets: DefaultKeyedRateLimiter<IpAddr>,
}

impl ClientRate {
    /// Buckets of `rate`, none yet.
    pub fn new(rate: Rate) -> ClientRate {
        ClientRate {
            rate,
            buckets: RateLimiter::keyed(quota(rate)),
        }
    }

    /// Takes one request from `client`'s bucket, or says when to come back.
    pub fn check(&self, client: IpAddr) -> Result<(), ApiError> {
        self.buckets
            .check_key(&client)
            .map_err(|n| refusal(self.rate, &n))
    }

    /// Forgets clients whose buckets are full again (they would start
    /// anew anyway), so the map holds only recent clients.
    pub fn forget_idle(&self) {
        self.buckets.retain_recent();
        self.buckets.shrink_to_fit();
    }
}

/// Middleware: refuses a request over its client's rate. A request with no
/// peer address (driven in-process, as tests do) counts as one client.
pub async fn limit_clients(State(state): State<AppState>, req: Request, next: Next) -> Response {
    if let Some(rate) = state.client_rate() {
        let client = req
            .extensions()
            .get::<ConnectInfo<SocketAddr>>()
            .map_or(IpAddr::V4(Ipv4Addr::UNSPECIFIED), |c| c.0.ip());
        if let Err(e) = rate.check(client) {
            return e.into_response();
        }
    }
    next.run(req).await
}

/// One WebSocket's message rate.
pub struct MessageRate {
    rate: Rate,
    bucket: DefaultDirectRateLimiter,
}

impl MessageRate {
    /// A full bucket of `rate`.
    pub fn new(rate: Rate) -> MessageRate {
        MessageRate {
            rate,
            bucket: RateLimiter::direct(quota(rate)),
        }
    }

    /// Takes one message from the bucket, or says when to come back.
    pub fn check(&self) -> Result<(), ApiError> {
        self.bucket.check().map_err(|n| refusal(self.rate, &n))
    }
}
