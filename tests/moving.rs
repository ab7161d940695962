//! Moving objects (Tai & Hsu §3.1): objects a scene file marks movable stay
//! out of every method's static structures and are culled where they are
//! now. Through a real server: a box moved from behind a wall into the
//! open is in every method's next frame; a movable panel hides nothing;
//! only the admin token moves anything, and a refused move moves nothing.

mod common;

use std::path::Path;
use std::sync::Arc;

use common::server::{Held, Server, view_json};
use glam::{DVec3, Vec3};
use pvsd::cull::{
    CullCounters, CullError, CullMethod, MethodContext, MethodEntry, MethodError, MethodOptions,
    Occludees, Registry, View, VisibleSet,
};
use pvsd::geom::Camera;
use pvsd::scene::generate::MeshBuilder;
use pvsd::scene::glb::{Document, Node};
use pvsd::scene::{Scene, load_slice};
use pvsd::server::{AppState, Limits};
use pvsd_proto::json::FrameResponse;
use serde_json::{Value, json};

const TOKEN: &str = "let-me-move-things";

/// Ids in the yard (the loader's pre-order: the root's children in order).
const GROUND: u32 = 0;
const WALL: u32 = 1;
const BOX: u32 = 2;
const PANEL: u32 = 3;
const CRATE: u32 = 4;

/// A yard: a ground and a wall (occluders), a movable box behind the wall,
/// a movable panel (flagged occluder too, to tempt the methods) in front of
/// a static crate, all seen from the south.
fn yard() -> Arc<Scene> {
    let mut doc = Document::default();
    let mut children = Vec::new();
    let mut add =
        |doc: &mut Document, name: &str, min: Vec3, max: Vec3, at: [f32; 3], extras: Value| {
            let mut m = MeshBuilder::new();
            m.cuboid(min, max, true);
            let mesh = doc.add_mesh(m.build(false));
            let mut node = Node::named(name);
            node.mesh = Some(mesh);
            node.translation = at;
            node.extras = Some(extras);
            children.push(doc.add_node(node));
        };
    let occluder = json!({"occluder": true});
    add(
        &mut doc,
        "ground",
        Vec3::new(-20.0, -0.2, -20.0),
        Vec3::new(60.0, 0.0, 60.0),
        [0.0; 3],
        occluder.clone(),
    );
    add(
        &mut doc,
        "wall",
        Vec3::new(5.0, 0.0, 20.0),
        Vec3::new(35.0, 6.0, 20.5),
        [0.0; 3],
        occluder,
    );
    add(
        &mut doc,
        "box",
        Vec3::new(-0.5, 0.0, -0.5),
        Vec3::new(0.5, 1.0, 0.5),
        [20.0, 0.0, 30.0],
        json!({"movable": true}),
    );
    add(
        &mut doc,
        "panel",
        Vec3::new(-3.0, 0.0, -0.1),
        Vec3::new(3.0, 3.0, 0.1),
        [26.0, 0.0, 10.0],
        json!({"movable": true, "occluder": true}),
    );
    add(
        &mut doc,
        "crate",
        Vec3::new(25.5, 0.0, 14.0),
        Vec3::new(26.5, 1.0, 15.0),
        [0.0; 3],
        json!({}),
    );
    let mut root = Node::named("yard");
    root.children = children;
    let root = doc.add_node(root);
    doc.roots.push(root);
    Arc::new(load_slice("yard", &doc.to_glb(), None, Path::new("yard.glb")).unwrap())
}

/// Standing south of everything, looking north at the wall.
fn camera() -> Camera {
    Camera {
        eye: DVec3::new(20.0, 1.7, 0.0),
        forward: DVec3::Z,
        up: DVec3::Y,
        fov_y_deg: 70.0,
        aspect: 1.6,
        near: 0.1,
        far: 1000.0,
        viewport: [256, 160],
    }
}

