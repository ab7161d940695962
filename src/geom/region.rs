//! A region of views around a camera, and the one frustum that holds the
//! frusta of all of them.
//!
//! A client 50–150 ms from the server asks for an answer valid for a
//! neighbourhood of its camera (Cohen-Or & Zadicario's ε-neighbourhood):
//! every eye within `radius` of the camera's eye, looking within `angle` of
//! its direction (any rotation by at most `angle`, roll included), with the
//! camera's own field of view, near and far. [`Region::enclosing_frustum`]
//! encloses the union of those frusta in one frustum, so that every method
//! that tests boxes against `View::frustum` honours the region without
//! knowing of it; occlusion is each method's part (Wonka et al. 2000:
//! occluders shrunk by the radius).
//!
//! How the enclosure is built, in the camera's frame (`f` forward):
//! 1. **Angle.** A side plane of half-angle `θ` (inward normal `n` with
//!    `n·f = sin θ`) tilted out to `θ' = θ + δ` has every ray of the
//!    original frustum at least `asin(sin δ / (cos θ · |d|))` inside it,
//!    where `|d| ≤ √(1 + tan²θ + tan²φ)` bounds the length of a ray
//!    `(x, y, 1)` (`φ` the other half-angle). With
//!    `sin δ = sin a · √(1 + tan²φ cos²θ)` that margin is at least `a`, so
//!    every ray rotated by at most `a` stays inside: the union of rotated
//!    frusta lies in the pyramid of half-angles `θx'`, `θy'`.
//! 2. **Radius.** A side plane through an eye `e + v`, `|v| ≤ r`, keeps
//!    `n·(p − e) ≥ n·v ≥ −r`; the plane through `e − b f` with
//!    `b = r / sin min(θx', θy')` keeps `n·(p − e) ≥ −b sin θ' ≥ −r`, so the
//!    apex moves back by `b`.
//! 3. **Near and far.** A point drawn from `e + v` lies at a distance at
//!    least `near` along a ray inside the widened pyramid, whose rays make
//!    `f·u ≥ |u| / √(1 + tan²θx' + tan²θy')`: so `f·(p − e) ≥ −r + near/L'`.
//!    It lies at most `far·√(1 + tan²θx + tan²θy)` from its eye (`far` when
//!    `angle` is 0, the view axis being `f` itself): so
//!    `f·(p − e) ≤ r + that`.
//!
//! When a widened half-angle reaches [`MAX_WIDENED`] no pyramid holds the
//! union (the rotated views see more than a half-space); the enclosure is
//! then the cube of half-size `r + far·√(1 + tan²θx + tan²θy)` around the
//! eye, which holds every point any of them draws.
//!
//! Every quantity is rounded outwards by [`SLACK`] (relative) and a few
//! ulps of the eye's coordinates, so rounding only widens the enclosure.
//! A point region (`radius` 0, `angle` 0) is the camera's own frustum, bit
//! for bit.

use glam::DVec3;

use super::{Camera, CameraBasis, CameraError, Frustum};

/// The widest half-angle a region's enclosing pyramid may have (radians,
/// 89.9°); wider, the enclosure is a cube around the eye.
pub const MAX_WIDENED: f64 = 89.9 * std::f64::consts::PI / 180.0;

/// Relative outward rounding of every quantity of an enclosure.
const SLACK: f64 = 1e-9;

/// The largest radius a request may ask for (world units): far beyond any
/// scene, and small enough that nothing derived from it overflows.
pub const MAX_RADIUS: f64 = 1e12;

/// The eyes and directions an answer must hold for: every eye within
/// `radius` of the camera's, looking within `angle` degrees of its
/// direction. Validated on construction.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Region {
    radius: f64,
    angle_deg: f64,
}

impl Region {
    /// The camera's own view: one eye, one direction.
    pub const POINT: Region = Region {
        radius: 0.0,
        angle_deg: 0.0,
    };

    /// A region, or the error naming the field at fault: `radius` is
    /// finite, ≥ 0 and at most [`MAX_RADIUS`]; `angle` finite, in [0, 180].
    pub fn new(radius: f64, angle_deg: f64) -> Result<Region, CameraError> {
        let bad = |field: &str, problem: String| CameraError {
            field: field.into(),
            problem,
        };
        if !radius.is_finite() || !(0.0..=MAX_RADIUS).contains(&radius) {
            return Err(bad(
                "radius",
                format!("must be a number in [0, {MAX_RADIUS:e}], got {radius}"),
            ));
        }
        if !angle_deg.is_finite() || !(0.0..=180.0).contains(&angle_deg) {
            return Err(bad(
                "angle",
                format!("must be degrees in [0, 180], got {angle_deg}"),
            ));
        }
        Ok(Region { radius, angle_deg })
    }

    /// The radius, world units.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// The angle, degrees.
    pub fn angle_deg(&self) -> f64 {
        self.angle_deg
    }

    /// Whether this is a single eye and direction.
    pub fn is_point(&self) -> bool {
        self.radius == 0.0 && self.angle_deg == 0.0
    }

