//! Routing keys: what a load balancer hashes so that every request that
//! needs one replica's memory reaches that replica (`proto/scale-out.md`).
//!
//! Session and walkthrough ids are `<key>-<secret>`: a 16-hex-digit
//! routing key, then 128 random bits (32 hex digits) that make the id
//! unguessable. A proxy in front of several replicas hashes requests to
//! `/sessions/{sid}/…` and `/walkthroughs/{wid}/…` on the key alone
//! (consistent hashing), and a request that makes a session or a
//! walkthrough on a key of its own choosing, which it hands the replica in
//! the [`ROUTE_HEADER`]: the id the replica mints then hashes to the
//! replica that minted it, with no replica knowing the others. A
//! walkthrough's users get sessions minted on the walkthrough's key, so
//! their frames meet on its replica and they can see each other.
//!
//! The key routes; it is no secret and grants nothing. Without the header
//! (one replica, no proxy) a replica draws the key at random.

use axum::http::HeaderMap;
use rand::Rng;

use super::error::ApiError;

/// The request header that carries the routing key a new session or
/// walkthrough is minted on (set by the proxy).
pub const ROUTE_HEADER: &str = "x-pvsd-route";

/// Hex digits of a routing key.
const KEY_DIGITS: usize = 16;
/// Hex digits of the secret that follows it.
const SECRET_DIGITS: usize = 32;

/// A routing key: 16 lowercase hex digits.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RouteKey(String);

impl RouteKey {
    /// A fresh key, 64 random bits.
    pub fn random() -> RouteKey {
        RouteKey(format!("{:016x}", rand::rng().random::<u64>()))
    }

    /// The key a request asks new ids to be minted on: its
    /// [`ROUTE_HEADER`], or a random one when it has none; 400
    /// `invalid_route` naming the header when the value is not 16
    /// lowercase hex digits.
    pub fn of_request(headers: &HeaderMap) -> Result<RouteKey, ApiError> {
        let Some(value) = headers.get(ROUTE_HEADER) else {
            return Ok(RouteKey::random());
        };
        value
            .to_str()
            .ok()
            .filter(|v| is_hex(v, KEY_DIGITS))
            .map(|v| RouteKey(v.to_string()))
            .ok_or_else(|| {
                ApiError::InvalidRoute(format!(
                    "the {ROUTE_HEADER} header must be {KEY_DIGITS} lowercase hex digits"
                ))
            })
    }

    /// The key of a minted id, `None` when `id` is not one.
    pub fn of_id(id: &str) -> Option<RouteKey> {
        let (key, secret) = id.split_once('-')?;
        (is_hex(key, KEY_DIGITS) && is_hex(secret, SECRET_DIGITS)).then(|| RouteKey(key.into()))
    }

    /// A new id on this key: the key, `-`, and 128 random bits from the
    /// thread's CSPRNG (ChaCha, seeded by the OS).
    pub fn mint(&self) -> String {
        format!("{}-{:032x}", self.0, rand::rng().random::<u128>())
    }

    /// The key's digits.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

fn is_hex(s: &str, digits: usize) -> bool {
    s.len() == digits && s.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    #[test]
    fn a_minted_id_carries_its_key_and_a_fresh_secret() {
        let key = RouteKey::random();
        let (a, b) = (key.mint(), key.mint());
        assert_ne!(a, b);
        assert_eq!(a.len(), KEY_DIGITS + 1 + SECRET_DIGITS);
        assert_eq!(RouteKey::of_id(&a), Some(key.clone()));
        assert!(a.starts_with(&format!("{}-", key.as_str())));
    }

    #[test]
    fn only_well_formed_ids_and_headers_are_keys() {
        for id in [
            "",
            "-",
            "0123456789abcdef",
            "0123456789abcdef-",
            "0123456789ABCDEF-0123456789abcdef0123456789abcdef",
            "0123456789abcde-0123456789abcdef0123456789abcdef0",
            "0123456789abcdef-0123456789abcdef0123456789abcdeg",
            "0123456789abcdef-0123456789abcdef0123456789abcdef-",
        ] {
            assert_eq!(RouteKey::of_id(id), None, "{id}");
        }
        let mut headers = HeaderMap::new();
        assert_eq!(RouteKey::of_request(&headers).unwrap().as_str().len(), 16);
        headers.insert(ROUTE_HEADER, HeaderValue::from_static("00ff00ff00ff00ff"));
        assert_eq!(
            RouteKey::of_request(&headers).unwrap().as_str(),
            "00ff00ff00ff00ff"
        );
        for bad in [
            "00ff",
            "00FF00FF00FF00FF",
            "00ff00ff00ff00ff00",
            "zzzzzzzzzzzzzzzz",
        ] {
            headers.insert(ROUTE_HEADER, HeaderValue::from_static(bad));
            let e = RouteKey::of_request(&headers).unwrap_err();
            assert_eq!(e.status_and_code().1, "invalid_route", "{bad}");
            assert!(e.to_string().contains(ROUTE_HEADER));
        }
    }
}
