//! Request bodies: [`RawBody`] reads the bytes (within the body limit) and
//! [`parse`] turns them into a type; both fail with [`ApiError`]s that say
//! where. They are two steps so a handler can check the path (is there such
//! a scene?) before it judges the body.
//!
//! Parsing differs from `axum::Json` in three ways, each for a client's sake:
//! - errors name the field (`eye: invalid length 2, expected an array of
//!   length 3`) through `serde_path_to_error`;
//! - the bare tokens `NaN`, `Infinity` and `-Infinity`, which JavaScript-style
//!   encoders (Python's `json` among them) write for non-finite numbers, are
//!   read as numbers, so the client hears "eye[1] is NaN" and not "expected
//!   value at column 12";
//! - the `Content-Type` is not insisted on (`curl -d` sends a form type).

use axum::body::Bytes;
use axum::extract::{FromRequest, Request};
use axum::http::StatusCode;
use serde::de::DeserializeOwned;

use super::error::ApiError;

/// A request body, read whole within the body limit.
#[derive(Debug)]
pub struct RawBody(pub Bytes);

impl<S: Send + Sync> FromRequest<S> for RawBody {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        let limit = req.extensions().get::<BodyLimit>().map_or(0, |l| l.0);
        let bytes = Bytes::from_request(req, state).await.map_err(|r| {
            if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
                ApiError::BodyTooLarge { limit }
            } else {
                ApiError::MalformedJson(format!("cannot read the body: {r}"))
            }
        })?;
        Ok(RawBody(bytes))
    }
}

/// The body limit in force, put in request extensions by the router so the
/// error can quote it.
#[derive(Clone, Copy, Debug)]
pub struct BodyLimit(pub usize);

/// Parses `bytes` as `T`, naming the failing path.
pub fn parse<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, ApiError> {
    let relaxed = relax_non_finite(bytes);
    let input = relaxed.as_deref().unwrap_or(bytes);
    let de = &mut serde_json::Deserializer::from_slice(input);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        if path == "." || inner.is_syntax() || inner.is_eof() {
            ApiError::MalformedJson(format!("body is not valid JSON: {inner}"))
        } else {
            ApiError::MalformedJson(format!("{path}: {inner}"))
        }
    })
}

/// Rewrites bare `NaN`, `Infinity` and `-Infinity` outside strings into the
/// strings `"NaN"`, `"Infinity"`, `"-Infinity"`, which [`pvsd_proto::json::Number`]
/// reads. `None` when there is none (the common case: no copy).
fn relax_non_finite(bytes: &[u8]) -> Option<Vec<u8>> {
    const TOKENS: [&[u8]; 3] = [b"-Infinity", b"Infinity", b"NaN"];
    let mut out: Option<Vec<u8>> = None;
    let (mut in_string, mut escaped) = (false, false);
    let mut i = 0;
    while i < bytes.len() {
        let b = bytes[i];
        if in_string {
            if escaped {
                escaped = false;
            } else if b == b'\\' {
                escaped = true;
            } else if b == b'"' {
                in_string = false;
            }
        } else if b == b'"' {
            in_string = true;
        } else if let Some(t) = TOKENS.iter().find(|t| bytes[i..].starts_with(t)) {
            let o = out.get_or_insert_with(|| bytes[..i].to_vec());
            o.push(b'"');
            o.extend_from_slice(t);
            o.push(b'"');
            i += t.len();
            continue;
        }
        if let Some(o) = out.as_mut() {
            o.push(b);
        }
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relaxes_only_outside_strings() {
        let got =
            relax_non_finite(br#"{"a":[NaN,-Infinity,Infinity],"s":"NaN \" Infinity"}"#).unwrap();
        assert_eq!(
            std::str::from_utf8(&got).unwrap(),
            r#"{"a":["NaN","-Infinity","Infinity"],"s":"NaN \" Infinity"}"#
        );
        assert!(relax_non_finite(br#"{"a":[1,2],"s":"NaN"}"#).is_none());
    }
}
