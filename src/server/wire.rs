//! The JSON bodies of the HTTP API (DESIGN "HTTP API"), and their conversion
//! to and from the library's types. Only the server knows serde's shapes.

use std::collections::BTreeMap;

use glam::DVec3;
use serde::{Deserialize, Deserializer, Serialize};

use super::error::ApiError;
use crate::cull::{CullStats, MethodOptions, MethodSpec};
use crate::geom::Camera;

/// A number that may also arrive as `"NaN"`, `"Infinity"` or `"-Infinity"`
/// (see `extract`), so that validation can name the field that is not finite.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Number(pub f64);

impl<'de> Deserialize<'de> for Number {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = Number;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a number")
            }
            fn visit_f64<E>(self, v: f64) -> Result<Number, E> {
                Ok(Number(v))
            }
            fn visit_i64<E>(self, v: i64) -> Result<Number, E> {
                Ok(Number(v as f64))
            }
            fn visit_u64<E>(self, v: u64) -> Result<Number, E> {
                Ok(Number(v as f64))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Number, E> {
                match v {
                    "NaN" => Ok(Number(f64::NAN)),
                    "Infinity" => Ok(Number(f64::INFINITY)),
                    "-Infinity" => Ok(Number(f64::NEG_INFINITY)),
                    _ => Err(E::invalid_type(serde::de::Unexpected::Str(v), &self)),
                }
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// A view as clients send it (DESIGN: "A **view**"). Absent fields take
/// [`Camera::default`]'s values; `aspect` defaults to the viewport's.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewRequest {
    /// Eye position, world coordinates.
    pub eye: [Number; 3],
    /// Viewing direction.
    pub forward: [Number; 3],
    /// Up direction (default +Y).
    pub up: Option<[Number; 3]>,
    /// Vertical field of view, degrees (default 60).
    pub fov_y_deg: Option<Number>,
    /// Width / height (default: the viewport's, else 1.6).
    pub aspect: Option<Number>,
    /// Near plane distance (default 0.1).
    pub near: Option<Number>,
    /// Far plane distance (default 10000).
    pub far: Option<Number>,
    /// Image size in pixels (default 1024 × 640).
    pub viewport: Option<[u32; 2]>,
    /// Culling method (default `auto`).
    pub method: Option<String>,
    /// The method's knobs.
    #[serde(default)]
    pub options: serde_json::Map<String, serde_json::Value>,
    /// Session frames only: the frame the client holds, to get the delta
    /// against it (default: the last frame the server sent).
    pub base: Option<u64>,
}

fn vec3(v: [Number; 3]) -> DVec3 {
    DVec3::new(v[0].0, v[1].0, v[2].0)
}

impl ViewRequest {
    /// The camera (not yet validated: `View::new` does that, naming fields).
    pub fn camera(&self) -> Camera {
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

    /// The method and its options.
    pub fn method_spec(&self) -> Result<MethodSpec, ApiError> {
        method_spec(self.method.as_deref(), &self.options)
    }

    /// Refuses what a stateless request cannot have (`base`).
    pub fn check_stateless(&self) -> Result<(), ApiError> {
        if self.base.is_some() {
            return Err(ApiError::MalformedJson(
                "base: only session frames (POST /sessions/{sid}/frames) have a base".into(),
            ));
        }
        Ok(())
    }

    /// Refuses what a session frame cannot have: its method and options
    /// were chosen when the session was made.
    pub fn check_frame(&self) -> Result<(), ApiError> {
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

/// A box in world coordinates.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Bounds {
    /// Smallest corner.
    pub min: [f64; 3],
    /// Largest corner.
    pub max: [f64; 3],
}

impl Bounds {
    /// From a world-space `(min, max)` pair.
    pub fn new((min, max): (DVec3, DVec3)) -> Self {
        Bounds {
            min: min.to_array(),
            max: max.to_array(),
        }
    }
}

/// One entry of `GET /scenes`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SceneInfo {
    /// The scene id (file stem).
    pub id: String,
    /// Number of objects.
    pub objects: usize,
    /// Number of triangles.
    pub triangles: usize,
    /// World bounds; `null` for a scene without triangles.
    pub bounds: Option<Bounds>,
    /// The up axis.
    pub up: [f32; 3],
    /// Methods it supports (`auto` is always accepted besides).
    pub methods: Vec<String>,
    /// Methods it does not support, each with why (e.g. `horizon` on a
    /// scene that is no height field over a ground).
    pub unsupported: BTreeMap<String, String>,
}

/// One entry of `GET /scenes/{id}/objects`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ObjectInfo {
    /// The object id.
    pub id: u32,
    /// Its name.
    pub name: String,
    /// World bounds; `null` for an object with no triangles.
    pub bounds: Option<Bounds>,
}

/// The `stats` of an answer.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct StatsBody {
    /// The method that answered.
    pub method: String,
    /// Cull time, microseconds.
    pub cull_us: f64,
    /// Hierarchy nodes tested.
    pub nodes_tested: u64,
    /// Objects in the frustum; `null` when the method does not count them
    /// (occlusion methods drop hidden subtrees uncounted).
    pub in_frustum: Option<u64>,
    /// Objects in the answer.
    pub visible: u64,
    /// The method that answered instead, when `method` failed (`frustum`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fallback: Option<String>,
    /// Why `method` failed, when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fallback_reason: Option<String>,
}

