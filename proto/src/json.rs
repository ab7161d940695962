//! The JSON bodies of the HTTP API (DESIGN "HTTP API"): what clients send
//! and what the server answers, field for field.
//!
//! Each type derives `ToSchema` next to its serde attributes, so the OpenAPI
//! document ([`crate::openapi`]) is read off these declarations and a field
//! cannot change without its schema. Doc comments become the schema's
//! descriptions: they are written for client authors.
//!
//! The conversions to and from the server's own types (cameras, method
//! specs, cull statistics) live in the server (`src/server/wire.rs`); this
//! crate knows nothing of geometry.

use std::collections::BTreeMap;

use serde::{Deserialize, Deserializer, Serialize};
use utoipa::openapi::schema::{ObjectBuilder, Type};
use utoipa::openapi::{RefOr, Schema};
use utoipa::{PartialSchema, ToSchema};

/// A number that may also arrive as `"NaN"`, `"Infinity"` or `"-Infinity"`
/// (the server rewrites those bare tokens into these strings), so that
/// validation can name the field that is not finite.
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

/// Written as a plain number (a client's requests carry finite ones).
impl Serialize for Number {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(self.0)
    }
}

/// In the document a `Number` is a number: the non-finite spellings are
/// read only to be refused by name.
impl PartialSchema for Number {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::Number)
            .description(Some(
                "A finite number (NaN or an infinity is refused, naming the field)",
            ))
            .into()
    }
}

impl ToSchema for Number {}

/// One value of a method's `options`: a string, a number or a boolean
/// (`{"k": 32, "variant": "fme"}`). Documentation only: `options` are kept
/// as JSON and the server refuses other values by name.
pub struct OptionValue;

impl PartialSchema for OptionValue {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(utoipa::openapi::schema::SchemaType::from_iter([
                Type::String,
                Type::Number,
                Type::Boolean,
            ]))
            .description(Some("A method option's value"))
            .into()
    }
}

impl ToSchema for OptionValue {}

/// A view as clients send it (DESIGN: "A **view**"): the body of
/// `POST /scenes/{id}/visible`, of `POST /sessions/{sid}/frames` and of
/// each WebSocket text message. Coordinates are in the scene's units
/// (glTF: metres, +Y up). Absent or `null` fields take their defaults.
#[derive(Clone, Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(as = View)]
pub struct ViewRequest {
    /// Eye position, world coordinates. Required unless `views` is given.
    #[schema(min_items = 3, max_items = 3)]
    pub eye: Option<[Number; 3]>,
    /// Viewing direction (need not be unit length; not zero). Required
    /// unless `views` is given.
    #[schema(min_items = 3, max_items = 3)]
    pub forward: Option<[Number; 3]>,
    /// Up direction, not parallel to `forward` (default +Y).
    #[schema(min_items = 3, max_items = 3, default = json!([0, 1, 0]))]
    pub up: Option<[Number; 3]>,
    /// Vertical field of view, degrees, in (0, 180) (default 60).
    // A `Number` is a number in the document; spelled `f64` here so that
    // the range reaches the schema (a `$ref` carries no bounds).
    #[schema(value_type = Option<f64>, default = 60, exclusive_minimum = 0, exclusive_maximum = 180)]
    pub fov_y_deg: Option<Number>,
    /// Width / height (default: the viewport's, else 1.6).
    pub aspect: Option<Number>,
    /// Near plane distance, above 0 (default 0.1).
    #[schema(value_type = Option<f64>, default = 0.1, exclusive_minimum = 0)]
    pub near: Option<Number>,
    /// Far plane distance, beyond `near` (default 10000).
    #[schema(default = 10000)]
    pub far: Option<Number>,
    /// Image size in pixels, width and height (default 1024 × 640).
    #[schema(min_items = 2, max_items = 2, default = json!([1024, 640]))]
    pub viewport: Option<[u32; 2]>,
    /// Culling method: one that `GET /scenes` lists for the scene, or
    /// `auto` (default). Session frames refuse it: the session chose.
    #[schema(default = "auto")]
    pub method: Option<String>,
    /// The method's knobs, e.g. `{"k": 32, "variant": "fme"}`; an unknown
    /// one is refused by name. Session frames refuse them.
    #[serde(default)]
    #[schema(value_type = BTreeMap<String, OptionValue>)]
    pub options: serde_json::Map<String, serde_json::Value>,
    /// Make the answer valid for every eye within this distance of `eye`
    /// (world units, ≥ 0; default 0, or the session's): a client may keep
    /// it while it stays inside the ball.
    #[schema(value_type = Option<f64>, default = 0, minimum = 0)]
    pub radius: Option<Number>,
    /// Make the answer valid for every direction within this many degrees
    /// of `forward` (any rotation by at most this, roll included; in
    /// [0, 180], default 0 or the session's).
    #[schema(value_type = Option<f64>, default = 0, minimum = 0, maximum = 180)]
    pub angle: Option<Number>,
    /// Several views answered together (1–8; two eyes of a headset, split
    /// screens, a shadow frustum), instead of this object's own `eye`,
    /// `forward` and camera fields: the answer is the union. Each is a view
    /// without `method`, `options`, `base` or `views`.
    #[schema(no_recursion)]
    pub views: Option<Vec<ViewRequest>>,
    /// Session frames only (refused on `/scenes/{id}/visible`): the frame
    /// the client holds; the answer is the delta against it if the session
    /// still keeps it (the last 4), else the whole set with `base: null`.
    /// Default: the last frame the server sent.
    pub base: Option<u64>,
}

