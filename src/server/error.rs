//! Errors as clients see them: a status and `{"error": {"code", "message"}}`
//! (`pvsd_proto::error`, whose [`ErrorCode`]s are the stable codes).
//!
//! Every handler returns `Result<_, ApiError>`; internals are logged, never
//! sent. A bad request never panics and never changes shared state.

use axum::Json;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use pvsd_proto::error::{ErrorBody, ErrorCode};

use crate::cull::{CullError, MethodError, Unanswered};
use crate::geom::CameraError;
use crate::scene::MoveError;

/// Everything a request can fail with.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// The camera cannot be used (`eye[1] is NaN`, `up is parallel to forward`).
    #[error("{0}")]
    InvalidView(String),
    /// The body is not JSON, or not of the expected shape (the path is named).
    #[error("{0}")]
    MalformedJson(String),
    /// The body is over the configured limit.
    #[error("request body is larger than the limit of {limit} bytes")]
    BodyTooLarge {
        /// The limit in force.
        limit: usize,
    },
    /// No scene has this id.
    #[error("no scene '{id}'; loaded scenes: {}", loaded.join(", "))]
    UnknownScene {
        /// What the client asked for.
        id: String,
        /// What is loaded.
        loaded: Vec<String>,
    },
    /// No session has this id (never made, or deleted).
    #[error("no session '{0}' (never made, or deleted)")]
    UnknownSession(String),
    /// The session was idle past the configured time and is gone.
    #[error("session '{id}' expired after {idle_s} s without a frame; make a new one")]
    SessionExpired {
        /// The session id.
        id: String,
        /// The idle limit in force, seconds.
        idle_s: u64,
    },
    /// The session was evicted to keep the server within its session caps.
    #[error(
        "session '{0}' was evicted: the server's cap on sessions or their memory was reached; make a new one"
    )]
    SessionEvicted(String),
    /// A WebSocket route asked without a valid upgrade.
    #[error("this route speaks WebSocket: {0}")]
    UpgradeRequired(String),
    /// The query string is not one the route takes.
    #[error("{0}")]
    InvalidQuery(String),
    /// No walkthrough has this id.
    #[error("no walkthrough '{0}' (never made, or idle past the session time limit)")]
    UnknownWalkthrough(String),
    /// The method or its options were refused.
    #[error(transparent)]
    Method(#[from] MethodError),
    /// No route here.
    #[error("no route for {method} {path}")]
    NoRoute {
        /// The HTTP method.
        method: String,
        /// The path asked.
        path: String,
    },
    /// The route exists but not with this HTTP method.
    #[error("{method} is not allowed on {path}")]
    MethodNotAllowed {
        /// The HTTP method.
        method: String,
        /// The path asked.
        path: String,
    },
    /// The request took longer than the configured timeout.
    #[error("the request took longer than {ms} ms")]
    Timeout {
        /// The timeout in force.
        ms: u64,
    },
    /// The method cannot take more work now; come back after the pause.
    #[error("method '{method}' is busy; retry after {retry_after_s} s")]
    Busy {
        /// The method.
        method: String,
        /// Seconds to wait (the `Retry-After` header).
        retry_after_s: u64,
    },
    /// A route that changes a scene, without the admin token.
    #[error("{0}")]
    Unauthorized(String),
    /// The server has no admin token, so no one may change its scenes.
    #[error("changing scenes is off: the server's config has no admin_token (set one to allow it)")]
    Forbidden,
    /// The object was not moved.
    #[error(transparent)]
    Move(#[from] MoveError),
    /// The JSON body is deeper or wider than the limits.
    #[error("{0}")]
    BodyTooComplex(String),
    /// The body came slower than the body timeout allows.
    #[error("the request body did not arrive within {ms} ms")]
    BodyTimeout {
        /// The timeout in force.
        ms: u64,
    },
    /// The client is over its request (or message) rate.
    #[error(
        "too many requests from this client: the limit is {per_s} a second; retry after {retry_after_s} s"
    )]
    RateLimited {
        /// The rate in force.
        per_s: f64,
        /// Seconds to wait (the `Retry-After` header).
        retry_after_s: u64,
    },
    /// The scene has no walk of the kind asked.
    #[error(transparent)]
    Walk(#[from] crate::eval::WalkError),
    /// The server has as many connections as it allows.
    #[error("the server has {max} connections open, its limit; retry after 1 s")]
    Overloaded {
        /// The limit in force.
        max: usize,
    },
    /// The routing key header is malformed.
    #[error("{0}")]
    InvalidRoute(String),
    /// The replica is loading or draining (`GET /healthz/ready`).
    #[error("{0}")]
    NotReady(String),
    /// The scene is configured but not loaded yet.
    #[error("scene '{0}' is still loading; retry after 1 s")]
    SceneLoading(String),
    /// A bug or an unexpected failure; details go to the log only.
    #[error("internal error")]
    Internal(String),
}

