//! Request bodies: [`RawBody`] reads the bytes (within the body limit and
//! the body timeout) and
//! [`parse`] turns them into a type; both fail with [`ApiError`]s that say
//! where. They are two steps so a handler can check the path (is there such
//! a scene?) before it judges the body.
//!
//! Parsing differs from `axum::Json` in four ways, each for a client's sake
//! or the server's:
//! - nesting and array lengths are bounded ([`JsonLimits`]) before the
//!   parser builds anything;
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
use super::state::{AppState, JsonLimits};

/// A request body, read whole within the body limit and the body timeout.
#[derive(Debug)]
pub struct RawBody(pub Bytes);

impl FromRequest<AppState> for RawBody {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &AppState) -> Result<Self, Self::Rejection> {
        let limits = state.limits();
        let timeout = limits.connections.body_timeout;
        let read = Bytes::from_request(req, state);
        let bytes = tokio::time::timeout(timeout, read)
            .await
            .map_err(|_| ApiError::BodyTimeout {
                ms: timeout.as_millis() as u64,
            })?
            .map_err(|r| {
                if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
                    ApiError::BodyTooLarge {
                        limit: limits.body_bytes,
                    }
                } else {
                    ApiError::MalformedJson(format!("cannot read the body: {r}"))
                }
            })?;
        Ok(RawBody(bytes))
    }
}

/// Parses `bytes` as `T` within `limits`, naming the failing path.
pub fn parse<T: DeserializeOwned>(bytes: &[u8], limits: JsonLimits) -> Result<T, ApiError> {
    let relaxed = scan(bytes, limits)?;
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

/// One pass over the body before it is parsed: refuses nesting deeper than
/// `limits.max_depth` and arrays longer than `limits.max_array` (the
/// parser would build them before any field could be refused), and
/// rewrites bare `NaN`, `Infinity` and `-Infinity` outside strings into the
/// strings `"NaN"`, `"Infinity"`, `"-Infinity"`, which
/// [`pvsd_proto::json::Number`] reads. `None` when nothing is rewritten
/// (the common case: no copy). Malformed JSON passes; the parser names it.
fn scan(bytes: &[u8], limits: JsonLimits) -> Result<Option<Vec<u8>>, ApiError> {
    const TOKENS: [&[u8]; 3] = [b"-Infinity", b"Infinity", b"NaN"];
    let mut out: Option<Vec<u8>> = None;
    let (mut in_string, mut escaped) = (false, false);
    // The open arrays and objects: for an array, its items so far.
    let mut open: Vec<Option<usize>> = Vec::new();
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
        } else {
            match b {
                b'"' => in_string = true,
                b'[' | b'{' => {
                    if open.len() == limits.max_depth {
                        return Err(ApiError::BodyTooComplex(format!(
                            "the body nests arrays and objects deeper than {} levels",
                            limits.max_depth
                        )));
                    }
                    open.push((b == b'[').then_some(0));
                }
                b']' | b'}' => {
                    open.pop();
                }
                b',' => {
                    if let Some(Some(items)) = open.last_mut() {
                        *items += 1;
                        // n commas separate n + 1 items.
                        if *items >= limits.max_array {
                            return Err(ApiError::BodyTooComplex(format!(
                                "an array in the body has more than {} items",
                                limits.max_array
                            )));
                        }
                    }
                }
                _ => {
                    if let Some(t) = TOKENS.iter().find(|t| bytes[i..].starts_with(t)) {
                        let o = out.get_or_insert_with(|| bytes[..i].to_vec());
                        o.push(b'"');
                        o.extend_from_slice(t);
                        o.push(b'"');
                        i += t.len();
                        continue;
                    }
                }
            }
        }
        if let Some(o) = out.as_mut() {
            o.push(b);
        }
        i += 1;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relaxes_only_outside_strings() {
        let limits = JsonLimits::default();
        let got = scan(
            br#"{"a":[NaN,-Infinity,Infinity],"s":"NaN \" Infinity"}"#,
            limits,
        )
        .unwrap()
        .unwrap();
        assert_eq!(
            std::str::from_utf8(&got).unwrap(),
            r#"{"a":["NaN","-Infinity","Infinity"],"s":"NaN \" Infinity"}"#
        );
        assert!(scan(br#"{"a":[1,2],"s":"NaN"}"#, limits).unwrap().is_none());
    }

    #[test]
    fn refuses_deep_nesting_and_long_arrays_but_not_brackets_in_strings() {
        let limits = JsonLimits {
            max_depth: 3,
            max_array: 4,
        };
        assert!(scan(br#"{"a":[[1]]}"#, limits).is_ok());
        let deep = scan(br#"{"a":[[[1]]]}"#, limits).unwrap_err();
        assert!(deep.to_string().contains("deeper than 3 levels"), "{deep}");
        assert!(scan(br#"{"a":[1,2,3,4],"b":[1,2,3,4]}"#, limits).is_ok());
        let long = scan(br#"{"a":[1,2,3,4,5]}"#, limits).unwrap_err();
        assert!(long.to_string().contains("more than 4 items"), "{long}");
        // Commas of objects and of strings are not items.
        assert!(scan(br#"{"a":1,"b":2,"c":3,"d":4,"e":"[[[[,,,,,"}"#, limits).is_ok());
        assert_eq!(long.status_and_code().1, "body_too_complex");
    }
}