/// Every method of the registry this machine serves for the yard.
fn methods(s: &Server, scenes: &Value) -> Vec<String> {
    let _ = s;
    let yard = scenes
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["id"] == "yard")
        .unwrap();
    yard["methods"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap().to_string())
        .collect()
}

async fn put(
    c: &reqwest::Client,
    s: &Server,
    oid: &str,
    token: Option<&str>,
    body: Value,
) -> (u16, Value) {
    let mut req = c
        .put(s.url(&format!("/scenes/yard/objects/{oid}")))
        .json(&body);
    if let Some(t) = token {
        req = req.bearer_auth(t);
    }
    let res = req.send().await.unwrap();
    let status = res.status().as_u16();
    (status, res.json().await.unwrap())
}

/// The session's next frame from [`camera`], applied to what it holds.
async fn next_frame(c: &reqwest::Client, s: &Server, sid: &str, held: &mut Held) {
    let f: FrameResponse = common::fetch(
        c.post(s.url(&format!("/sessions/{sid}/frames")))
            .json(&view_json(&camera())),
    )
    .await;
    held.apply(&f);
}

async fn bounds_of(c: &reqwest::Client, s: &Server, id: u32) -> Value {
    let objects: Value = common::fetch(c.get(s.url("/scenes/yard/objects"))).await;
    objects[id as usize]["bounds"].clone()
}

