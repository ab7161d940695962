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
use crate::cull::{CullStats, MethodOptions, MethodSpec};
use crate::geom::Camera;
use crate::scene::MoveError;

fn vec3(v: [Number; 3]) -> DVec3 {
    DVec3::new(v[0].0, v[1].0, v[2].0)
}

/// What the server makes of a [`ViewRequest`].
pub trait ViewRequestExt {
    /// The camera (not yet validated: `View::new` does that, naming
    /// fields). Absent fields take [`Camera::default`]'s values; `aspect`
    /// defaults to the viewport's.
    fn camera(&self) -> Camera;

    /// The method and its options.
    fn method_spec(&self) -> Result<MethodSpec, ApiError>;

    /// Refuses what a stateless request cannot have (`base`).
    fn check_stateless(&self) -> Result<(), ApiError>;

    /// Refuses what a session frame cannot have: its method and options
    /// were chosen when the session was made.
    fn check_frame(&self) -> Result<(), ApiError>;
}

impl ViewRequestExt for ViewRequest {
    fn camera(&self) -> Camera {
        let d = Camera::default();
        let viewport = self.viewport.unwrap_or(d.viewport);
        let aspect = match (self.aspect, self.viewport) {
            (Some(a), _) => a.0,
            (None, Some([w, h])) if w > 0 && h > 0 => w as f64 / h as f64,
            _ => d.aspect,
        };
        Camera {
            eye: vec3(self.eye),
            forward: vec3(self.forward),
            up: self.up.map_or(d.up, vec3),
            fov_y_deg: self.fov_y_deg.map_or(d.fov_y_deg, |n| n.0),
            aspect,
            near: self.near.map_or(d.near, |n| n.0),
            far: self.far.map_or(d.far, |n| n.0),
            viewport,
        }
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
        }
    }
}