    /// A region around `center`, with the camera frame `frame`, that holds
    /// every part: each a region around an eye, with a camera frame (the
    /// views of a multi-view request). A part's views are rotations of
    /// the centre's by the rotation between the two frames (whose angle
    /// `acos((tr R − 1) / 2)` counts roll too) and then by its own angle.
    pub fn covering(
        center: DVec3,
        frame: &CameraBasis,
        parts: impl IntoIterator<Item = (Region, DVec3, CameraBasis)>,
    ) -> Result<Region, CameraError> {
        let (mut radius, mut angle) = (0.0f64, 0.0f64);
        for (r, eye, b) in parts {
            radius = radius.max(r.radius + eye.distance(center));
            let trace =
                b.right.dot(frame.right) + b.up.dot(frame.up) + b.forward.dot(frame.forward);
            let turn = ((trace - 1.0) * 0.5).clamp(-1.0, 1.0).acos().to_degrees();
            angle = angle.max(r.angle_deg + turn);
        }
        // Rounded outwards: the distances and angles above are a few ulps
        // off (an acos near 0 by up to ~1e-8 rad).
        Region::new(
            radius * (1.0 + 4.0 * f64::EPSILON) + center.abs().max_element() * 4.0 * f64::EPSILON,
            (angle + 1e-5).min(180.0),
        )
    }

    /// The frustum, relative to `origin`, that holds every point any view
    /// of the region draws (module docs). The camera must be valid.
    pub fn enclosing_frustum(
        &self,
        camera: &Camera,
        origin: DVec3,
    ) -> Result<Frustum, CameraError> {
        Ok(self.enclosing(camera, origin)?.0)
    }

    /// [`Region::enclosing_frustum`] and its apex relative to `origin`: the
    /// point all its side planes pass through (the camera's eye moved back;
    /// the eye itself for a point region), `None` for the cube.
    pub fn enclosing(
        &self,
        camera: &Camera,
        origin: DVec3,
    ) -> Result<(Frustum, Option<DVec3>), CameraError> {
        if self.is_point() {
            return Ok((
                Frustum::from_camera(camera, origin)?,
                Some(camera.eye - origin),
            ));
        }
        camera.validate()?;
        let basis = camera.basis().ok_or_else(|| CameraError {
            field: "up".into(),
            problem: "is parallel to forward".into(),
        })?;
        let r = self.radius;
        let (tx, ty) = camera.half_tangents();
        // How far from its eye any view draws: its far corners' distance.
        let corner_reach = camera.far * (1.0 + tx * tx + ty * ty).sqrt();
        // How far along the axis: `far` itself when no view turns.
        let reach = if self.angle_deg == 0.0 {
            camera.far
        } else {
            corner_reach
        };
        // Rounding of the eye's own coordinates, which every plane inherits.
        let ulps = camera.eye.abs().max_element() * 8.0 * f64::EPSILON;
        let Some((wx, wy)) = self.widened(tx, ty) else {
            let half = (r + corner_reach) * (1.0 + SLACK) + ulps;
            let cube =
                Frustum::around(camera.eye - origin, &basis, half).ok_or_else(|| CameraError {
                    field: "radius".into(),
                    problem: "puts the region out of the range of f64".into(),
                })?;
            return Ok((cube, None));
        };
        let (tx2, ty2) = (wx.tan(), wy.tan());
        let back = (r / wx.min(wy).sin()) * (1.0 + SLACK) + ulps;
        let l2 = (1.0 + tx2 * tx2 + ty2 * ty2).sqrt();
        let near = ((back - r) + camera.near / l2) * (1.0 - SLACK);
        let far = (back + r + reach) * (1.0 + SLACK) + ulps;
        let enclosing = Camera {
            eye: camera.eye - basis.forward * back,
            forward: basis.forward,
            up: basis.up,
            fov_y_deg: (2.0 * wy).to_degrees(),
            aspect: tx2 / ty2,
            near,
            far,
            viewport: camera.viewport,
        };
        let frustum = Frustum::from_camera(&enclosing, origin).map_err(|e| CameraError {
            field: "radius".into(),
            problem: format!("makes a region whose frustum is unusable ({e})"),
        })?;
        Ok((frustum, Some(enclosing.eye - origin)))
    }

    /// The half-angles (radians) of the pyramid that holds every rotated
    /// frustum (step 1), rounded outwards; `None` when one reaches
    /// [`MAX_WIDENED`].
    fn widened(&self, tx: f64, ty: f64) -> Option<(f64, f64)> {
        let a = self.angle_deg.to_radians();
        if a >= std::f64::consts::FRAC_PI_2 {
            return None;
        }
        let widen = |t: f64, other: f64| -> Option<f64> {
            let th = t.atan();
            let s = a.sin() * (1.0 + other * other * th.cos().powi(2)).sqrt();
            if s >= 1.0 {
                return None;
            }
            let w = (th + s.asin()) * (1.0 + SLACK) + f64::EPSILON;
            (w < MAX_WIDENED).then_some(w)
        };
        Some((widen(tx, ty)?, widen(ty, tx)?))
    }
}