impl From<CullStats> for StatsBody {
    fn from(s: CullStats) -> Self {
        let (fallback, fallback_reason) = match s.fallback {
            Some(f) => (Some(f.method.to_string()), Some(f.reason)),
            None => (None, None),
        };
        StatsBody {
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

/// The answer of `POST /scenes/{id}/visible`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct VisibleResponse {
    /// Possibly visible object ids, ascending.
    pub visible: Vec<u32>,
    /// Per id of `visible`, an upper bound of the pixels it covers; only
    /// when the method was asked for them (`horizon` with `areas=true`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub areas: Option<Vec<f64>>,
    /// What it cost.
    pub stats: StatsBody,
}

/// `value` as JSON into a buffer sized for `ids` ids up front: an answer
/// of thousands of ids would otherwise grow its buffer a dozen times.
fn json_sized(value: &impl Serialize, ids: usize) -> Vec<u8> {
    // Ids of a scene under a million objects print in at most 7 bytes with
    // their comma; the rest of a body is well under 256.
    let mut out = Vec::with_capacity(256 + ids * 7);
    serde_json::to_writer(&mut out, value).expect("answers serialize");
    out
}

impl VisibleResponse {
    /// The JSON body.
    pub fn to_json(&self) -> Vec<u8> {
        let areas = self.areas.as_ref().map_or(0, |a| a.len() * 3);
        json_sized(self, self.visible.len() + areas)
    }
}

impl FrameResponse {
    /// The JSON body.
    pub fn to_json(&self) -> Vec<u8> {
        let users = self.users_visible.as_ref().map_or(0, |u| u.len() * 5);
        json_sized(self, self.added.len() + self.removed.len() + users)
    }
}

/// The body of `POST /sessions` and `POST /walkthroughs`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SessionRequest {
    /// The scene id.
    pub scene: String,
    /// Culling method (default `auto`).
    pub method: Option<String>,
    /// The method's knobs.
    #[serde(default)]
    pub options: serde_json::Map<String, serde_json::Value>,
}

/// The answer of `POST /sessions`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SessionCreated {
    /// The session id: 128 random bits, 32 hex digits; whoever holds it
    /// owns the session.
    pub session: String,
    /// The method that answers its frames (`auto` resolved).
    pub method: String,
}

/// A session frame: the change from `base` to this frame's visible set
/// (JSON, or `application/x-pvs` as `proto/wire-format.md` gives it).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
pub struct FrameResponse {
    /// This frame's number: 1 for the session's first, then one more each frame.
    pub frame: u64,
    /// The frame the delta is against; `null`: `added` is the whole set.
    pub base: Option<u64>,
    /// Ids visible now and not in `base`, ascending.
    pub added: Vec<u32>,
    /// Ids in `base` and not visible now, ascending.
    pub removed: Vec<u32>,
    /// In a walkthrough: the other users whose avatars may be visible, ascending.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub users_visible: Option<Vec<String>>,
}

/// The answer of `POST /walkthroughs`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct WalkthroughCreated {
    /// The walkthrough id.
    pub walkthrough: String,
    /// The method its users' frames are answered with (`auto` resolved).
    pub method: String,
}

/// The answer of `POST /walkthroughs/{wid}/users`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct UserJoined {
    /// The user's id, as others see it in `users_visible`.
    pub user: String,
    /// The user's session: send frames to it.
    pub session: String,
}

/// Where a user last stood (world coordinates).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Pose {
    /// The eye.
    pub eye: [f64; 3],
    /// The viewing direction.
    pub forward: [f64; 3],
    /// The up direction.
    pub up: [f64; 3],
}

/// One user of `GET /walkthroughs/{wid}`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct UserInfo {
    /// The user id.
    pub user: String,
    /// The last frame's camera; `null` before the first frame.
    pub pose: Option<Pose>,
    /// Frames answered.
    pub frames: u64,
}

/// The answer of `GET /walkthroughs/{wid}`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct WalkthroughInfo {
    /// The walkthrough id.
    pub walkthrough: String,
    /// Its scene.
    pub scene: String,
    /// Its method.
    pub method: String,
    /// Its users, by id.
    pub users: Vec<UserInfo>,
}
