//! Requests to the router in process, without a socket (tower's
//! `oneshot`), as axum's examples test their routers.

use axum::body::Body;
use axum::body::Bytes;
use axum::http::{HeaderMap, Request, StatusCode};
use http_body_util::BodyExt;
use pvsd::server::{AppState, app};
use serde_json::Value;
use tower::ServiceExt;

/// The body of a request that has none.
pub const NO_BODY: Option<&str> = None;

/// `method uri` with an optional JSON body; the status and the answer as
/// JSON (a body that is not JSON comes back as a string, an empty one as
/// an empty string).
pub async fn call(
    state: &AppState,
    method: &str,
    uri: &str,
    body: Option<impl ToString>,
) -> (StatusCode, Value) {
    let (status, _, bytes) = call_raw(state, method, uri, body, &[]).await;
    let value = serde_json::from_slice(&bytes)
        .unwrap_or_else(|_| Value::String(String::from_utf8_lossy(&bytes).into()));
    (status, value)
}

/// `method uri` with an optional JSON body and more `headers`; the status,
/// the headers and the bytes of the answer.
pub async fn call_raw(
    state: &AppState,
    method: &str,
    uri: &str,
    body: Option<impl ToString>,
    headers: &[(&str, &str)],
) -> (StatusCode, HeaderMap, Bytes) {
    let mut req = Request::builder().method(method).uri(uri);
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    let req = match body {
        Some(b) => req
            .header("content-type", "application/json")
            .body(Body::from(b.to_string())),
        None => req.body(Body::empty()),
    }
    .unwrap();
    let res = app(state.clone()).oneshot(req).await.unwrap();
    let (status, headers) = (res.status(), res.headers().clone());
    let bytes = res.into_body().collect().await.unwrap().to_bytes();
    (status, headers, bytes)
}
