//! The listener: accepts connections, caps them, times out slow clients,
//! speaks TLS when configured, and drains on shutdown.
//!
//! `axum::serve` has none of these limits, so pvsd accepts connections
//! itself, as mini-redis's listener does, and hands each to hyper's HTTP/1
//! server with the limits nginx and envoy apply by default:
//! - at most [`ConnectionLimits::max_connections`] connections (a
//!   WebSocket counts until it closes); one more gets `503 overloaded` with
//!   `Retry-After` and is closed, without waiting on the client;
//! - a client must send a request's whole head within
//!   [`ConnectionLimits::header_timeout`], which also ends a keep-alive
//!   connection left idle that long (a slowloris client holds a task and a
//!   socket for at most that time, nothing else); the body has its own
//!   timeout, applied where it is read (`extract`);
//! - a TLS handshake must finish within the header timeout too.
//!
//! Shutdown: the server drains first (not ready, still serving, for
//! [`ConnectionLimits::drain`]); then the listener stops accepting;
//! connections finish the request in flight and close; WebSockets get a
//! close frame saying why (`ws`); whatever is still open after the grace
//! period is dropped.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::connect_info::ConnectInfo;
use axum::response::IntoResponse;
use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio_rustls::TlsAcceptor;
use tower::ServiceExt;

use super::error::ApiError;
use super::metrics::Refusal;
use super::state::AppState;

/// Limits on connections, as the config sets them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConnectionLimits {
    /// Most open connections (WebSockets included).
    pub max_connections: usize,
    /// Longest a client may take to send a request's head (and longest a
    /// keep-alive connection may sit idle).
    pub header_timeout: Duration,
    /// Longest a client may take to send a request's body.
    pub body_timeout: Duration,
    /// How long the server, told to stop, goes on serving while
    /// `GET /healthz/ready` answers 503, so that load balancers stop
    /// sending it work before it closes.
    pub drain: Duration,
    /// How long shutdown waits for requests in flight and WebSockets.
    pub shutdown_grace: Duration,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        // 10k connections is ~10k file descriptors and a few MiB of task
        // state; 10 s is ample for a head or a body of at most the body
        // limit (64 KiB) on any link a user would walk a scene over.
        ConnectionLimits {
            max_connections: 10_000,
            header_timeout: Duration::from_secs(10),
            body_timeout: Duration::from_secs(10),
            // None by default: one server alone has no balancer to tell.
            drain: Duration::ZERO,
            shutdown_grace: Duration::from_secs(10),
        }
    }
}

