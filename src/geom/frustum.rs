//! View frusta as six inward-facing planes, and plane-mask box tests.
//!
//! A frustum is built in *scene-local* coordinates: the scene's `f64` origin
//! is subtracted from the `f64` eye first (camera-relative setup), so a scene
//! and camera both translated by 1e7 units give the same planes as untranslated.
//!
//! The plane mask follows hierarchical culling (Bittner et al. §5.3; also
//! Assarsson–Möller): a plane that a node's box lies wholly inside is dropped
//! for that node's descendants, since their boxes lie inside the node's box.

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
}

impl Frustum {
    /// The frustum of `camera`, in coordinates relative to `origin`.
    ///
    /// Fails like [`Camera::validate`] on a camera that has no frustum.
    pub fn from_camera(camera: &Camera, origin: DVec3) -> Result<Frustum, CameraError> {
        camera.validate()?;
        let basis = camera.basis().expect("validated camera has a basis");
        let eye = camera.eye - origin;
        let (tx, ty) = camera.half_tangents();
        let f = basis.forward;
        let side = |n: DVec3| Plane::from_point_normal(eye, n).expect("side normals are non-zero");
        Ok(Frustum {
            planes: [
                Plane::from_point_normal(eye + f * camera.near, f).expect("unit forward"),
                Plane::from_point_normal(eye + f * camera.far, -f).expect("unit forward"),
                side(f * tx + basis.right),
                side(f * tx - basis.right),
                side(f * ty + basis.up),
                side(f * ty - basis.up),
            ],
        })
    }

    /// The frustum of a `clip_from_world` matrix with depth in `[0, 1]`
    /// (Vulkan, wgpu, `glam::DMat4::perspective_rh`), by Gribb–Hartmann plane
    /// extraction. `None` when a plane degenerates.
    pub fn from_clip_from_world(m: DMat4) -> Option<Frustum> {
        let r = |i: usize| m.row(i);
        let (r0, r1, r2, r3) = (r(0), r(1), r(2), r(3));
        let plane = |v: glam::DVec4| Plane::from_coefficients(v.x, v.y, v.z, v.w);
        Some(Frustum {
            planes: [
                plane(r2)?,
                plane(r3 - r2)?,
                plane(r3 + r0)?,
                plane(r3 - r0)?,
                plane(r3 + r1)?,
                plane(r3 - r1)?,
            ],
        })
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

    /// Whether the box may intersect the frustum: it is not wholly outside
    /// any one plane. This is the test frustum culling answers with; it is
    /// conservative (a box near a frustum edge may pass without touching it).
    pub fn intersects(&self, b: &Aabb) -> bool {
        self.classify(b, ALL_PLANES).0 != Side::Outside
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