/// The body of `POST /sessions` and `POST /walkthroughs`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SessionRequest {
    /// The scene id.
    pub scene: String,
    /// Culling method (default `auto`).
    #[schema(default = "auto")]
    pub method: Option<String>,
    /// The method's knobs, as in a view.
    #[serde(default)]
    #[schema(value_type = BTreeMap<String, OptionValue>)]
    pub options: serde_json::Map<String, serde_json::Value>,
    /// The `radius` of frames that give none (default 0).
    #[serde(default)]
    #[schema(value_type = Option<f64>, default = 0, minimum = 0)]
    pub radius: Option<Number>,
    /// The `angle` of frames that give none (default 0).
    #[serde(default)]
    #[schema(value_type = Option<f64>, default = 0, minimum = 0, maximum = 180)]
    pub angle: Option<Number>,
}

/// The body of `POST /walkthroughs/{wid}/users`, all optional: with a
/// scene (and the method and options the walkthrough was made with), a
/// walkthrough the replica does not hold is made again under the same id
/// (`proto/scale-out.md`); without, an unknown walkthrough is 404.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JoinRequest {
    /// The walkthrough's scene id.
    #[serde(default)]
    pub scene: Option<String>,
    /// Its culling method (default `auto`).
    #[serde(default)]
    pub method: Option<String>,
    /// The method's knobs.
    #[serde(default)]
    #[schema(value_type = BTreeMap<String, OptionValue>)]
    pub options: serde_json::Map<String, serde_json::Value>,
    /// The walkthrough's `radius` for frames that give none (default 0).
    #[serde(default)]
    #[schema(value_type = Option<f64>, default = 0, minimum = 0)]
    pub radius: Option<Number>,
    /// The walkthrough's `angle` for frames that give none (default 0).
    #[serde(default)]
    #[schema(value_type = Option<f64>, default = 0, minimum = 0, maximum = 180)]
    pub angle: Option<Number>,
}

/// A box in world coordinates.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct Bounds {
    /// Smallest corner.
    #[schema(min_items = 3, max_items = 3)]
    pub min: [f64; 3],
    /// Largest corner.
    #[schema(min_items = 3, max_items = 3)]
    pub max: [f64; 3],
}

