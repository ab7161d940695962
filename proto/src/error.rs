//! The error body every refused request gets, whatever was accepted:
//! a 4xx/5xx status and `{"error": {"code", "message"}}`.
//!
//! `code` is stable and machine-readable ([`ErrorCode`], one list for the
//! server, its clients and the OpenAPI document); `message` is for people
//! and names what was wrong (`eye[1] is NaN`).

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// Defines [`ErrorCode`] from one list of `Variant = "wire_name"`, with
/// [`ErrorCode::as_str`] and [`ErrorCode::ALL`]. The wire name is the
/// variant's in snake case (`rename_all`, which serde and the OpenAPI
/// derive both read); `codes_travel_as_their_names` checks that it is
/// the name written here.
macro_rules! error_codes {
    ($($(#[$doc:meta])* $variant:ident = $code:literal,)*) => {
        /// Why a request was refused.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
        #[serde(rename_all = "snake_case")]
        pub enum ErrorCode {
            $($(#[$doc])* $variant,)*
        }

        impl ErrorCode {
            /// Every code, in the order of the document.
            pub const ALL: &[ErrorCode] = &[$(ErrorCode::$variant,)*];

            /// The code as it travels.
            pub fn as_str(self) -> &'static str {
                match self {
                    $(ErrorCode::$variant => $code,)*
                }
            }
        }
    };
}

error_codes! {
    /// 400: the camera cannot be used (a NaN, a zero or parallel direction).
    InvalidView = "invalid_view",
    /// 400: the body is not JSON, or not of the expected shape.
    MalformedJson = "malformed_json",
    /// 413: the body is over the server's limit.
    BodyTooLarge = "body_too_large",
    /// 404: no scene has this id.
    UnknownScene = "unknown_scene",
    /// 400: no method has this name.
    UnknownMethod = "unknown_method",
    /// 400: the scene does not support this method (the message lists those it does).
    UnsupportedMethod = "unsupported_method",
    /// 400: the method has no such option.
    UnknownOption = "unknown_option",
    /// 400: an option's value is out of range or of the wrong kind.
    InvalidOption = "invalid_option",
    /// 404: no route here.
    NotFound = "not_found",
    /// 405: the route exists, not with this HTTP method.
    MethodNotAllowed = "method_not_allowed",
    /// 503: the request took longer than the server's timeout.
    Timeout = "timeout",
    /// 503: the method's device queue is full; try again after `Retry-After` seconds.
    Busy = "busy",
    /// 500: a bug; the details are in the server's log only.
    Internal = "internal",
    /// 404: no session has this id (never made, or deleted).
    UnknownSession = "unknown_session",
    /// 410: the session was idle past the server's limit.
    SessionExpired = "session_expired",
    /// 410: the session was evicted to keep the server within its caps.
    SessionEvicted = "session_evicted",
    /// 404: no walkthrough has this id.
    UnknownWalkthrough = "unknown_walkthrough",
    /// 426: a WebSocket route asked without a WebSocket upgrade.
    UpgradeRequired = "upgrade_required",
    /// 400: the query string is not one the route takes.
    InvalidQuery = "invalid_query",
    /// 401: a route that changes a scene, without the server's admin token (`Authorization: Bearer …`).
    Unauthorized = "unauthorized",
    /// 403: the server has no admin token configured, so nothing may change its scenes.
    Forbidden = "forbidden",
    /// 404: the scene has no object with this id.
    UnknownObject = "unknown_object",
    /// 409: the object is part of the static scene; only objects the file marks movable move.
    StaticObject = "static_object",
    /// 400: the transform has a NaN, an infinity, or a zero scale.
    InvalidTransform = "invalid_transform",
    /// 413: the JSON body nests deeper, or has a longer array, than the server's limits.
    BodyTooComplex = "body_too_complex",
    /// 408: the client took longer than the server's body timeout to send the body.
    BodyTimeout = "body_timeout",
    /// 429: the client sent more requests (or WebSocket messages) than its rate allows; try again after `Retry-After` seconds.
    RateLimited = "rate_limited",
    /// 503: the server has as many connections open as it allows; try again after `Retry-After` seconds.
    Overloaded = "overloaded",
    /// 413: a WebSocket message over the body limit (the close frame's reason).
    MessageTooLarge = "message_too_large",
    /// 422: the scene has no walk of this kind (no free space at eye height, no geometry).
    NoWalk = "no_walk",
    /// 400: the `x-pvsd-route` header is not 16 lowercase hex digits.
    InvalidRoute = "invalid_route",
    /// 503: the replica is not ready: its scenes are still loading, or it is draining before it stops (`GET /healthz/ready`).
    NotReady = "not_ready",
    /// 503: the scene is configured but still loading; try again after `Retry-After` seconds.
    SceneLoading = "scene_loading",
    /// 400: the method cannot answer for a region of views (`radius` or `angle` above 0); the message says why and the method to use instead.
    UnsupportedRegion = "unsupported_region",
}

impl std::fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The body of every 4xx and 5xx answer.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[schema(as = Error)]
pub struct ErrorBody {
    /// What went wrong.
    pub error: ErrorDetail,
}

/// The `error` of an error body.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ErrorDetail {
    /// Stable and machine-readable.
    pub code: ErrorCode,
    /// For people: what was wrong, naming the field or the limit.
    pub message: String,
}

impl ErrorBody {
    /// `{"error": {"code": code, "message": message}}`.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        ErrorBody {
            error: ErrorDetail {
                code,
                message: message.into(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_travel_as_their_names() {
        for &code in ErrorCode::ALL {
            let json = serde_json::to_value(code).unwrap();
            assert_eq!(json, code.as_str());
            assert_eq!(serde_json::from_value::<ErrorCode>(json).unwrap(), code);
        }
        let body = ErrorBody::new(ErrorCode::InvalidView, "eye[1] is NaN");
        assert_eq!(
            serde_json::to_string(&body).unwrap(),
            r#"{"error":{"code":"invalid_view","message":"eye[1] is NaN"}}"#
        );
    }
}
