//! `GET /sessions/{sid}/ws`: a session's frames over a WebSocket.
//!
//! The client sends views as JSON text messages (the body of
//! `POST /sessions/{sid}/frames`); the server answers each, in order, with
//! the frame as JSON text, or as an `application/x-pvs` binary message when
//! the upgrade asked for it (`?encoding=x-pvs` or that `Accept`); with
//! `?stats=true` each frame carries its cull's stats (the web viewer shows
//! them). A bad
//! view gets an error message (`{"error": ...}`) and the socket stays open;
//! a session that ends (deleted, expired) gets its error and a close.
//!
//! Limits: a message over the body limit closes the socket with `1009`
//! (`message_too_large`); when the config sets a message rate, messages
//! over it get a `rate_limited` error and are not answered; shutdown
//! closes every socket with `1001 going away`.
//!
//! Backpressure: one message is read, answered and *sent* before the next
//! is read. A client that stops reading fills its socket's buffers, the
//! send waits, nothing more is read, and the client's own writes stall: the
//! server holds at most one answer per connection. Closing the socket does
//! not end the session.

use axum::extract::rejection::QueryRejection;
use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade, close_code};
use axum::extract::{Extension, Path, Query, State};
use axum::http::HeaderMap;
use axum::response::Response;
use pvsd_proto::xpvs as binary;
use serde::Deserialize;

use pvsd_proto::error::ErrorCode;

use super::error::ApiError;
use super::limit::MessageRate;
use super::listener::ConnectionSlot;
use super::metrics::Refusal;
use super::routes::{answer_frame, wants_binary};
use super::state::AppState;

/// The upgrade's query.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WsQuery {
    /// `json` (default) or `x-pvs`.
    encoding: Option<String>,
    /// Whether frames carry their cull's stats (default false).
    stats: Option<bool>,
}

/// How a socket's answers are written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Encoding {
    /// As `application/x-pvs` binary messages, else JSON text.
    pub binary: bool,
    /// With each frame's stats.
    pub stats: bool,
}

/// The upgrade: checks the session first, so a dead one is a plain 404/410.
pub async fn upgrade(
    State(state): State<AppState>,
    Path(sid): Path<String>,
    query: Result<Query<WsQuery>, QueryRejection>,
    headers: HeaderMap,
    slot: Option<Extension<ConnectionSlot>>,
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
    let encoding = Encoding {
        binary,
        stats: query.stats.unwrap_or(false),
    };
    let limit = state.limits().body_bytes;
    Ok(ws
        .max_message_size(limit)
        .max_frame_size(limit)
        .on_upgrade(move |socket| {
            let tasks = state.lifecycle().tasks.clone();
            // The socket keeps its connection's place under the cap, and
            // shutdown waits for it.
            tasks.track_future(async move {
                let _slot = slot;
                serve(state, sid, socket, encoding).await;
            })
        }))
}

/// What the server does with one message from the client.
#[derive(Debug)]
pub enum Reply {
    /// Send this and read on.
    Send(Message),
    /// Send this error, then close with this frame: the session ended.
    End(Message, CloseFrame),
    /// Nothing to send (a ping or pong; pongs are sent for us).
    Nothing,
    /// The client closed.
    Closed,
}

/// The reply to one message on session `sid`'s socket: a view (JSON text)
/// gets its frame (written as `encoding` says), anything else a named error.
/// Messages over `rate`, when there is one, are refused without being
/// read. The socket's loop and the fuzzer both go through here.
pub async fn reply(
    state: &AppState,
    sid: &str,
    message: Message,
    encoding: Encoding,
    rate: Option<&MessageRate>,
) -> Reply {
    let body = match message {
        Message::Text(text) => text,
        Message::Binary(_) => {
            return Reply::Send(error_message(&ApiError::MalformedJson(
                "send views as JSON text messages; binary is only for answers".into(),
            )));
        }
        Message::Close(_) => return Reply::Closed,
        Message::Ping(_) | Message::Pong(_) => return Reply::Nothing,
    };
    if let Some(Err(e)) = rate.map(MessageRate::check) {
        state.metrics().refused(Refusal::WebSocketRate);
        return Reply::Send(error_message(&e));
    }
    match answer_frame(state, sid, body.as_bytes(), encoding.stats).await {
        Ok(frame) if encoding.binary => {
            Reply::Send(Message::Binary(binary::encode_frame(&frame).into()))
        }
        Ok(frame) => Reply::Send(Message::Text(
            String::from_utf8(frame.to_json())
                .expect("JSON is UTF-8")
                .into(),
        )),
        Err(
            e @ (ApiError::UnknownSession(_)
            | ApiError::SessionExpired { .. }
            | ApiError::SessionEvicted(_)),
        ) => Reply::End(
            error_message(&e),
            CloseFrame {
                code: close_code::POLICY,
                reason: e.status_and_code().1.into(),
            },
        ),
        Err(e) => Reply::Send(error_message(&e)),
    }
}

/// Answers views until the client closes, the session ends, or the server
/// shuts down (a close frame `1001 going away`).
async fn serve(state: AppState, sid: String, mut socket: WebSocket, encoding: Encoding) {
    state.metrics().websocket(1);
    let rate = state.limits().websocket_rate.map(MessageRate::new);
    let shutdown = state.lifecycle().shutdown.clone();
    loop {
        let received = tokio::select! {
            received = socket.recv() => received,
            () = shutdown.cancelled() => {
                let _ = socket
                    .send(Message::Close(Some(CloseFrame {
                        code: close_code::AWAY,
                        reason: "server shutting down".into(),
                    })))
                    .await;
                break;
            }
        };
        let message = match received {
            Some(Ok(message)) => message,
            Some(Err(e)) => {
                if is_too_large(&e) {
                    state.metrics().refused(Refusal::WebSocketSize);
                    let limit = state.limits().body_bytes;
                    let _ = socket
                        .send(Message::Close(Some(CloseFrame {
                            code: close_code::SIZE,
                            reason: format!(
                                "{}: messages are at most {limit} bytes",
                                ErrorCode::MessageTooLarge
                            )
                            .into(),
                        })))
                        .await;
                }
                break;
            }
            None => break,
        };
        let sent = match reply(&state, &sid, message, encoding, rate.as_ref()).await {
            Reply::Send(m) => socket.send(m).await.is_ok(),
            Reply::End(m, close) => {
                if socket.send(m).await.is_ok() {
                    let _ = socket.send(Message::Close(Some(close))).await;
                }
                false
            }
            Reply::Nothing => true,
            Reply::Closed => false,
        };
        if !sent {
            break;
        }
    }
    state.metrics().websocket(-1);
}

/// Whether the socket failed on a message or frame over the size limit.
fn is_too_large(e: &axum::Error) -> bool {
    use std::error::Error as _;
    let mut source = e.source();
    while let Some(s) = source {
        if let Some(tungstenite::Error::Capacity(_)) = s.downcast_ref::<tungstenite::Error>() {
            return true;
        }
        source = s.source();
    }
    false
}

fn error_message(e: &ApiError) -> Message {
    Message::Text(e.body().to_string().into())
}
