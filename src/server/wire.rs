//! Between the wire and the library: the JSON bodies are `pvsd_proto`'s
//! (shared with `loadtest` and any Rust client); this module turns them
//! into the library's types (cameras, method specs) and the library's
//! results into them (statistics, bounds). Only the server knows both.
//!
//! The conversions on `pvsd_proto`'s types are extension traits
//! ([`ViewRequestExt`], [`BoundsExt`]): the orphan rules keep inherent
//! methods on a type to its own crate.

use glam::{DMat4, DQuat, DVec3};
use pvsd_proto::json::{Bounds, MoveRequest, Number, Stats, ViewRequest};

use super::error::ApiError;
use crate::cull::View;
use crate::cull::{CullStats, MethodOptions, MethodSpec};
use crate::geom::{Camera, Region};
use crate::scene::MoveError;
use crate::scene::Scene;

fn vec3(v: [Number; 3]) -> DVec3 {
    DVec3::new(v[0].0, v[1].0, v[2].0)
}

/// At most this many views in one request's `views`.
pub const MAX_VIEWS: usize = 8;

/// A request's views, validated against a scene.
#[derive(Clone, Debug)]
pub struct Views {
    /// One or more (at most [`MAX_VIEWS`]).
    pub views: Vec<View>,
    /// The largest radius asked.
    pub radius: f64,
    /// The largest angle asked, degrees.
    pub angle: f64,
}

impl Views {
    /// Whether any view asks for a region.
    pub fn has_region(&self) -> bool {
        self.views.iter().any(|v| !v.region().is_point())
    }

    /// The request's echo in an answer's stats: the region and the number
    /// of views, when they are not a single point view.
    pub fn echo(&self, stats: &mut Stats) {
        if self.has_region() {
            stats.radius = Some(self.radius);
            stats.angle = Some(self.angle);
        }
        if self.views.len() > 1 {
            stats.views = Some(self.views.len() as u32);
        }
    }
}

/// What the server makes of a [`ViewRequest`].
pub trait ViewRequestExt {
    /// The camera (not yet validated: `View::new` does that, naming
    /// fields). Absent fields take [`Camera::default`]'s values; `aspect`
    /// defaults to the viewport's. A missing `eye` or `forward` is
    /// refused by name.
    fn camera(&self) -> Result<Camera, ApiError>;

    /// The views asked for (one, or each of `views`), each valid for its
    /// region: its own `radius` and `angle`, else the request's, else
    /// `default` (a session's). Errors name the field (`views[1].eye[0]`).
    fn views(&self, scene: &Scene, default: Region) -> Result<Views, ApiError>;

    /// The method and its options.
    fn method_spec(&self) -> Result<MethodSpec, ApiError>;

    /// Refuses what a stateless request cannot have (`base`).
    fn check_stateless(&self) -> Result<(), ApiError>;

    /// Refuses what a session frame cannot have: its method and options
    /// were chosen when the session was made.
    fn check_frame(&self) -> Result<(), ApiError>;
}

/// A region from a request's optional fields, falling back to `default`'s.
pub fn region(
    radius: Option<Number>,
    angle: Option<Number>,
    default: Region,
) -> Result<Region, ApiError> {
    Region::new(
        radius.map_or(default.radius(), |n| n.0),
        angle.map_or(default.angle_deg(), |n| n.0),
    )
    .map_err(|e| ApiError::InvalidView(e.to_string()))
}

impl ViewRequestExt for ViewRequest {
    fn camera(&self) -> Result<Camera, ApiError> {
        let missing = |field: &str| ApiError::MalformedJson(format!("missing field `{field}`"));
        let d = Camera::default();
        let viewport = self.viewport.unwrap_or(d.viewport);
        let aspect = match (self.aspect, self.viewport) {
            (Some(a), _) => a.0,
            (None, Some([w, h])) if w > 0 && h > 0 => w as f64 / h as f64,
            _ => d.aspect,
        };
        Ok(Camera {
            eye: vec3(self.eye.ok_or_else(|| missing("eye"))?),
            forward: vec3(self.forward.ok_or_else(|| missing("forward"))?),
            up: self.up.map_or(d.up, vec3),
            fov_y_deg: self.fov_y_deg.map_or(d.fov_y_deg, |n| n.0),
            aspect,
            near: self.near.map_or(d.near, |n| n.0),
            far: self.far.map_or(d.far, |n| n.0),
            viewport,
        })
    }

