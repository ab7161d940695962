//! pvsd: a visibility server.
//!
//! # Layout
//! Data flows one way, top to bottom:
//! - [`geom`]: boxes, planes, cameras, frusta, convex polygons.
//! - [`scene`]: the scene model, the glTF loader and writer, generators.
//! - [`spatial`]: the kd-tree over a scene's objects.
//! - [`cull`]: the one trait every culling method implements, and the methods.
//! - [`truth`]: ground truth, by rendering every triangle with its object id.
//! - [`eval`]: walkthroughs, and every method's speed against its accuracy.
//! - [`server`]: the HTTP service (axum): routes, scene registry, metrics.
//!
//! `docs/ARCHITECTURE.md` is the map: the flow of a request and the invariants.

pub mod cull;
pub mod eval;
pub mod geom;
pub mod scene;
pub mod server;
pub mod spatial;
pub mod truth;