/// One entry of `GET /scenes`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct SceneInfo {
    /// The scene id: its file stem (`city1k.glb` → `city1k`).
    pub id: String,
    /// Number of objects.
    pub objects: usize,
    /// Number of triangles.
    pub triangles: usize,
    /// World bounds; `null` for a scene without triangles.
    #[schema(required = true)]
    pub bounds: Option<Bounds>,
    /// The up axis.
    #[schema(min_items = 3, max_items = 3)]
    pub up: [f32; 3],
    /// Methods it supports (`auto` is always accepted besides).
    pub methods: Vec<String>,
    /// Methods it does not support, each with why (e.g. `horizon` on a
    /// scene that is no height field over a ground).
    pub unsupported: BTreeMap<String, String>,
    /// The options each method it supports takes, and `auto`'s (e.g.
    /// `"supporting_planes": ["k", "lambda", "min_cost", "temporal"]`): the
    /// keys of a request's `options`, for clients' forms.
    #[serde(default)]
    pub options: BTreeMap<String, Vec<String>>,
    /// What `auto` answers with here, and the measurements behind it
    /// (absent from servers older than the ranking; read as unmeasured).
    #[serde(default)]
    pub auto: AutoInfo,
}

/// `auto` on one scene: its choice at the server's prices and the ranking
/// it chose from.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct AutoInfo {
    /// The method `auto` answers with at the server's prices.
    pub choice: String,
    /// `measured` once the scene's methods were measured; `unmeasured`
    /// before (or with `rank_methods = false`): then `auto` is frustum.
    pub status: String,
    /// The server's price of drawing a triangle, ns (a request may name
    /// its own: `auto` with `{"cost_per_triangle_ns": 10}`).
    pub cost_per_triangle_ns: f64,
    /// The server's price of sending a byte of geometry, ns.
    pub cost_per_byte_ns: f64,
    /// The walks the sample views came from.
    pub walks: Vec<String>,
    /// Sample views in all.
    pub frames: usize,
    /// Every conservative method measured, cheapest first at the server's prices.
    pub ranking: Vec<RankedMethod>,
}

/// One method as `auto` measured it on a scene.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct RankedMethod {
    /// The method (default options).
    pub method: String,
    /// Mean cull time, µs: CPU time of the thread that culled (so a server
    /// busy while it measures does not inflate it), wall time for a device
    /// method.
    pub mean_cull_us: f64,
    /// Median cull time, µs, measured alike.
    pub median_cull_us: f64,
    /// Mean objects in the answer.
    pub mean_pvs: f64,
    /// Mean triangles in the answer.
    pub mean_pvs_triangles: f64,
    /// Mean bytes of the answer's geometry (36 a triangle).
    pub mean_pvs_bytes: f64,
    /// Modelled frame cost at the server's prices, µs: cull + triangles ×
    /// cost_per_triangle_ns + bytes × cost_per_byte_ns.
    pub frame_cost_us: f64,
}

/// One entry of `GET /scenes/{id}/objects`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct ObjectInfo {
    /// The object id.
    pub id: u32,
    /// Its name.
    pub name: String,
    /// World bounds; `null` for an object with no triangles.
    #[schema(required = true)]
    pub bounds: Option<Bounds>,
}

/// One camera of a walk (`GET /scenes/{id}/walk`): a view without its
/// image size, which is the client's.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct WalkView {
    /// Eye position, world coordinates.
    pub eye: [f64; 3],
    /// Viewing direction, unit length.
    pub forward: [f64; 3],
    /// Up direction.
    pub up: [f64; 3],
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Near plane distance.
    pub near: f64,
    /// Far plane distance.
    pub far: f64,
}

