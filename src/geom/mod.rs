//! Geometry: boxes, planes, cameras, frusta and convex polygons.
//!
//! Scene data is `f32` relative to a scene origin; everything a camera
//! produces (planes, frusta) is `f64`, so precision is lost neither far from
//! the world origin nor at extreme near/far ratios.

mod aabb;
mod camera;
mod frustum;
mod plane;
mod polygon;
mod region;
mod round;

pub use aabb::Aabb;
pub use camera::{
    Camera, CameraBasis, CameraError, MAX_HALF_TANGENT, PARALLEL_TOLERANCE, direction,
};
pub use frustum::{ALL_PLANES, Frustum, PlaneMask};
pub use plane::{Plane, Side};
pub use polygon::{ConvexPolygon, Split};
pub use region::{MAX_RADIUS, MAX_WIDENED, Region};
pub use round::{ceil_i64, floor_i64, greater, lesser, ordered_bits};
