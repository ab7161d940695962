//! The HTTP service: routes, shared state, errors, metrics, shutdown.
//!
//! Split like mini-redis: [`app`] builds the router over an [`AppState`]
//! (tests drive it with `tower::ServiceExt::oneshot`), [`run`] serves it on a
//! listener until a shutdown future resolves, [`shutdown_signal`] is that
//! future for SIGINT and SIGTERM, and [`config`] reads `--config` files.

pub mod config;
mod error;
mod extract;
mod metrics;
mod routes;
mod state;
pub mod wire;

use std::future::Future;

use axum::Router;
use axum::error_handling::HandleErrorLayer;
use axum::extract::DefaultBodyLimit;
use axum::routing::{get, post};
use tokio::net::TcpListener;
use tower::ServiceBuilder;
use tower_http::catch_panic::CatchPanicLayer;
use tower_http::trace::TraceLayer;

pub use error::ApiError;
pub use extract::BodyLimit;
pub use metrics::Metrics;
pub use state::{AppState, DuplicateScene, Limits};

/// The router of DESIGN's HTTP API over `state`.
pub fn app(state: AppState) -> Router {
    let limits = state.limits();
    let timeout_state = state.clone();
    Router::new()
        .route("/healthz", get(routes::healthz))
        .route("/scenes", get(routes::scenes))
        .route("/scenes/{id}/objects", get(routes::objects))
        .route("/scenes/{id}/visible", post(routes::visible))
        .route("/metrics", get(routes::metrics))
        .fallback(routes::no_route)
        .method_not_allowed_fallback(routes::method_not_allowed)
        .layer(DefaultBodyLimit::max(limits.body_bytes))
        .layer(axum::Extension(BodyLimit(limits.body_bytes)))
        .layer(
            ServiceBuilder::new()
                .layer(HandleErrorLayer::new(move |err| {
                    routes::timed_out(timeout_state.clone(), err)
                }))
                .timeout(limits.request_timeout),
        )
        // A panic in a handler is a bug; the client still gets a JSON 500 and
        // the server keeps serving everyone else.
        .layer(CatchPanicLayer::custom(routes::panicked))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            metrics::track,
        ))
        .layer(TraceLayer::new_for_http())
        .with_state(state)
}

/// Serves `app(state)` on `listener` until `shutdown` resolves, then lets
/// requests in flight finish.
pub async fn run(
    listener: TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    axum::serve(listener, app(state))
        .with_graceful_shutdown(shutdown)
        .await
}

/// Resolves on SIGINT (Ctrl+C) or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        if let Err(e) = tokio::signal::ctrl_c().await {
            tracing::error!("cannot listen for Ctrl+C: {e}");
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(e) => {
                tracing::error!("cannot listen for SIGTERM: {e}");
                std::future::pending::<()>().await;
            }
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = terminate => {},
    }
    tracing::info!("shutting down: finishing requests in flight");
}