/// The answer of `GET /scenes/{id}/walk`: a path through the scene that
/// clients replay (the web viewer's start and its auto-walk, scripted
/// tests, the example client).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct WalkResponse {
    /// `street`, `random`, `orbit` or `views` (what `pvsd eval --walk` takes).
    pub kind: String,
    /// Metres between views, when asked for (`step`); `null`: the walk's own.
    #[schema(required = true)]
    pub step: Option<f64>,
    /// The cameras, in order.
    pub views: Vec<WalkView>,
}

/// The body of `POST /scenes/{id}/meshes`: the objects whose triangles
/// the client wants, answered in this order, a repeated id once
/// (`application/x-pvs-mesh`).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq, Eq, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MeshesRequest {
    /// Object ids (at most the server's JSON array limit, 1,024 by default).
    pub ids: Vec<u32>,
}

/// The body of `PUT /scenes/{id}/objects/{oid}`: the object's new world
/// transform, as a glTF node's (translation, then rotation, then scale;
/// each optional, identity when absent).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MoveRequest {
    /// World translation `[x, y, z]`.
    #[serde(default)]
    pub translation: Option<[f64; 3]>,
    /// World rotation, a unit quaternion `[x, y, z, w]`.
    #[serde(default)]
    pub rotation: Option<[f64; 4]>,
    /// Scale `[x, y, z]`, applied first.
    #[serde(default)]
    pub scale: Option<[f64; 3]>,
}

/// The `stats` of an answer: what it cost.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct Stats {
    /// The method that answered (`auto` resolved).
    pub method: String,
    /// Cull time, microseconds.
    pub cull_us: f64,
    /// Hierarchy nodes tested.
    pub nodes_tested: u64,
    /// Objects in the frustum; `null` when the method does not count them
    /// (occlusion methods drop hidden subtrees uncounted).
    #[schema(required = true)]
    pub in_frustum: Option<u64>,
    /// Objects in the answer.
    pub visible: u64,
    /// Only when the asked method could not answer this view (e.g. a lost
    /// device): the method that answered instead, e.g. `frustum`, whose
    /// answer is conservative too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false)]
    pub fallback: Option<String>,
    /// Only with `fallback`: why the asked method could not answer.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false)]
    pub fallback_reason: Option<String>,
    /// Only for a region: the largest `radius` of the request's views.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false)]
    pub radius: Option<f64>,
    /// Only for a region: the largest `angle` of the request's views.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false)]
    pub angle: Option<f64>,
    /// Only for several views: how many were answered together.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false)]
    pub views: Option<u32>,
}

/// The answer of `POST /scenes/{id}/visible`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct VisibleResponse {
    /// Possibly visible object ids, ascending.
    pub visible: Vec<u32>,
    /// Per id of `visible`, an upper bound of the pixels it covers; only
    /// when the method was asked for them (`horizon` with `areas=true`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false)]
    pub areas: Option<Vec<f64>>,
    /// What it cost.
    pub stats: Stats,
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

/// The answer of `POST /sessions`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct SessionCreated {
    /// The session id, `<routing key>-<secret>`: 16 hex digits a load
    /// balancer hashes on (`proto/scale-out.md`), `-`, then 128 random
    /// bits as 32 hex digits; whoever holds it owns the session.
    pub session: String,
    /// The method that answers its frames (`auto` resolved).
    pub method: String,
}

/// A session frame: the change from `base` to this frame's visible set
/// (JSON, or `application/x-pvs` as `proto/wire-format.md` gives it).
/// Apply `removed`, then `added`, to the set held for `base`.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq, ToSchema)]
#[schema(as = Frame)]
pub struct FrameResponse {
    /// This frame's number: 1 for the session's first, then one more each frame.
    pub frame: u64,
    /// The frame the delta is against; `null`: `added` is the whole set.
    #[schema(required = true)]
    pub base: Option<u64>,
    /// Ids visible now and not in `base`, ascending.
    pub added: Vec<u32>,
    /// Ids in `base` and not visible now, ascending.
    pub removed: Vec<u32>,
    /// In a walkthrough only: the other users whose avatars may be
    /// visible, ascending.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false)]
    pub users_visible: Option<Vec<String>>,
    /// Only on a WebSocket opened with `stats=true`: what the frame's cull
    /// cost, for clients that show it (the web viewer's panel).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false)]
    pub stats: Option<Stats>,
}

