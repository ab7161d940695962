//! A validated view: the camera a client sent, set up against one scene,
//! with the region of eyes and directions its answer must hold for.

use glam::DVec3;

use crate::geom::{Camera, CameraBasis, CameraError, Frustum, Region};
use crate::scene::Scene;

/// A camera that passed validation, with its frame and its frustum in the
/// scene's local coordinates. The fields are private so that every `View`
/// was made by [`View::new`] or [`View::with_region`]: a method may rely on
/// a finite frustum and a camera frame without checking again.
#[derive(Clone, Copy, Debug)]
pub struct View {
    camera: Camera,
    basis: CameraBasis,
    frustum: Frustum,
    eye: DVec3,
    region: Region,
    apex: Option<DVec3>,
}

impl View {
    /// Validates `camera` and sets it up relative to `scene`'s origin; the
    /// error names the field at fault.
    pub fn new(camera: Camera, scene: &Scene) -> Result<View, CameraError> {
        View::with_region(camera, Region::POINT, scene)
    }

    /// [`View::new`] for an answer that must hold for every view of
    /// `region`: the frustum is then the region's enclosing frustum
    /// ([`Region::enclosing_frustum`]), and the eye, camera and frame stay
    /// the region's centre.
    pub fn with_region(camera: Camera, region: Region, scene: &Scene) -> Result<View, CameraError> {
        let (frustum, apex) = region.enclosing(&camera, scene.origin)?;
        // `enclosing_frustum` validated the camera, so it has a frame; the
        // check stays so that a change there cannot turn into a panic here.
        let basis = camera.basis().ok_or_else(|| CameraError {
            field: "forward".into(),
            problem: "is zero or parallel to up".into(),
        })?;
        Ok(View {
            camera,
            basis,
            frustum,
            eye: camera.eye - scene.origin,
            region,
            apex,
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

    /// The frustum, relative to the scene origin: the camera's, or for a
    /// region the one that holds all of its views.
    pub fn frustum(&self) -> &Frustum {
        &self.frustum
    }

    /// The eye relative to the scene origin, in `f64` (a region's centre).
    pub fn eye(&self) -> DVec3 {
        self.eye
    }

    /// The eyes and directions the answer must hold for.
    pub fn region(&self) -> Region {
        self.region
    }

    /// The point the frustum's side planes pass through, relative to the
    /// scene origin: the eye for a point view, behind it for a region;
    /// `None` when a region's frustum is a cube around the eye.
    pub fn apex(&self) -> Option<DVec3> {
        self.apex
    }
}

/// Views closer than this to their mean eye (scene units) may be answered
/// as one region: a headset's two eyes (6.4 cm apart), not split screens.
pub const ENCLOSE_RADIUS: f64 = 0.25;

/// Views whose frames turn less than this (degrees) from their mean may be
/// answered as one region.
pub const ENCLOSE_ANGLE: f64 = 5.0;

/// The views of one request as a job culls them: the first and the rest.
/// When `regions` (the method answers for regions) and the views are
/// near one another ([`ENCLOSE_RADIUS`], [`ENCLOSE_ANGLE`]) with the same
/// lens (field of view, aspect, near, far, viewport), they become one
/// region view around their mean eye that holds every one of them: one
/// traversal instead of one per view, for a slightly larger answer.
///
/// # Panics
/// When `views` is empty (a request has at least one view).
pub fn gather(views: &[View], regions: bool, scene: &Scene) -> (View, Vec<View>) {
    let (first, rest) = views.split_first().expect("a request has a view");
    // One view (the usual request) allocates nothing.
    if rest.is_empty() || !regions {
        return (*first, rest.to_vec());
    }
    match enclose(first, rest, scene) {
        Some(one) => (one, Vec::new()),
        None => (*first, rest.to_vec()),
    }
}

/// One region view holding `first` and `rest`, when they are near enough.
fn enclose(first: &View, rest: &[View], scene: &Scene) -> Option<View> {
    let lens = |v: &View| {
        let c = v.camera();
        (c.fov_y_deg, c.aspect, c.near, c.far, c.viewport)
    };
    if rest.iter().any(|v| lens(v) != lens(first)) {
        return None;
    }
    let all = || std::iter::once(first).chain(rest);
    let n = (rest.len() + 1) as f64;
    let eye = all().map(|v| v.camera().eye).sum::<DVec3>() / n;
    let forward = all()
        .map(|v| v.basis().forward)
        .sum::<DVec3>()
        .try_normalize()?;
    let centre = Camera {
        eye,
        forward,
        up: first.basis().up,
        ..*first.camera()
    };
    let basis = centre.basis()?;
    let region = Region::covering(
        eye,
        &basis,
        all().map(|v| (v.region(), v.camera().eye, *v.basis())),
    )
    .ok()?;
    if region.radius() > ENCLOSE_RADIUS + all().map(|v| v.region().radius()).fold(0.0, f64::max)
        || region.angle_deg()
            > ENCLOSE_ANGLE + all().map(|v| v.region().angle_deg()).fold(0.0, f64::max)
    {
        return None;
    }
    View::with_region(centre, region, scene).ok()
}
