//! A validated view: the camera a client sent, set up against one scene.

use glam::DVec3;

use crate::geom::{Camera, CameraBasis, CameraError, Frustum};
use crate::scene::Scene;

/// A camera that passed validation, with its frame and its frustum in the
/// scene's local coordinates. The fields are private so that every `View`
/// was made by [`View::new`]: a method may rely on a finite frustum and a
/// camera frame without checking again.
#[derive(Clone, Copy, Debug)]
pub struct View {
    camera: Camera,
    basis: CameraBasis,
    frustum: Frustum,
    eye: DVec3,
}

impl View {
    /// Validates `camera` and sets it up relative to `scene`'s origin; the
    /// error names the field at fault.
    pub fn new(camera: Camera, scene: &Scene) -> Result<View, CameraError> {
        let frustum = Frustum::from_camera(&camera, scene.origin)?;
        // `from_camera` validated the camera, so it has a frame; the check
        // stays so that a change there cannot turn into a panic here.
        let basis = camera.basis().ok_or_else(|| CameraError {
            field: "forward".into(),
            problem: "is zero or parallel to up".into(),
        })?;
        Ok(View {
            camera,
            basis,
            frustum,
            eye: camera.eye - scene.origin,
        })
    }

    /// The camera as the client sent it (world coordinates).
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The camera's orthonormal frame.
    pub fn basis(&self) -> &CameraBasis {
        &self.basis
    }

    /// The frustum, relative to the scene origin.
    pub fn frustum(&self) -> &Frustum {
        &self.frustum
    }

    /// The eye relative to the scene origin, in `f64`.
    pub fn eye(&self) -> DVec3 {
        self.eye
    }
}