impl Frustum {
    /// The cube of half-size `half` around `center` (local coordinates),
    /// with the faces of a frustum along `basis` (near, far, left, right,
    /// bottom, top).
    pub fn around(center: DVec3, basis: &CameraBasis, half: f64) -> Option<Frustum> {
        let (f, r, u) = (basis.forward, basis.right, basis.up);
        let plane = |p: DVec3, n: DVec3| super::Plane::from_point_normal(p, n);
        let planes = [
            plane(center - f * half, f)?,
            plane(center + f * half, -f)?,
            plane(center - r * half, r)?,
            plane(center + r * half, -r)?,
            plane(center - u * half, u)?,
            plane(center + u * half, -u)?,
        ];
        if planes.iter().any(|p| !p.d.is_finite()) {
            return None;
        }
        let corners = std::array::from_fn(|i| {
            let x = if i & 1 == 0 { -half } else { half };
            let y = if i & 2 == 0 { -half } else { half };
            let z = if i & 4 == 0 { -half } else { half };
            center + r * x + u * y + f * z
        });
        Frustum::from_planes_and_corners(planes, corners)
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;

    fn camera() -> Camera {
        Camera {
            eye: DVec3::new(3.0, 1.7, -2.0),
            forward: DVec3::new(1.0, -0.1, 0.4),
            viewport: [320, 200],
            far: 200.0,
            ..Camera::default()
        }
    }

    /// Rotates `v` by `angle` about `axis` (unit).
    fn rotate(v: DVec3, axis: DVec3, angle: f64) -> DVec3 {
        glam::DQuat::from_axis_angle(axis, angle) * v
    }

    #[test]
    fn a_point_region_is_the_camera_frustum_bit_for_bit() {
        let c = camera();
        let origin = DVec3::new(1.0, 0.0, 5.0);
        assert_eq!(
            Region::POINT.enclosing_frustum(&c, origin).unwrap(),
            Frustum::from_camera(&c, origin).unwrap()
        );
    }

    #[test]
    fn bad_regions_name_their_field() {
        for (r, a, field) in [
            (-1.0, 0.0, "radius"),
            (f64::NAN, 0.0, "radius"),
            (f64::INFINITY, 0.0, "radius"),
            (1e13, 0.0, "radius"),
            (0.0, -0.5, "angle"),
            (0.0, 181.0, "angle"),
            (0.0, f64::NAN, "angle"),
        ] {
            assert_eq!(Region::new(r, a).unwrap_err().field, field, "{r} {a}");
        }
        assert!(Region::new(0.0, 0.0).unwrap().is_point());
        assert!(!Region::new(0.5, 0.0).unwrap().is_point());
    }

    /// Points drawn from random eyes in the ball, looking in random
    /// directions of the cone, all lie in the enclosing frustum.
    #[test]
    fn the_enclosure_holds_every_view_of_the_region() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(21);
        for (radius, angle, fov, aspect) in [
            (0.5, 0.0, 60.0, 1.6),
            (2.0, 5.0, 60.0, 1.6),
            (0.0, 15.0, 90.0, 2.0),
            (5.0, 40.0, 30.0, 0.5),
            (1.0, 89.0, 60.0, 1.6),
            (1.0, 120.0, 10.0, 1.0),
            (1e-3, 0.0, 0.01, 1.0),
            (3.0, 10.0, 179.0, 100.0),
            (3.0, 0.0, 179.0, 100.0),
            (0.5, 0.0, 90.0, 600.0),
        ] {
            let region = Region::new(radius, angle).unwrap();
            let cam = Camera {
                fov_y_deg: fov,
                aspect,
                ..camera()
            };
            let origin = DVec3::new(-4.0, 0.0, 1.0);
            let frustum = region.enclosing_frustum(&cam, origin).unwrap();
            let basis = cam.basis().unwrap();
            let (tx, ty) = cam.half_tangents();
            for _ in 0..2000 {
                // An eye in the ball, a rotation within the cone.
                let v = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                let v = if v.length() > 1.0 { v / v.length() } else { v };
                let eye = cam.eye + v * radius;
                let axis = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize();
                let turn = angle.to_radians() * rng.random_range(0.0..=1.0f64).sqrt();
                let (f, r, u) = (
                    rotate(basis.forward, axis, turn),
                    rotate(basis.right, axis, turn),
                    rotate(basis.up, axis, turn),
                );
                // A point of that view's frustum, its corners included.
                let corner = rng.random_bool(0.3);
                let mut pick = |t: f64| {
                    if corner {
                        if rng.random_bool(0.5) { t } else { -t }
                    } else {
                        rng.random_range(-t..=t)
                    }
                };
                let (x, y) = (pick(tx), pick(ty));
                let depth = if corner && rng.random_bool(0.5) {
                    if rng.random_bool(0.5) {
                        cam.near
                    } else {
                        cam.far
                    }
                } else {
                    rng.random_range(cam.near..=cam.far)
                };
                let p = eye + (f + r * x + u * y) * depth - origin;
                let inside = frustum
                    .planes()
                    .iter()
                    .all(|pl| pl.signed_distance(p) >= -1e-9 * p.length().max(1.0));
                assert!(inside, "r {radius} a {angle} fov {fov}: {p:?} left out");
            }
        }
    }
}
