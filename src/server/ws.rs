//! `GET /sessions/{sid}/ws`: a session's frames over a WebSocket.
//!
//! The client sends views as JSON text messages (the body of
//! `POST /sessions/{sid}/frames`); the server answers each, in order, with
//! the frame as JSON text, or as an `application/x-pvs` binary message when
//! the upgrade asked for it (`?encoding=x-pvs` or that `Accept`). A bad
//! view gets an error message (`{"error": ...}`) and the socket stays open;
//! a session that ends (deleted, expired) gets its error and a close.
//!
//! Backpressure: one message is read, answered and *sent* before the next
//! is read. A client that stops reading fills its socket's buffers, the
//! send waits, nothing more is read, and the client's own writes stall: the
//! server holds at most one answer per connection. Closing the socket does
//! not end the session.

use axum::extract::rejection::QueryRejection;
use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade, close_code};
use axum::extract::{Path, Query, State};
use axum::http::HeaderMap;
use axum::response::Response;
use pvsd_proto::xpvs as binary;
use serde::Deserialize;

use super::error::ApiError;
use super::routes::{answer_frame, wants_binary};
use super::state::AppState;

/// The upgrade's query.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WsQuery {
    /// `json` (default) or `x-pvs`.
    encoding: Option<String>,
}

/// The upgrade: checks the session first, so a dead one is a plain 404/410.
pub async fn upgrade(
    State(state): State<AppState>,
    Path(sid): Path<String>,
    query: Result<Query<WsQuery>, QueryRejection>,
    headers: HeaderMap,
    ws: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    state.sessions().get(&sid)?;
    let Query(query) = query.map_err(|e| ApiError::InvalidQuery(e.body_text()))?;
    let ws = ws.map_err(|e| ApiError::UpgradeRequired(e.body_text()))?;
    let binary = match query.encoding.as_deref() {
        None => wants_binary(&headers),
        Some("json") => false,
        Some("x-pvs") => true,
        Some(other) => {
            return Err(ApiError::InvalidQuery(format!(
                "encoding: '{other}' is not json or x-pvs"
            )));
        }
    };
    let limit = state.limits().body_bytes;
    Ok(ws
        .max_message_size(limit)
        .max_frame_size(limit)
        .on_upgrade(move |socket| serve(state, sid, socket, binary)))
}

/// Answers views until the client closes or the session ends.
async fn serve(state: AppState, sid: String, mut socket: WebSocket, binary: bool) {
    state.metrics().websocket(1);
    while let Some(Ok(message)) = socket.recv().await {
        let body = match message {
            Message::Text(text) => text,
            Message::Binary(_) => {
                let e = ApiError::MalformedJson(
                    "send views as JSON text messages; binary is only for answers".into(),
                );
                if socket.send(error_message(&e)).await.is_err() {
                    break;
                }
                continue;
            }
            Message::Close(_) => break,
            // Pongs are sent for us.
            Message::Ping(_) | Message::Pong(_) => continue,
        };
        let reply = match answer_frame(&state, &sid, body.as_bytes()).await {
            Ok(frame) if binary => Message::Binary(binary::encode_frame(&frame).into()),
            Ok(frame) => Message::Text(
                String::from_utf8(frame.to_json())
                    .expect("JSON is UTF-8")
                    .into(),
            ),
            Err(e) => {
                let ended = matches!(
                    e,
                    ApiError::UnknownSession(_)
                        | ApiError::SessionExpired { .. }
                        | ApiError::SessionEvicted(_)
                );
                if socket.send(error_message(&e)).await.is_err() {
                    break;
                }
                if !ended {
                    continue;
                }
                let _ = socket
                    .send(Message::Close(Some(CloseFrame {
                        code: close_code::POLICY,
                        reason: e.status_and_code().1.into(),
                    })))
                    .await;
                break;
            }
        };
        if socket.send(reply).await.is_err() {
            break;
        }
    }
    state.metrics().websocket(-1);
}

fn error_message(e: &ApiError) -> Message {
    Message::Text(e.body().to_string().into())
}
