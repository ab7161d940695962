//! View frusta as six inward-facing planes, and plane-mask box tests.
//!
//! A frustum is built in *scene-local* coordinates: the scene's `f64` origin
//! is subtracted from the `f64` eye first (camera-relative setup), so a scene
//! and camera both translated by 1e7 units give the same planes as untranslated.
//!
//! The plane mask follows hierarchical culling (Bittner et al. §5.3; also
//! Assarsson–Möller): a plane that a node's box lies wholly inside is dropped
//! for that node's descendants, since their boxes lie inside the node's box.
//!
//! The six planes alone accept some boxes near the frustum's edges that do
//! not touch it. [`Frustum::classify_exact`] completes them to an exact
//! separating-axis test of two convex polyhedra: the frustum's face normals,
//! the box's axes, and the cross products of the frustum's six edge
//! directions with the box's three. The frustum's extent along each axis is
//! computed once per view, so a box costs only its own projections.

use glam::{DMat4, DVec3};

use super::{Aabb, Camera, CameraError, Plane, Side};

/// A set of the six frustum planes, one bit each (bit `i` = `Frustum::planes()[i]`).
pub type PlaneMask = u8;

/// Every plane of a frustum.
pub const ALL_PLANES: PlaneMask = 0b11_1111;

/// The region seen by a perspective camera, between its near and far planes.
///
/// Plane order: near, far, left, right, bottom, top. Normals point inward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    planes: [Plane; 6],
    /// Corners: bit 0 = right, bit 1 = top, bit 2 = far.
    corners: [DVec3; 8],
    /// Smallest and largest corner coordinate per world axis.
    corner_min: DVec3,
    corner_max: DVec3,
    /// The 18 edge × box-axis separating axes with the frustum's extent on each.
    cross: [Projection; 18],
}

/// A separating axis and the frustum's interval along it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Projection {
    axis: DVec3,
    lo: f64,
    hi: f64,
    /// Rounding allowance: a gap smaller than this does not separate.
    tol: f64,
}

/// Relative rounding allowance of the separating-axis test. Projections are
/// a few `f64` products (error ~1e-16 of their magnitude); 1e-12 of the
/// magnitude keeps a box that touches the frustum from being called apart
/// by rounding, at the cost of accepting boxes within that sliver.
const SAT_TOLERANCE: f64 = 1e-12;

impl Frustum {
    pub(super) fn from_planes_and_corners(
        planes: [Plane; 6],
        corners: [DVec3; 8],
    ) -> Option<Frustum> {
        if corners.iter().any(|c| !c.is_finite()) {
            return None;
        }
        let corner_min = corners
            .iter()
            .copied()
            .fold(DVec3::splat(f64::INFINITY), DVec3::min);
        let corner_max = corners
            .iter()
            .copied()
            .fold(DVec3::splat(f64::NEG_INFINITY), DVec3::max);
        let edges = [
            corners[1] - corners[0],
            corners[2] - corners[0],
            corners[4] - corners[0],
            corners[5] - corners[1],
            corners[6] - corners[2],
            corners[7] - corners[3],
        ];
        let reach = corners.iter().map(|c| c.length()).fold(0.0, f64::max);
        let mut cross = [Projection {
            axis: DVec3::ZERO,
            lo: f64::NEG_INFINITY,
            hi: f64::INFINITY,
            tol: 0.0,
        }; 18];
        for (i, e) in edges.iter().enumerate() {
            for (j, a) in [DVec3::X, DVec3::Y, DVec3::Z].iter().enumerate() {
                // A zero axis (edge along a box axis) separates nothing: keep the
                // infinite interval, which never separates either.
                let Some(axis) = e.cross(*a).try_normalize() else {
                    continue;
                };
                let (lo, hi) = corners
                    .iter()
                    .map(|c| axis.dot(*c))
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), d| {
                        (l.min(d), h.max(d))
                    });
                cross[i * 3 + j] = Projection {
                    axis,
                    lo,
                    hi,
                    tol: SAT_TOLERANCE * reach,
                };
            }
        }
        Some(Frustum {
            planes,
            corners,
            corner_min,
            corner_max,
            cross,
        })
    }
}