impl From<CameraError> for ApiError {
    fn from(e: CameraError) -> Self {
        ApiError::InvalidView(e.to_string())
    }
}

impl From<CullError> for ApiError {
    fn from(e: CullError) -> Self {
        match e {
            CullError::Busy {
                method,
                retry_after,
            } => ApiError::Busy {
                method: method.to_string(),
                // Whole seconds, at least one: what `Retry-After` can say.
                retry_after_s: retry_after.as_secs_f64().ceil().max(1.0) as u64,
            },
            failed @ CullError::Failed { .. } => ApiError::Internal(failed.to_string()),
        }
    }
}

impl From<Unanswered> for ApiError {
    fn from(u: Unanswered) -> Self {
        u.error.into()
    }
}

impl ApiError {
    /// The status and the stable machine-readable code.
    pub fn status_and_code(&self) -> (StatusCode, &'static str) {
        let (status, code) = self.status_and_error_code();
        (status, code.as_str())
    }

    /// The status and the code, typed.
    pub fn status_and_error_code(&self) -> (StatusCode, ErrorCode) {
        match self {
            ApiError::InvalidView(_) => (StatusCode::BAD_REQUEST, ErrorCode::InvalidView),
            ApiError::MalformedJson(_) => (StatusCode::BAD_REQUEST, ErrorCode::MalformedJson),
            ApiError::BodyTooLarge { .. } => {
                (StatusCode::PAYLOAD_TOO_LARGE, ErrorCode::BodyTooLarge)
            }
            ApiError::UnknownScene { .. } => (StatusCode::NOT_FOUND, ErrorCode::UnknownScene),
            ApiError::UnknownSession(_) => (StatusCode::NOT_FOUND, ErrorCode::UnknownSession),
            ApiError::SessionExpired { .. } => (StatusCode::GONE, ErrorCode::SessionExpired),
            ApiError::SessionEvicted(_) => (StatusCode::GONE, ErrorCode::SessionEvicted),
            ApiError::UpgradeRequired(_) => {
                (StatusCode::UPGRADE_REQUIRED, ErrorCode::UpgradeRequired)
            }
            ApiError::InvalidQuery(_) => (StatusCode::BAD_REQUEST, ErrorCode::InvalidQuery),
            ApiError::UnknownWalkthrough(_) => {
                (StatusCode::NOT_FOUND, ErrorCode::UnknownWalkthrough)
            }
            ApiError::Method(e) => match e {
                MethodError::Unknown { .. } => (StatusCode::BAD_REQUEST, ErrorCode::UnknownMethod),
                MethodError::Unsupported { .. } => {
                    (StatusCode::BAD_REQUEST, ErrorCode::UnsupportedMethod)
                }
                MethodError::UnknownOption { .. } => {
                    (StatusCode::BAD_REQUEST, ErrorCode::UnknownOption)
                }
                MethodError::InvalidOption { .. } | MethodError::Malformed { .. } => {
                    (StatusCode::BAD_REQUEST, ErrorCode::InvalidOption)
                }
                MethodError::NotRebuilt { .. } => {
                    (StatusCode::INTERNAL_SERVER_ERROR, ErrorCode::Internal)
                }
                MethodError::NoRegions { .. } => {
                    (StatusCode::BAD_REQUEST, ErrorCode::UnsupportedRegion)
                }
            },
            ApiError::NoRoute { .. } => (StatusCode::NOT_FOUND, ErrorCode::NotFound),
            ApiError::MethodNotAllowed { .. } => {
                (StatusCode::METHOD_NOT_ALLOWED, ErrorCode::MethodNotAllowed)
            }
            ApiError::Timeout { .. } => (StatusCode::SERVICE_UNAVAILABLE, ErrorCode::Timeout),
            ApiError::Busy { .. } => (StatusCode::SERVICE_UNAVAILABLE, ErrorCode::Busy),
            ApiError::Unauthorized(_) => (StatusCode::UNAUTHORIZED, ErrorCode::Unauthorized),
            ApiError::Forbidden => (StatusCode::FORBIDDEN, ErrorCode::Forbidden),
            ApiError::Move(e) => match e {
                MoveError::Unknown(_) => (StatusCode::NOT_FOUND, ErrorCode::UnknownObject),
                MoveError::Static(_) => (StatusCode::CONFLICT, ErrorCode::StaticObject),
                MoveError::Transform(_) => (StatusCode::BAD_REQUEST, ErrorCode::InvalidTransform),
            },
            ApiError::BodyTooComplex(_) => {
                (StatusCode::PAYLOAD_TOO_LARGE, ErrorCode::BodyTooComplex)
            }
            ApiError::BodyTimeout { .. } => (StatusCode::REQUEST_TIMEOUT, ErrorCode::BodyTimeout),
            ApiError::RateLimited { .. } => (StatusCode::TOO_MANY_REQUESTS, ErrorCode::RateLimited),
            ApiError::Overloaded { .. } => (StatusCode::SERVICE_UNAVAILABLE, ErrorCode::Overloaded),
            ApiError::Walk(_) => (StatusCode::UNPROCESSABLE_ENTITY, ErrorCode::NoWalk),
            ApiError::InvalidRoute(_) => (StatusCode::BAD_REQUEST, ErrorCode::InvalidRoute),
            ApiError::NotReady(_) => (StatusCode::SERVICE_UNAVAILABLE, ErrorCode::NotReady),
            ApiError::SceneLoading(_) => (StatusCode::SERVICE_UNAVAILABLE, ErrorCode::SceneLoading),
            ApiError::Internal(_) => (StatusCode::INTERNAL_SERVER_ERROR, ErrorCode::Internal),
        }
    }
}