#[test]
fn the_yard_loads_its_movers() {
    let scene = yard();
    assert_eq!(scene.objects()[BOX as usize].name, "box");
    assert_eq!(scene.objects()[CRATE as usize].name, "crate");
    let movers: Vec<u32> = scene.motion().ids().collect();
    assert_eq!(movers, [BOX, PANEL]);
    assert!(scene.objects()[GROUND as usize].is_static());
    assert!(!scene.objects()[BOX as usize].is_static());
    let tree = pvsd::spatial::KdTree::build(&scene, Default::default());
    tree.validate(&scene).unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_box_moved_into_the_open_is_in_every_methods_next_frame() {
    let state = AppState::new(vec![yard()], Limits::default())
        .unwrap()
        .with_admin_token(Some(TOKEN.into()));
    let s = Server::start(state).await;
    let c = reqwest::Client::new();
    let scenes: Value = common::fetch(c.get(s.url("/scenes"))).await;
    let methods = methods(&s, &scenes);
    assert!(methods.len() >= 4, "{methods:?}");

    // A session per method, each with its first frame: the box is behind
    // the wall, the crate behind the movable panel.
    let mut sessions = Vec::new();
    for m in &methods {
        let created: Value = common::fetch(
            c.post(s.url("/sessions"))
                .json(&json!({"scene": "yard", "method": m})),
        )
        .await;
        let sid = created["session"].as_str().unwrap().to_string();
        let mut held = Held::default();
        next_frame(&c, &s, &sid, &mut held).await;
        // The panel hides nothing: it may move, so no method occludes with it.
        assert!(
            held.ids.contains(&CRATE),
            "{m} hid the crate behind the movable panel"
        );
        assert!(held.ids.contains(&WALL), "{m}");
        sessions.push((m.clone(), sid, held));
    }

    // Into the open, in front of the wall.
    let (status, moved) = put(
        &c,
        &s,
        "2",
        Some(TOKEN),
        json!({"translation": [18.0, 0.0, 12.0]}),
    )
    .await;
    assert_eq!(status, 200, "{moved}");
    assert_eq!(moved["bounds"]["min"], json!([17.5, 0.0, 11.5]));
    assert_eq!(bounds_of(&c, &s, BOX).await, moved["bounds"]);

    for (m, sid, held) in &mut sessions {
        next_frame(&c, &s, sid, held).await;
        assert!(
            held.ids.contains(&BOX),
            "{m}: the moved box is not in the next frame"
        );
    }
    // And a stateless answer sees it too.
    let mut body = view_json(&camera());
    body["method"] = json!("frustum");
    let v: Value = common::fetch(c.post(s.url("/scenes/yard/visible")).json(&body)).await;
    assert!(
        v["visible"].as_array().unwrap().contains(&json!(BOX)),
        "{v}"
    );

    // Back behind the wall: a method that sees occlusion may drop it again.
    let (status, _) = put(
        &c,
        &s,
        "2",
        Some(TOKEN),
        json!({"translation": [20.0, 0.0, 30.0]}),
    )
    .await;
    assert_eq!(status, 200);
    let mut dropped = Vec::new();
    for (m, sid, held) in &mut sessions {
        next_frame(&c, &s, sid, held).await;
        if !held.ids.contains(&BOX) {
            dropped.push(m.clone());
        }
    }
    eprintln!("behind the wall again, dropped by {dropped:?}");
    assert!(
        !dropped.contains(&"frustum".to_string()),
        "the box is in the frustum"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_the_admin_token_moves_and_a_refused_move_moves_nothing() {
    let c = reqwest::Client::new();
    // No token configured: moving is off.
    let s = Server::with(vec![yard()], Limits::default()).await;
    let before = bounds_of(&c, &s, BOX).await;
    let (status, v) = put(
        &c,
        &s,
        "2",
        Some(TOKEN),
        json!({"translation": [0.0, 0.0, 0.0]}),
    )
    .await;
    assert_eq!(
        (status, v["error"]["code"].as_str()),
        (403, Some("forbidden")),
        "{v}"
    );
    assert_eq!(bounds_of(&c, &s, BOX).await, before);

    let state = AppState::new(vec![yard()], Limits::default())
        .unwrap()
        .with_admin_token(Some(TOKEN.into()));
    let s = Server::start(state).await;
    let here = json!({"translation": [1.0, 0.0, 1.0]});
    for (token, oid, body, status, code) in [
        (None, "2", here.clone(), 401, "unauthorized"),
        (Some("wrong"), "2", here.clone(), 401, "unauthorized"),
        (Some(TOKEN), "4", here.clone(), 409, "static_object"),
        (Some(TOKEN), "99", here.clone(), 404, "unknown_object"),
        (Some(TOKEN), "box", here.clone(), 404, "unknown_object"),
        (
            Some(TOKEN),
            "2",
            json!({"rotation": [0, 0, 0, 2]}),
            400,
            "invalid_transform",
        ),
        (
            Some(TOKEN),
            "2",
            json!({"scale": [1, 0, 1]}),
            400,
            "invalid_transform",
        ),
        (
            Some(TOKEN),
            "2",
            json!({"translation": [1, 2]}),
            400,
            "malformed_json",
        ),
        (
            Some(TOKEN),
            "2",
            json!({"translate": [1, 2, 3]}),
            400,
            "malformed_json",
        ),
    ] {
        let (got, v) = put(&c, &s, oid, token, body.clone()).await;
        assert_eq!(
            (got, v["error"]["code"].as_str()),
            (status, Some(code)),
            "{token:?} {oid} {body}: {v}"
        );
        assert_eq!(
            bounds_of(&c, &s, BOX).await,
            before,
            "a refused move moved the box"
        );
    }
    // A 401 says how to authenticate.
    let res = c
        .put(s.url("/scenes/yard/objects/2"))
        .json(&here)
        .send()
        .await
        .unwrap();
    assert!(res.headers().contains_key("www-authenticate"));
    // Rotation and scale carry the box around its own origin.
    let (status, v) = put(
        &c,
        &s,
        "2",
        Some(TOKEN),
        json!({"translation": [5, 0, 5], "rotation": [0, std::f64::consts::FRAC_1_SQRT_2, 0, std::f64::consts::FRAC_1_SQRT_2], "scale": [2, 2, 2]}),
    )
    .await;
    assert_eq!(status, 200, "{v}");
    let (min, max) = (&v["bounds"]["min"], &v["bounds"]["max"]);
    for (axis, lo, hi) in [(0, 4.0, 6.0), (1, 0.0, 2.0), (2, 4.0, 6.0)] {
        assert!((min[axis].as_f64().unwrap() - lo).abs() < 1e-3, "{v}");
        assert!((max[axis].as_f64().unwrap() - hi).abs() < 1e-3, "{v}");
    }
}

/// A method that says it culls the movers itself, then fails: the frustum
/// fallback must still answer the movers.
struct FailsWithMovers;

impl CullMethod for FailsWithMovers {
    type State = ();
    fn name(&self) -> &'static str {
        "fails_with_movers"
    }
    fn new_state(&self, _: &MethodOptions) -> Result<(), MethodError> {
        Ok(())
    }
    fn is_conservative(&self, _: &()) -> bool {
        true
    }
    fn culls_movers(&self) -> bool {
        true
    }
    fn cull(
        &self,
        _: &View,
        _: &mut (),
        _: &mut VisibleSet,
        _: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        Err(CullError::Failed {
            method: "fails_with_movers",
            reason: "lost".into(),
        })
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fallback_answers_the_movers_of_a_method_that_culls_them_itself() {
    let registry = Registry::standard().with(MethodEntry {
        name: "fails_with_movers",
        purpose: "a test's method",
        checked_with: &[],
        options: &[],
        regions: None,
        build: |_| Ok(Arc::new(FailsWithMovers)),
    });
    let state = AppState::with_methods(
        vec![yard()],
        Limits::default(),
        &registry,
        &MethodContext::default(),
    )
    .unwrap()
    .with_admin_token(Some(TOKEN.into()));
    let s = Server::start(state).await;
    let c = reqwest::Client::new();
    let (status, _) = put(
        &c,
        &s,
        "2",
        Some(TOKEN),
        json!({"translation": [18.0, 0.0, 12.0]}),
    )
    .await;
    assert_eq!(status, 200);
    let mut body = view_json(&camera());
    body["method"] = json!("fails_with_movers");
    let v: Value = common::fetch(c.post(s.url("/scenes/yard/visible")).json(&body)).await;
    assert_eq!(v["stats"]["fallback"], "frustum", "{v}");
    let visible = v["visible"].as_array().unwrap();
    assert!(
        visible.contains(&json!(BOX)) && visible.contains(&json!(PANEL)),
        "{v}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_moved_objects_mesh_is_drawn_where_it_is_now() {
    let state = AppState::new(vec![yard()], Limits::default())
        .unwrap()
        .with_admin_token(Some(TOKEN.into()));
    let s = Server::start(state).await;
    let c = reqwest::Client::new();
    let mesh = |oid: u32| {
        let (c, url) = (
            c.clone(),
            s.url(&format!("/scenes/yard/objects/{oid}/mesh")),
        );
        async move {
            let res = c.get(url).send().await.unwrap();
            let tag = res.headers()["etag"].to_str().unwrap().to_string();
            let m = pvsd_proto::mesh::decode(&res.bytes().await.unwrap()).unwrap();
            let o = DVec3::from_array(m.origin);
            let low = m.meshes[0]
                .positions
                .iter()
                .map(|p| o + Vec3::from_array(*p).as_dvec3())
                .fold(DVec3::INFINITY, DVec3::min);
            (tag, m.meshes[0].movable, low)
        }
    };
    let (tag, movable, low) = mesh(BOX).await;
    assert!(movable);
    assert_eq!(low, DVec3::new(19.5, 0.0, 29.5));
    let (_, wall_movable, _) = mesh(WALL).await;
    assert!(!wall_movable);
    let (status, _) = put(&c, &s, "2", Some(TOKEN), json!({"translation": [10, 2, 5]})).await;
    assert_eq!(status, 200);
    let (moved_tag, _, moved_low) = mesh(BOX).await;
    assert_eq!(moved_low, DVec3::new(9.5, 2.0, 4.5));
    assert_ne!(
        moved_tag, tag,
        "new bytes, new tag: a cache asks again and gets them"
    );
}