    fn views(&self, scene: &Scene, default: Region) -> Result<Views, ApiError> {
        let outer = region(self.radius, self.angle, default)?;
        let Some(list) = &self.views else {
            let view = View::with_region(self.camera()?, outer, scene)?;
            return Ok(Views {
                views: vec![view],
                radius: outer.radius(),
                angle: outer.angle_deg(),
            });
        };
        let own = [
            ("eye", self.eye.is_some()),
            ("forward", self.forward.is_some()),
            ("up", self.up.is_some()),
            ("fov_y_deg", self.fov_y_deg.is_some()),
            ("aspect", self.aspect.is_some()),
            ("near", self.near.is_some()),
            ("far", self.far.is_some()),
            ("viewport", self.viewport.is_some()),
        ];
        if let Some((field, _)) = own.iter().find(|(_, given)| *given) {
            return Err(ApiError::MalformedJson(format!(
                "{field}: a request with views gives each view's camera inside views, not beside it"
            )));
        }
        if list.is_empty() || list.len() > MAX_VIEWS {
            return Err(ApiError::InvalidView(format!(
                "views must hold 1 to {MAX_VIEWS} views, got {}",
                list.len()
            )));
        }
        let mut out = Views {
            views: Vec::with_capacity(list.len()),
            radius: 0.0,
            angle: 0.0,
        };
        for (i, v) in list.iter().enumerate() {
            let inner = [
                ("method", v.method.is_some()),
                ("options", !v.options.is_empty()),
                ("base", v.base.is_some()),
                ("views", v.views.is_some()),
            ];
            if let Some((field, _)) = inner.iter().find(|(_, given)| *given) {
                return Err(ApiError::MalformedJson(format!(
                    "views[{i}].{field}: a view inside views has only a camera, radius and angle"
                )));
            }
            let named = |e: ApiError| match e {
                ApiError::InvalidView(m) => ApiError::InvalidView(format!("views[{i}]: {m}")),
                ApiError::MalformedJson(m) => ApiError::MalformedJson(format!("views[{i}]: {m}")),
                other => other,
            };
            let r = region(v.radius, v.angle, outer).map_err(named)?;
            let camera = v.camera().map_err(named)?;
            // A camera's own errors name its field: `views[1].eye[0] is NaN`.
            let view = View::with_region(camera, r, scene)
                .map_err(|e| ApiError::InvalidView(format!("views[{i}].{e}")))?;
            out.radius = out.radius.max(r.radius());
            out.angle = out.angle.max(r.angle_deg());
            out.views.push(view);
        }
        Ok(out)
    }

    fn method_spec(&self) -> Result<MethodSpec, ApiError> {
        method_spec(self.method.as_deref(), &self.options)
    }

    fn check_stateless(&self) -> Result<(), ApiError> {
        if self.base.is_some() {
            return Err(ApiError::MalformedJson(
                "base: only session frames (POST /sessions/{sid}/frames) have a base".into(),
            ));
        }
        Ok(())
    }

    fn check_frame(&self) -> Result<(), ApiError> {
        if self.method.is_some() || !self.options.is_empty() {
            let field = if self.method.is_some() {
                "method"
            } else {
                "options"
            };
            return Err(ApiError::MalformedJson(format!(
                "{field}: a session's method and options are set by POST /sessions, not per frame"
            )));
        }
        Ok(())
    }
}

/// A method spec from a JSON name and options object. Option values may be
/// strings, numbers or booleans; anything else is refused by name.
pub fn method_spec(
    name: Option<&str>,
    options: &serde_json::Map<String, serde_json::Value>,
) -> Result<MethodSpec, ApiError> {
    let mut spec = MethodSpec::named(name.unwrap_or("auto"))?;
    let mut opts = MethodOptions::new();
    for (k, v) in options {
        let text = match v {
            serde_json::Value::String(s) => s.clone(),
            serde_json::Value::Number(n) => n.to_string(),
            serde_json::Value::Bool(b) => b.to_string(),
            _ => {
                return Err(ApiError::MalformedJson(format!(
                    "options.{k}: must be a string, number or boolean"
                )));
            }
        };
        opts.insert(k.clone(), text);
    }
    spec.options = opts;
    Ok(spec)
}

/// The library's side of a [`MoveRequest`].
pub trait MoveRequestExt {
    /// The world transform asked for; a rotation that is not a unit
    /// quaternion is refused (glTF's rule), as is any non-finite number.
    fn transform(&self) -> Result<DMat4, MoveError>;
}

impl MoveRequestExt for MoveRequest {
    fn transform(&self) -> Result<DMat4, MoveError> {
        let t = DVec3::from(self.translation.unwrap_or([0.0; 3]));
        let r = DQuat::from_array(self.rotation.unwrap_or([0.0, 0.0, 0.0, 1.0]));
        let s = DVec3::from(self.scale.unwrap_or([1.0; 3]));
        if !(t.is_finite() && r.is_finite() && s.is_finite()) {
            return Err(MoveError::Transform(
                "has a number that is not finite".into(),
            ));
        }
        if (r.length() - 1.0).abs() > 1e-3 {
            return Err(MoveError::Transform(format!(
                "rotation {:?} is not a unit quaternion (length {})",
                r.to_array(),
                r.length()
            )));
        }
        Ok(DMat4::from_scale_rotation_translation(s, r.normalize(), t))
    }
}

/// [`Bounds`] from the library's boxes.
pub trait BoundsExt {
    /// From a world-space `(min, max)` pair.
    fn new(world: (DVec3, DVec3)) -> Self;
}

impl BoundsExt for Bounds {
    fn new((min, max): (DVec3, DVec3)) -> Self {
        Bounds {
            min: min.to_array(),
            max: max.to_array(),
        }
    }
}

impl From<CullStats> for Stats {
    fn from(s: CullStats) -> Self {
        let (fallback, fallback_reason) = match s.fallback {
            Some(f) => (Some(f.method.to_string()), Some(f.reason)),
            None => (None, None),
        };
        Stats {
            method: s.method.to_string(),
            cull_us: s.cull_us,
            nodes_tested: s.nodes_tested,
            in_frustum: s.in_frustum,
            visible: s.visible,
            fallback,
            fallback_reason,
            radius: None,
            angle: None,
            views: None,
        }
    }
}