impl FrameResponse {
    /// The JSON body.
    pub fn to_json(&self) -> Vec<u8> {
        let users = self.users_visible.as_ref().map_or(0, |u| u.len() * 5);
        json_sized(self, self.added.len() + self.removed.len() + users)
    }
}

/// The answer of `POST /walkthroughs`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct WalkthroughCreated {
    /// The walkthrough id.
    pub walkthrough: String,
    /// The method its users' frames are answered with (`auto` resolved).
    pub method: String,
}

/// The answer of `POST /walkthroughs/{wid}/users`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct UserJoined {
    /// The user's id, as others see it in `users_visible`.
    pub user: String,
    /// The user's session: send its frames there. It carries the
    /// walkthrough's routing key.
    pub session: String,
    /// True when this join made the walkthrough again (it was lost): the
    /// user may be the first one back.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub recreated: bool,
}

/// Where a user last stood (world coordinates).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct Pose {
    /// The eye.
    #[schema(min_items = 3, max_items = 3)]
    pub eye: [f64; 3],
    /// The viewing direction.
    #[schema(min_items = 3, max_items = 3)]
    pub forward: [f64; 3],
    /// The up direction.
    #[schema(min_items = 3, max_items = 3)]
    pub up: [f64; 3],
}

/// One user of `GET /walkthroughs/{wid}`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct UserInfo {
    /// The user id.
    pub user: String,
    /// The last frame's camera; `null` before the first frame.
    #[schema(required = true)]
    pub pose: Option<Pose>,
    /// Frames answered.
    pub frames: u64,
}

/// The answer of `GET /walkthroughs/{wid}`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
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

#[cfg(test)]
mod tests {
    use super::*;

    fn stats(fallback: Option<(&str, &str)>) -> Stats {
        Stats {
            method: "gpu".into(),
            cull_us: 1.5,
            nodes_tested: 3,
            in_frustum: None,
            visible: 2,
            fallback: fallback.map(|f| f.0.into()),
            fallback_reason: fallback.map(|f| f.1.into()),
            radius: None,
            angle: None,
            views: None,
        }
    }

    #[test]
    fn a_fallback_is_said_only_when_there_was_one() {
        let plain = serde_json::to_value(stats(None)).unwrap();
        assert_eq!(
            plain,
            serde_json::json!({"method": "gpu", "cull_us": 1.5, "nodes_tested": 3,
                "in_frustum": null, "visible": 2})
        );
        let fell = stats(Some(("frustum", "device lost")));
        let json = serde_json::to_value(&fell).unwrap();
        assert_eq!(json["fallback"], "frustum");
        assert_eq!(json["fallback_reason"], "device lost");
        assert_eq!(serde_json::from_value::<Stats>(json).unwrap(), fell);
        assert_eq!(serde_json::from_value::<Stats>(plain).unwrap(), stats(None));
    }
}

/// The answer of `POST /admin/reload` (and what `SIGHUP` logs): which
/// scene files were read again and swapped in, which had not changed, and
/// which could not be loaded (their old scene serves on).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct ReloadReport {
    /// Scenes whose file changed, now serving the new version; their
    /// sessions get the whole set (`base: null`) at their next frame.
    pub reloaded: Vec<String>,
    /// Scenes whose file had not changed: same scene, same ids.
    pub unchanged: Vec<String>,
    /// Scenes whose file could not be read or loaded.
    pub failed: Vec<ReloadFailure>,
}

/// A scene file a reload could not use.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, ToSchema)]
pub struct ReloadFailure {
    /// The scene.
    pub scene: String,
    /// Why (the file and the problem).
    pub error: String,
}