impl Frustum {
    /// The frustum of `camera`, in coordinates relative to `origin`.
    ///
    /// Fails like [`Camera::validate`] on a camera that has no frustum.
    pub fn from_camera(camera: &Camera, origin: DVec3) -> Result<Frustum, CameraError> {
        camera.validate()?;
        // Validation leaves only cameras whose numbers are finite but may be
        // huge (an eye at 1e300, far = 1e308): those fail here, by name.
        let out_of_range = |field: &str| CameraError {
            field: field.into(),
            problem: "puts the frustum out of the range of f64".into(),
        };
        let basis = camera.basis().ok_or_else(|| out_of_range("up"))?;
        let eye = camera.eye - origin;
        let (tx, ty) = camera.half_tangents();
        let f = basis.forward;
        let plane = |p: DVec3, n: DVec3| {
            Plane::from_point_normal(p, n).filter(|pl| pl.normal.is_finite() && pl.d.is_finite())
        };
        let planes = [
            plane(eye + f * camera.near, f).ok_or_else(|| out_of_range("eye"))?,
            plane(eye + f * camera.far, -f).ok_or_else(|| out_of_range("far"))?,
            plane(eye, f * tx + basis.right).ok_or_else(|| out_of_range("eye"))?,
            plane(eye, f * tx - basis.right).ok_or_else(|| out_of_range("eye"))?,
            plane(eye, f * ty + basis.up).ok_or_else(|| out_of_range("eye"))?,
            plane(eye, f * ty - basis.up).ok_or_else(|| out_of_range("eye"))?,
        ];
        let corners = std::array::from_fn(|i| {
            let d = if i & 4 == 0 { camera.near } else { camera.far };
            let x = if i & 1 == 0 { -tx } else { tx };
            let y = if i & 2 == 0 { -ty } else { ty };
            eye + (f + basis.right * x + basis.up * y) * d
        });
        Frustum::from_planes_and_corners(planes, corners).ok_or_else(|| out_of_range("far"))
    }

    /// The frustum of a `clip_from_world` matrix with depth in `[0, 1]`
    /// (Vulkan, wgpu, `glam::DMat4::perspective_rh`), by Gribb–Hartmann plane
    /// extraction. `None` when a plane degenerates.
    pub fn from_clip_from_world(m: DMat4) -> Option<Frustum> {
        let r = |i: usize| m.row(i);
        let (r0, r1, r2, r3) = (r(0), r(1), r(2), r(3));
        let plane = |v: glam::DVec4| Plane::from_coefficients(v.x, v.y, v.z, v.w);
        let planes = [
            plane(r2)?,
            plane(r3 - r2)?,
            plane(r3 + r0)?,
            plane(r3 - r0)?,
            plane(r3 + r1)?,
            plane(r3 - r1)?,
        ];
        let world_from_clip = m.inverse();
        let corners = std::array::from_fn(|i| {
            let ndc = DVec3::new(
                if i & 1 == 0 { -1.0 } else { 1.0 },
                if i & 2 == 0 { -1.0 } else { 1.0 },
                if i & 4 == 0 { 0.0 } else { 1.0 },
            );
            world_from_clip.project_point3(ndc)
        });
        Frustum::from_planes_and_corners(planes, corners)
    }

    /// The six planes: near, far, left, right, bottom, top.
    pub fn planes(&self) -> &[Plane; 6] {
        &self.planes
    }

    /// Where a box lies, testing only the planes in `mask`.
    ///
    /// Returns the side and the planes still to test for boxes inside this
    /// one: a plane the box lies wholly inside is removed from the mask.
    pub fn classify(&self, b: &Aabb, mask: PlaneMask) -> (Side, PlaneMask) {
        let mut remaining = mask;
        for (i, plane) in self.planes.iter().enumerate() {
            let bit = 1 << i;
            if mask & bit == 0 {
                continue;
            }
            match plane.classify(b) {
                Side::Outside => return (Side::Outside, 0),
                Side::Inside => remaining &= !bit,
                Side::Intersecting => {}
            }
        }
        let side = if remaining == 0 {
            Side::Inside
        } else {
            Side::Intersecting
        };
        (side, remaining)
    }

