//! A pinhole camera as clients send it, and the checks that make it usable.
//!
//! The eye is `f64` world coordinates: a client far from the world origin
//! (1e7 units) must not lose its position before the scene's own origin is
//! subtracted (see [`crate::geom::Frustum::from_camera`]).

use glam::DVec3;

/// How close to parallel `forward` and `up` may be before the view has no
/// defined "right" (the sine of the angle between them).
pub const PARALLEL_TOLERANCE: f64 = 1e-9;

/// The largest tangent of a half field of view (about 89.99994°). Beyond it
/// a frustum's side planes lie within rounding of the eye plane and its far
/// corners overflow; DESIGN's widest view (fov 179°, aspect 100) has 1.1e4.
pub const MAX_HALF_TANGENT: f64 = 1e6;

/// `v` scaled to unit length, or `None` when it is zero or not finite.
/// Scales by the largest component first, so `[1e200, 0, 0]` and
/// `[1e-200, 0, 0]` are directions too (their squared length would overflow
/// or underflow).
pub fn direction(v: DVec3) -> Option<DVec3> {
    let m = v.abs().max_element();
    if !(m.is_finite() && m > 0.0) {
        return None;
    }
    (v / m).try_normalize()
}

/// A perspective camera in world coordinates (glTF: metres, +Y up).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position, world coordinates.
    pub eye: DVec3,
    /// Viewing direction (any length but zero).
    pub forward: DVec3,
    /// Approximate up direction (any length but zero, not parallel to `forward`).
    pub up: DVec3,
    /// Full vertical field of view in degrees, in (0, 180).
    pub fov_y_deg: f64,
    /// Width over height of the image, > 0.
    pub aspect: f64,
    /// Distance of the near plane, > 0.
    pub near: f64,
    /// Distance of the far plane, > `near`.
    pub far: f64,
    /// Image size in pixels (used by image-space methods and ground truth).
    pub viewport: [u32; 2],
}

/// Why a camera cannot be used; `field` names the offending request field.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{field} {problem}")]
pub struct CameraError {
    /// The request field, as a client wrote it (`eye[1]`, `fov_y_deg`, ...).
    pub field: String,
    /// What is wrong with it, phrased to follow the field name.
    pub problem: String,
}

impl CameraError {
    fn new(field: impl Into<String>, problem: impl Into<String>) -> Self {
        CameraError {
            field: field.into(),
            problem: problem.into(),
        }
    }
}

/// An orthonormal camera frame: `right × up = -forward` is not assumed; only
/// that the three are unit length and mutually perpendicular.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraBasis {
    /// Unit viewing direction.
    pub forward: DVec3,
    /// Unit vector to the right of the image.
    pub right: DVec3,
    /// Unit vector to the top of the image.
    pub up: DVec3,
}

impl Default for Camera {
    /// The defaults a request gets for the fields it leaves out (DESIGN's example view).
    fn default() -> Self {
        Camera {
            eye: DVec3::ZERO,
            forward: DVec3::NEG_Z,
            up: DVec3::Y,
            fov_y_deg: 60.0,
            aspect: 1.6,
            near: 0.1,
            far: 10_000.0,
            viewport: [1024, 640],
        }
    }
}

impl Camera {
    /// Checks every field; the first problem found is returned, naming its field.
    pub fn validate(&self) -> Result<(), CameraError> {
        finite_vec("eye", self.eye)?;
        finite_vec("forward", self.forward)?;
        finite_vec("up", self.up)?;
        for (field, v) in [
            ("fov_y_deg", self.fov_y_deg),
            ("aspect", self.aspect),
            ("near", self.near),
            ("far", self.far),
        ] {
            finite(field, v)?;
        }
        if direction(self.forward).is_none() {
            return Err(CameraError::new("forward", "is a zero vector"));
        }
        if direction(self.up).is_none() {
            return Err(CameraError::new("up", "is a zero vector"));
        }
        if self.basis().is_none() {
            return Err(CameraError::new("up", "is parallel to forward"));
        }
        if !(self.fov_y_deg > 0.0 && self.fov_y_deg < 180.0) {
            return Err(CameraError::new(
                "fov_y_deg",
                format!("must be in (0, 180), got {}", self.fov_y_deg),
            ));
        }
        if self.aspect <= 0.0 {
            return Err(CameraError::new(
                "aspect",
                format!("must be > 0, got {}", self.aspect),
            ));
        }
        let (tx, ty) = self.half_tangents();
        if ty > MAX_HALF_TANGENT {
            return Err(CameraError::new(
                "fov_y_deg",
                format!(
                    "is too close to 180 (at most {:.5})",
                    2.0 * MAX_HALF_TANGENT.atan().to_degrees()
                ),
            ));
        }
        if tx > MAX_HALF_TANGENT {
            return Err(CameraError::new(
                "aspect",
                format!(
                    "makes the horizontal field of view too close to 180 degrees \
                     (aspect × tan(fov_y/2) must be ≤ {MAX_HALF_TANGENT:e})"
                ),
            ));
        }
        if self.near <= 0.0 {
            return Err(CameraError::new(
                "near",
                format!("must be > 0, got {}", self.near),
            ));
        }
        if self.far <= self.near {
            return Err(CameraError::new(
                "far",
                format!(
                    "must be greater than near ({}), got {}",
                    self.near, self.far
                ),
            ));
        }
        for (i, v) in self.viewport.iter().enumerate() {
            if *v == 0 {
                return Err(CameraError::new(format!("viewport[{i}]"), "must be > 0"));
            }
        }
        Ok(())
    }