/// A connection's place under [`ConnectionLimits::max_connections`], held
/// by the connection and by a WebSocket it was upgraded to; the place is
/// free again when both are done with it.
#[derive(Clone)]
pub struct ConnectionSlot(#[allow(dead_code)] Arc<OwnedSemaphorePermit>);

/// Serves `state`'s router on `listener` (with TLS when `tls` is given)
/// until `shutdown` resolves, then drains within the grace period.
pub async fn serve(
    listener: TcpListener,
    state: AppState,
    tls: Option<TlsAcceptor>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let limits = state.limits().connections;
    let app = super::app(state.clone());
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let lifecycle = state.lifecycle().clone();
    if state.client_rate().is_some() {
        let state = state.clone();
        lifecycle.tasks.spawn(async move {
            let mut every = tokio::time::interval(Duration::from_secs(60));
            let shutdown = state.lifecycle().shutdown.clone();
            while shutdown.run_until_cancelled(every.tick()).await.is_some() {
                if let Some(rate) = state.client_rate() {
                    rate.forget_idle();
                }
            }
        });
    }
    // Told to stop, the server first drains: `/healthz/ready` answers 503
    // at once, and it goes on accepting and serving for the drain period,
    // so that load balancers take it out before anything is refused.
    let readiness = state.readiness().clone();
    let drained = async move {
        shutdown.await;
        // One that never was ready (told to stop while loading, or its
        // scenes failed) had no traffic to drain.
        let was_ready = readiness.check().is_ok();
        readiness.drain();
        if was_ready && !limits.drain.is_zero() {
            tracing::info!(
                drain_s = limits.drain.as_secs_f64(),
                "draining: not ready; serving on while load balancers take this replica out"
            );
            tokio::time::sleep(limits.drain).await;
        }
    };
    tokio::pin!(drained);
    loop {
        let (stream, peer) = tokio::select! {
            () = &mut drained => break,
            accepted = listener.accept() => match accepted {
                Ok(accepted) => accepted,
                Err(e) => {
                    // Out of file descriptors (or another transient
                    // failure): wait, rather than spin on accept.
                    tracing::warn!("accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
        };
        let _ = stream.set_nodelay(true);
        let Ok(permit) = slots.clone().try_acquire_owned() else {
            state.metrics().refused(Refusal::Connections);
            lifecycle
                .tasks
                .spawn(refuse(stream, limits.max_connections));
            continue;
        };
        let slot = ConnectionSlot(Arc::new(permit));
        let app = app.clone();
        let (tls, state) = (tls.clone(), state.clone());
        lifecycle.tasks.spawn(async move {
            match tls {
                None => connection(stream, peer, slot, app, state).await,
                Some(tls) => {
                    match tokio::time::timeout(limits.header_timeout, tls.accept(stream)).await {
                        Ok(Ok(stream)) => connection(stream, peer, slot, app, state).await,
                        Ok(Err(e)) => tracing::debug!(%peer, "TLS handshake failed: {e}"),
                        Err(_) => state.metrics().refused(Refusal::HeaderTimeout),
                    }
                }
            }
        });
    }
    drop(listener);
    tracing::info!(
        grace_s = limits.shutdown_grace.as_secs_f64(),
        "shutting down: no new connections; finishing requests in flight"
    );
    lifecycle.shutdown.cancel();
    lifecycle.tasks.close();
    if tokio::time::timeout(limits.shutdown_grace, lifecycle.tasks.wait())
        .await
        .is_err()
    {
        tracing::warn!(
            open = lifecycle.tasks.len(),
            "the grace period is over: dropping connections still open"
        );
    }
    Ok(())
}

/// Serves one connection until the client closes it, a timeout ends it,
/// or shutdown finishes its request in flight.
async fn connection<I>(io: I, peer: SocketAddr, slot: ConnectionSlot, app: Router, state: AppState)
where
    I: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let limits = state.limits().connections;
    let service = app.map_request(move |mut req: hyper::Request<hyper::body::Incoming>| {
        req.extensions_mut().insert(ConnectInfo(peer));
        req.extensions_mut().insert(slot.clone());
        req
    });
    let mut builder = http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout);
    let conn = builder
        .serve_connection(TokioIo::new(io), TowerToHyperService::new(service))
        .with_upgrades();
    tokio::pin!(conn);
    let shutdown = state.lifecycle().shutdown.clone();
    let result = tokio::select! {
        r = conn.as_mut() => r,
        () = shutdown.cancelled() => {
            conn.as_mut().graceful_shutdown();
            conn.await
        }
    };
    if let Err(e) = result {
        if e.is_timeout() {
            state.metrics().refused(Refusal::HeaderTimeout);
        }
        tracing::debug!(%peer, "connection ended: {e}");
    }
}

/// Answers a connection over the cap with `503 overloaded` and closes it.
/// The client is given a moment to send its request (so it reads an
/// answer, not a reset), never more.
async fn refuse(stream: TcpStream, max: usize) {
    let service = hyper::service::service_fn(move |_req| async move {
        Ok::<_, std::convert::Infallible>(ApiError::Overloaded { max }.into_response())
    });
    let conn = http1::Builder::new()
        .keep_alive(false)
        .serve_connection(TokioIo::new(stream), service);
    let _ = tokio::time::timeout(Duration::from_secs(1), conn).await;
}