    /// [`Frustum::classify`], then, for a box the planes leave
    /// intersecting, the remaining separating axes: a box that the planes
    /// pass but that does not touch the frustum (near an edge or a corner)
    /// is [`Side::Outside`]. `mask` only skips planes, never these axes.
    pub fn classify_exact(&self, b: &Aabb, mask: PlaneMask) -> (Side, PlaneMask) {
        let (side, mask) = self.classify(b, mask);
        if side == Side::Intersecting && self.separated(b) {
            return (Side::Outside, 0);
        }
        (side, mask)
    }

    /// Whether the closed box and the frustum share a point (up to
    /// [`SAT_TOLERANCE`] of the frustum's size): the test frustum culling
    /// answers with.
    pub fn intersects(&self, b: &Aabb) -> bool {
        self.classify_exact(b, ALL_PLANES).0 != Side::Outside
    }

    /// The eight corners (bit 0 = right, bit 1 = top, bit 2 = far).
    pub fn corners(&self) -> &[DVec3; 8] {
        &self.corners
    }

    /// Whether a box axis or an edge cross product separates the box.
    fn separated(&self, b: &Aabb) -> bool {
        let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
        let reach = self
            .corner_min
            .abs()
            .max(self.corner_max.abs())
            .max(lo.abs())
            .max(hi.abs());
        let tol = reach * SAT_TOLERANCE;
        if (self.corner_max.cmplt(lo - tol)).any() || (self.corner_min.cmpgt(hi + tol)).any() {
            return true;
        }
        let center = (lo + hi) * 0.5;
        let half = (hi - lo) * 0.5;
        self.cross.iter().any(|p| {
            let c = p.axis.dot(center);
            let r = p.axis.abs().dot(half);
            let tol = p.tol + SAT_TOLERANCE * (c.abs() + r);
            c + r < p.lo - tol || c - r > p.hi + tol
        })
    }