impl ApiError {
    /// The JSON body clients get, `{"error": {"code", "message"}}`; logs
    /// the details of an internal error, which the body does not carry.
    pub fn body(&self) -> serde_json::Value {
        let code = self.status_and_error_code().1;
        if let ApiError::Internal(detail) = self {
            tracing::error!(%detail, "internal error");
        } else {
            tracing::debug!(%code, message = %self, "request refused");
        }
        serde_json::to_value(ErrorBody::new(code, self.to_string()))
            .expect("an error body serializes")
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let (status, code) = self.status_and_error_code();
        let mut response = (status, Json(self.body())).into_response();
        // For the metrics layer, which counts refusals by code.
        response.extensions_mut().insert(code);
        match self {
            ApiError::Busy { retry_after_s, .. } | ApiError::RateLimited { retry_after_s, .. } => {
                response
                    .headers_mut()
                    .insert(header::RETRY_AFTER, HeaderValue::from(retry_after_s));
            }
            ApiError::SceneLoading(_) => {
                response
                    .headers_mut()
                    .insert(header::RETRY_AFTER, HeaderValue::from(1));
            }
            ApiError::Overloaded { .. } => {
                let headers = response.headers_mut();
                headers.insert(header::RETRY_AFTER, HeaderValue::from(1));
                headers.insert(header::CONNECTION, HeaderValue::from_static("close"));
            }
            ApiError::BodyTimeout { .. } => {
                // The rest of the body is unread: the connection cannot
                // carry another request.
                response
                    .headers_mut()
                    .insert(header::CONNECTION, HeaderValue::from_static("close"));
            }
            ApiError::Unauthorized(_) => {
                response.headers_mut().insert(
                    header::WWW_AUTHENTICATE,
                    HeaderValue::from_static("Bearer realm=\"pvsd\""),
                );
            }
            _ => {}
        }
        response
    }
}
