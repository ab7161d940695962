//! The tolerances the occlusion methods' conservativeness rests on, named
//! once, each with what it guards and why its value is safe.
//!
//! The rule behind all of them: a tolerance may only make a method find
//! *more* visible. A point within the plane tolerance of a plane counts as
//! on both sides; an occluder part too small to trust is not used; an
//! occluder seen almost edge-on is not picked. None of them can turn a
//! visible box into a hidden one.

use glam::DVec3;

use crate::scene::Scene;

/// The plane tolerance's share of the scene's size plus the eye's distance
/// from the scene origin. Plane tests are computed in `f64` on scene-local
/// coordinates (f32 inputs): their rounding is a few `f64` ulps of those
/// magnitudes (~1e-16 relative), so 1e-9 of them is a margin of ~10⁷
/// roundings, while staying far below anything a camera can resolve (1 nm
/// in a 1 km scene).
pub const PLANE_TOLERANCE_RELATIVE: f64 = 1e-9;

/// The plane tolerance's floor, for a scene of zero size seen from its
/// origin: keeps the tolerance positive, so "on the plane" is never an
/// exact floating-point comparison.
pub const PLANE_TOLERANCE_FLOOR: f64 = 1e-12;

/// The distance within which a point counts as on a plane, for views from
/// `eye` (scene-local) in `scene`: points that close are taken to lie on
/// both sides, which can only find more visible.
pub fn plane_tolerance(scene: &Scene, eye: DVec3) -> f64 {
    PLANE_TOLERANCE_RELATIVE * (scene.bounds().extent().length() as f64 + eye.length())
        + PLANE_TOLERANCE_FLOOR
}

/// An occluder part whose longest edge is shorter than this many plane
/// tolerances is not used. Shadow planes through the eye and the edges of a
/// part barely larger than the tolerance can be tilted, or flipped, by the
/// rounding of their normals; a thousand tolerances keep that tilt below
/// 1e-3 rad. Not using an occluder is always safe.
pub const MIN_TRUSTED_SPAN: f64 = 1e3;

/// Whether the polygon `vertices` is too small for its shadow planes to be
/// trusted at plane tolerance `eps` ([`MIN_TRUSTED_SPAN`]).
pub fn too_small_to_trust(vertices: &[DVec3], eps: f64) -> bool {
    let n = vertices.len();
    let span = (0..n)
        .map(|i| vertices[i].distance(vertices[(i + 1) % n]))
        .fold(0.0, f64::max);
    span < MIN_TRUSTED_SPAN * eps
}

/// An occluder is not picked when the eye lies within this share of its
/// distance (plus one unit) from the occluder's plane: seen that edge-on it
/// hides nothing, and its shadow planes would be near-degenerate. Skipping
/// an occluder is always safe.
pub const EDGE_ON_TOLERANCE: f64 = 1e-9;