    /// Whether the point (scene-local) is inside or on the frustum.
    pub fn contains_point(&self, p: DVec3) -> bool {
        self.planes.iter().all(|pl| pl.signed_distance(p) >= 0.0)
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    fn cam() -> Camera {
        Camera {
            eye: DVec3::new(1.0, 2.0, 3.0),
            forward: DVec3::new(0.3, -0.2, -1.0),
            up: DVec3::Y,
            fov_y_deg: 50.0,
            aspect: 1.5,
            near: 0.5,
            far: 200.0,
            viewport: [300, 200],
        }
    }

    #[test]
    fn camera_and_matrix_frusta_agree() {
        let c = cam();
        let b = c.basis().unwrap();
        let view = DMat4::look_to_rh(c.eye, b.forward, b.up);
        let proj = DMat4::perspective_rh(c.fov_y_deg.to_radians(), c.aspect, c.near, c.far);
        let from_matrix = Frustum::from_clip_from_world(proj * view).unwrap();
        let from_camera = Frustum::from_camera(&c, DVec3::ZERO).unwrap();
        for (a, m) in from_camera.planes().iter().zip(from_matrix.planes()) {
            assert!((a.normal - m.normal).length() < 1e-9, "{a:?} vs {m:?}");
            assert!(
                (a.d - m.d).abs() < 1e-6 * (1.0 + a.d.abs()),
                "{a:?} vs {m:?}"
            );
        }
    }

    #[test]
    fn points_along_the_axis_are_inside_between_near_and_far() {
        let c = cam();
        let f = Frustum::from_camera(&c, DVec3::ZERO).unwrap();
        let dir = c.forward.normalize();
        assert!(f.contains_point(c.eye + dir * 1.0));
        assert!(f.contains_point(c.eye + dir * 199.0));
        assert!(!f.contains_point(c.eye + dir * 0.1));
        assert!(!f.contains_point(c.eye + dir * 201.0));
        assert!(!f.contains_point(c.eye - dir * 5.0));
    }

    #[test]
    fn mask_drops_planes_a_box_is_inside() {
        let c = Camera {
            eye: DVec3::ZERO,
            forward: DVec3::NEG_Z,
            ..cam()
        };
        let f = Frustum::from_camera(&c, DVec3::ZERO).unwrap();
        let small = Aabb::new(Vec3::new(-0.1, -0.1, -10.1), Vec3::new(0.1, 0.1, -9.9));
        assert_eq!(f.classify(&small, ALL_PLANES), (Side::Inside, 0));
        let across_left = Aabb::new(Vec3::new(-100.0, -0.1, -10.1), Vec3::new(0.1, 0.1, -9.9));
        let (side, mask) = f.classify(&across_left, ALL_PLANES);
        assert_eq!(side, Side::Intersecting);
        assert_eq!(mask, 1 << 2, "only the left plane is left to test");
        let behind = Aabb::new(Vec3::new(-1.0, -1.0, 1.0), Vec3::new(1.0, 1.0, 2.0));
        assert_eq!(f.classify(&behind, ALL_PLANES).0, Side::Outside);
    }

    #[test]
    fn exact_test_rejects_a_box_beside_an_edge_that_the_planes_accept() {
        let c = Camera {
            eye: DVec3::ZERO,
            forward: DVec3::NEG_Z,
            fov_y_deg: 90.0,
            aspect: 1.0,
            near: 1.0,
            far: 10.0,
            ..cam()
        };
        let f = Frustum::from_camera(&c, DVec3::ZERO).unwrap();
        // Past the edge where the right plane (x <= -z) meets the far plane
        // (z >= -10): each plane alone has part of the box inside, but no point
        // of it is inside both.
        let b = Aabb::new(Vec3::new(10.5, -1.0, -12.0), Vec3::new(12.0, 1.0, -9.8));
        assert_ne!(f.classify(&b, ALL_PLANES).0, Side::Outside);
        assert!(!f.intersects(&b));
        // Touching the edge at (10, y, -10) still counts.
        let touching = Aabb::new(Vec3::new(10.0, -1.0, -12.0), Vec3::new(12.0, 1.0, -10.0));
        assert!(f.intersects(&touching));
    }

    #[test]
    fn corners_from_camera_and_matrix_agree() {
        let c = cam();
        let b = c.basis().unwrap();
        let m = DMat4::perspective_rh(c.fov_y_deg.to_radians(), c.aspect, c.near, c.far)
            * DMat4::look_to_rh(c.eye, b.forward, b.up);
        let a = Frustum::from_camera(&c, DVec3::ZERO).unwrap();
        let m = Frustum::from_clip_from_world(m).unwrap();
        for (p, q) in a.corners().iter().zip(m.corners()) {
            assert!((*p - *q).length() < 1e-6 * (1.0 + p.length()), "{p} vs {q}");
        }
    }

    #[test]
    fn cameras_beyond_f64_range_are_errors_not_panics() {
        let huge_far = Camera {
            far: 1e308,
            eye: DVec3::splat(1e308),
            ..cam()
        };
        assert!(Frustum::from_camera(&huge_far, DVec3::ZERO).is_err());
        let huge_far = Camera {
            far: f64::MAX,
            fov_y_deg: 170.0,
            ..cam()
        };
        assert_eq!(
            Frustum::from_camera(&huge_far, DVec3::ZERO)
                .unwrap_err()
                .field,
            "far"
        );
    }

    #[test]
    fn origin_shift_gives_identical_planes() {
        let c = cam();
        let shift = DVec3::new(1e7, -1e7, 1e7);
        let a = Frustum::from_camera(&c, DVec3::ZERO).unwrap();
        let b = Frustum::from_camera(
            &Camera {
                eye: c.eye + shift,
                ..c
            },
            shift,
        )
        .unwrap();
        for (p, q) in a.planes().iter().zip(b.planes()) {
            assert_eq!(p.normal, q.normal);
            assert!((p.d - q.d).abs() < 1e-8);
        }
    }
}
