//! The handlers, one per route of DESIGN's HTTP API.
//!
//! Culling that a method declares cheap (`Culler::is_cheap`: frustum
//! culling, microseconds) runs on the async worker; anything else runs on
//! `spawn_blocking`, since past ~100 µs it would stall the worker's other
//! requests.

use axum::Json;
use axum::extract::{OriginalUri, Path, State};
use axum::http::{Method, header};
use axum::response::IntoResponse;

use super::error::ApiError;
use super::extract::{RawBody, parse};
use super::state::AppState;
use super::wire::{Bounds, ObjectInfo, SceneInfo, ViewRequest, VisibleResponse};
use crate::cull::{View, VisibleSet};

/// `GET /healthz`: 200 while the server runs.
pub async fn healthz() -> &'static str {
    "ok"
}

/// `GET /scenes`: every scene with its size, bounds and methods.
pub async fn scenes(State(state): State<AppState>) -> Json<Vec<SceneInfo>> {
    Json(
        state
            .scenes()
            .map(|m| {
                let s = m.scene();
                SceneInfo {
                    id: s.id.clone(),
                    objects: s.objects().len(),
                    triangles: s.triangle_count(),
                    bounds: (!s.bounds().is_empty()).then(|| Bounds::new(s.to_world(&s.bounds()))),
                    up: s.up().to_array(),
                    methods: m.names().into_iter().map(String::from).collect(),
                    unsupported: m
                        .unsupported()
                        .iter()
                        .map(|(name, why)| (name.to_string(), why.clone()))
                        .collect(),
                }
            })
            .collect(),
    )
}

/// `GET /scenes/{id}/objects`: what each id means.
pub async fn objects(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<Vec<ObjectInfo>>, ApiError> {
    let s = state.scene(&id)?.scene();
    Ok(Json(
        s.objects()
            .iter()
            .map(|o| ObjectInfo {
                id: o.id,
                name: o.name.clone(),
                bounds: (!o.bounds.is_empty()).then(|| Bounds::new(s.to_world(&o.bounds))),
            })
            .collect(),
    ))
}

/// `POST /scenes/{id}/visible`: the potentially visible set of one view.
pub async fn visible(
    State(state): State<AppState>,
    Path(id): Path<String>,
    RawBody(body): RawBody,
) -> Result<Json<VisibleResponse>, ApiError> {
    let methods = state.scene(&id)?;
    let req: ViewRequest = parse(&body)?;
    let spec = req.method_spec()?;
    let view = View::new(req.camera(), methods.scene())?;
    let (method, mut cache) = methods.prepare_client(&spec)?;
    let mut out = VisibleSet::new();
    let stats = if method.is_cheap() {
        method.cull(&view, &mut cache, &mut out)
    } else {
        // Hundreds of microseconds: off the async workers, so one heavy
        // request does not stall the others sharing the worker.
        let (stats, done) = tokio::task::spawn_blocking(move || {
            let stats = method.cull(&view, &mut cache, &mut out);
            (stats, out)
        })
        .await
        .map_err(|e| ApiError::Internal(format!("cull task failed: {e}")))?;
        out = done;
        stats
    };
    state
        .metrics()
        .observe_cull(&id, stats.method, stats.cull_us * 1e-6, stats.visible);
    Ok(Json(VisibleResponse {
        visible: out.ids().to_vec(),
        areas: out.areas(),
        stats: stats.into(),
    }))
}

/// `GET /metrics`: Prometheus text.
pub async fn metrics(State(state): State<AppState>) -> impl IntoResponse {
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        state.metrics().encode(),
    )
}

/// Any path no route matches.
pub async fn no_route(method: Method, OriginalUri(uri): OriginalUri) -> ApiError {
    ApiError::NoRoute {
        method: method.to_string(),
        path: uri.path().to_string(),
    }
}

/// A route that exists, asked with the wrong HTTP method.
pub async fn method_not_allowed(method: Method, OriginalUri(uri): OriginalUri) -> ApiError {
    ApiError::MethodNotAllowed {
        method: method.to_string(),
        path: uri.path().to_string(),
    }
}

/// For `HandleErrorLayer`: what the timeout layer's error becomes.
pub async fn timed_out(state: AppState, err: tower::BoxError) -> ApiError {
    if err.is::<tower::timeout::error::Elapsed>() {
        ApiError::Timeout {
            ms: state.limits().request_timeout.as_millis() as u64,
        }
    } else {
        ApiError::Internal(err.to_string())
    }
}

/// For `CatchPanicLayer`: a handler that panicked answers 500 `internal`.
pub fn panicked(err: Box<dyn std::any::Any + Send + 'static>) -> axum::response::Response {
    let detail = err
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| err.downcast_ref::<&str>().copied())
        .unwrap_or("a panic with no message");
    ApiError::Internal(format!("handler panicked: {detail}")).into_response()
}
