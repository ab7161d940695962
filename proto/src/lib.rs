//! pvsd's wire protocol: everything a client and the server must agree on,
//! and nothing else (no geometry, no HTTP stack). The server and `loadtest`
//! both depend on it; a thin client in Rust would too.
//!
//! # Layout
//!
//! - [`json`]: the JSON bodies of the HTTP API (views, answers, sessions,
//!   walkthroughs, scene listings).
//! - [`error`]: the error body and its stable codes.
//! - [`xpvs`]: the `application/x-pvs` binary encoding of id sets and
//!   frames, specified in `proto/wire-format.md`.
//! - [`mesh`]: the `application/x-pvs-mesh` encoding of objects'
//!   triangles, specified in `proto/mesh-format.md`.
//! - [`delta`]: frame deltas (`diff`) and the encoded id sets a session
//!   keeps (`IdSet`).
//! - [`openapi`]: the OpenAPI document, generated from the types above;
//!   `proto/openapi.json` is its committed copy.

pub mod delta;
pub mod error;
pub mod json;
pub mod mesh;
pub mod openapi;
pub mod xpvs;