    /// The camera frame, or `None` when `forward` or `up` is zero or they are parallel.
    pub fn basis(&self) -> Option<CameraBasis> {
        let forward = direction(self.forward)?;
        let up = direction(self.up)?;
        let right = forward.cross(up);
        if right.length().partial_cmp(&PARALLEL_TOLERANCE) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let right = right.normalize();
        Some(CameraBasis {
            forward,
            right,
            up: right.cross(forward),
        })
    }

    /// `tan` of the half field of view, vertically and horizontally.
    pub fn half_tangents(&self) -> (f64, f64) {
        let ty = (self.fov_y_deg.to_radians() * 0.5).tan();
        (ty * self.aspect, ty)
    }
}

fn finite(field: &str, v: f64) -> Result<(), CameraError> {
    if v.is_nan() {
        Err(CameraError::new(field, "is NaN"))
    } else if v.is_infinite() {
        Err(CameraError::new(field, "is infinite"))
    } else {
        Ok(())
    }
}

fn finite_vec(field: &str, v: DVec3) -> Result<(), CameraError> {
    for (i, c) in v.to_array().into_iter().enumerate() {
        finite(&format!("{field}[{i}]"), c)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_camera_is_valid() {
        Camera::default().validate().unwrap();
    }

    #[test]
    fn errors_name_the_field() {
        let cam = Camera {
            eye: DVec3::new(0.0, f64::NAN, 0.0),
            ..Camera::default()
        };
        assert_eq!(cam.validate().unwrap_err().to_string(), "eye[1] is NaN");
        let cam = Camera {
            forward: DVec3::new(0.0, 0.0, f64::INFINITY),
            ..Camera::default()
        };
        assert_eq!(
            cam.validate().unwrap_err().to_string(),
            "forward[2] is infinite"
        );
        let cam = Camera {
            forward: DVec3::ZERO,
            ..Camera::default()
        };
        assert_eq!(cam.validate().unwrap_err().field, "forward");
        let cam = Camera {
            up: DVec3::new(0.0, 0.0, -3.0),
            ..Camera::default()
        };
        assert_eq!(
            cam.validate().unwrap_err().to_string(),
            "up is parallel to forward"
        );
        let cam = Camera {
            fov_y_deg: 180.0,
            ..Camera::default()
        };
        assert_eq!(cam.validate().unwrap_err().field, "fov_y_deg");
        let cam = Camera {
            far: 0.05,
            ..Camera::default()
        };
        assert_eq!(cam.validate().unwrap_err().field, "far");
        let cam = Camera {
            viewport: [10, 0],
            ..Camera::default()
        };
        assert_eq!(cam.validate().unwrap_err().field, "viewport[1]");
    }

    #[test]
    fn huge_and_tiny_directions_are_directions() {
        for f in [
            DVec3::new(1e200, 0.0, 0.0),
            DVec3::new(1e-200, 0.0, 1e-201),
            DVec3::splat(f64::MAX),
        ] {
            let cam = Camera {
                forward: f,
                ..Camera::default()
            };
            cam.validate().unwrap();
            assert!((cam.basis().unwrap().forward.length() - 1.0).abs() < 1e-12);
        }
        let zero = Camera {
            forward: DVec3::ZERO,
            ..Camera::default()
        };
        assert_eq!(
            zero.validate().unwrap_err().to_string(),
            "forward is a zero vector"
        );
    }

    #[test]
    fn fields_of_view_near_180_are_refused_by_name() {
        let wide = Camera {
            aspect: 1e155,
            ..Camera::default()
        };
        assert_eq!(wide.validate().unwrap_err().field, "aspect");
        let tall = Camera {
            fov_y_deg: 179.999_999_9,
            ..Camera::default()
        };
        assert_eq!(tall.validate().unwrap_err().field, "fov_y_deg");
        let widest_design_asks = Camera {
            fov_y_deg: 179.0,
            aspect: 100.0,
            ..Camera::default()
        };
        widest_design_asks.validate().unwrap();
    }

    #[test]
    fn basis_is_orthonormal_for_straight_down_with_other_up() {
        let cam = Camera {
            forward: DVec3::NEG_Y,
            up: DVec3::NEG_Z,
            ..Camera::default()
        };
        cam.validate().unwrap();
        let b = cam.basis().unwrap();
        assert!((b.forward.dot(b.right)).abs() < 1e-15);
        assert!((b.up.dot(b.forward)).abs() < 1e-15);
        assert!((b.up.length() - 1.0).abs() < 1e-15);
    }
}
