//! The HTTP service: routes, shared state, sessions, walkthroughs,
//! WebSocket, errors, metrics, shutdown.
//!
//! Split like mini-redis: [`app`] builds the router over an [`AppState`]
//! (tests drive it with `tower::ServiceExt::oneshot`), [`run`] serves it on a
//! listener until a shutdown future resolves, [`shutdown_signal`] is that
//! future for SIGINT and SIGTERM, and [`config`] reads `--config` files.
//! [`session`] keeps clients' temporal caches and computes deltas,
//! [`walkthrough`] puts several sessions in one scene, [`ws`] streams
//! frames. The wire formats (JSON bodies, `application/x-pvs`, deltas) are
//! `pvsd_proto`'s, shared with `loadtest`; [`wire`] converts between them
//! and the library's types.

pub mod config;
mod error;
mod extract;
mod limit;
mod listener;
mod mesh;
mod metrics;
pub mod route;
mod routes;
pub mod session;
mod state;
pub mod tls;
mod viewer;
mod walk;
pub mod walkthrough;
pub mod wire;
pub mod ws;

use std::future::Future;

use axum::Router;
use axum::error_handling::HandleErrorLayer;
use axum::extract::DefaultBodyLimit;
use axum::handler::Handler;
use axum::http::{HeaderValue, Method};
use axum::routing::{MethodFilter, on};
use tokio::net::TcpListener;
use tower::ServiceBuilder;
use tower_http::catch_panic::CatchPanicLayer;
use tower_http::trace::{DefaultOnFailure, TraceLayer};

pub use error::ApiError;
pub use extract::parse;
pub use limit::{ClientRate, MessageRate};
pub use listener::{ConnectionLimits, ConnectionSlot};
pub use metrics::Metrics;
pub use state::{
    AppState, DuplicateScene, JsonLimits, Lifecycle, Limits, Rate, Readiness, SessionLimits,
};

/// A router that remembers what it routes, so the OpenAPI document can be
/// checked against the routes themselves.
struct Routes {
    router: Router<AppState>,
    table: Vec<(Method, &'static str)>,
}

impl Routes {
    fn add<H, T>(mut self, method: Method, path: &'static str, handler: H) -> Self
    where
        H: Handler<T, AppState>,
        T: 'static,
    {
        let filter = MethodFilter::try_from(method.clone()).expect("a standard HTTP method");
        self.router = self.router.route(path, on(filter, handler));
        self.table.push((method, path));
        self
    }
}

/// Every route of DESIGN's HTTP API, in one place.
fn routes() -> Routes {
    Routes {
        router: Router::new(),
        table: Vec::new(),
    }
    .add(Method::GET, "/", viewer::page)
    .add(Method::GET, "/viewer", viewer::page)
    .add(Method::GET, "/viewer/{file}", viewer::asset)
    .add(Method::GET, "/healthz", routes::healthz)
    .add(Method::GET, "/healthz/live", routes::live)
    .add(Method::GET, "/healthz/ready", routes::ready)
    .add(Method::GET, "/scenes", routes::scenes)
    .add(Method::GET, "/scenes/{id}/objects", routes::objects)
    .add(
        Method::PUT,
        "/scenes/{id}/objects/{oid}",
        routes::move_object,
    )
    .add(
        Method::GET,
        "/scenes/{id}/objects/{oid}/mesh",
        mesh::object_mesh,
    )
    .add(Method::POST, "/scenes/{id}/meshes", mesh::meshes)
    .add(Method::GET, "/scenes/{id}/walk", walk::scene_walk)
    .add(Method::POST, "/scenes/{id}/visible", routes::visible)
    .add(Method::POST, "/sessions", routes::create_session)
    .add(Method::POST, "/sessions/{sid}/frames", routes::frames)
    .add(Method::DELETE, "/sessions/{sid}", routes::delete_session)
    .add(Method::GET, "/sessions/{sid}/ws", ws::upgrade)
    .add(Method::POST, "/walkthroughs", routes::create_walkthrough)
    .add(
        Method::POST,
        "/walkthroughs/{wid}/users",
        routes::join_walkthrough,
    )
    .add(Method::GET, "/walkthroughs/{wid}", routes::walkthrough)
    .add(Method::GET, "/metrics", routes::metrics)
    .add(Method::POST, "/admin/reload", routes::reload)
}

/// The (HTTP method, path template) of every route [`app`] serves.
pub fn route_table() -> Vec<(Method, &'static str)> {
    routes().table
}

/// The router of DESIGN's HTTP API over `state`.
pub fn app(state: AppState) -> Router {
    let limits = state.limits();
    let timeout_state = state.clone();
    // Which replica answered, for clients and load tests behind a proxy.
    let replica = state
        .replica()
        .and_then(|name| HeaderValue::from_str(name).ok());
    let router = routes()
        .router
        .fallback(routes::no_route)
        .method_not_allowed_fallback(routes::method_not_allowed)
        .layer(DefaultBodyLimit::max(limits.body_bytes))
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
            limit::limit_clients,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            metrics::track,
        ))
        // A 5xx is logged where it is made (`ApiError::body` logs internal
        // errors); the trace layer's own error line would also fire for
        // every `not_ready` a readiness probe gets while a replica loads.
        .layer(
            TraceLayer::new_for_http()
                .on_failure(DefaultOnFailure::new().level(tracing::Level::DEBUG)),
        )
        .with_state(state);
    match replica {
        Some(name) => router.layer(axum::middleware::map_response(
            move |mut response: axum::response::Response| {
                let name = name.clone();
                async move {
                    response.headers_mut().insert(REPLICA_HEADER, name);
                    response
                }
            },
        )),
        None => router,
    }
}

/// The header naming the replica that answered (when it has a name).
pub const REPLICA_HEADER: &str = "x-pvsd-replica";

/// Serves `app(state)` on `listener` until `shutdown` resolves, then lets
/// requests in flight finish within the grace period (`listener`).
pub async fn run(
    listener: TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    listener::serve(listener, state, None, shutdown).await
}

/// [`run`], speaking TLS with `tls` (see [`tls::acceptor`]).
pub async fn run_tls(
    listener: TcpListener,
    state: AppState,
    tls: tokio_rustls::TlsAcceptor,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    listener::serve(listener, state, Some(tls), shutdown).await
}

/// Reloads `state`'s scene files at every SIGHUP ([`AppState::reload`]),
/// logging what each reload did; runs until the server shuts down.
pub async fn reload_on_sighup(state: AppState) {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let mut hangups = match signal(SignalKind::hangup()) {
            Ok(s) => s,
            Err(e) => {
                tracing::error!("cannot listen for SIGHUP: {e}");
                return;
            }
        };
        let shutdown = state.lifecycle().shutdown.clone();
        while shutdown
            .run_until_cancelled(hangups.recv())
            .await
            .flatten()
            .is_some()
        {
            tracing::info!("SIGHUP: reloading scene files");
            let s = state.clone();
            match tokio::task::spawn_blocking(move || s.reload()).await {
                Ok(report) => tracing::info!(
                    reloaded = ?report.reloaded,
                    unchanged = ?report.unchanged,
                    failed = report.failed.len(),
                    "reload done"
                ),
                Err(e) => tracing::error!("the reload failed: {e}"),
            }
        }
    }
    #[cfg(not(unix))]
    let _ = state;
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
    tracing::info!("shutdown signal received");
}
