//! Multi-user walkthroughs: users see each other's avatars in the open, not
//! behind their backs, and (with an occlusion method) not behind a wall;
//! `users_visible` never drops an avatar that ground truth shows; users
//! leave with their sessions.

mod common;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use common::server::{Server, view_json};
use common::{CHECK_VIEWPORT, city_scene, cuboid, fetch};
use glam::{DVec3, Vec3};
use pvsd::cull::{CullJob, MethodSpec, View};
use pvsd::eval::{WalkKind, WalkParams, walk};
use pvsd::geom::Camera;
use pvsd::scene::{Scene, SceneBuilder};
use pvsd::server::walkthrough::avatar;
use pvsd::server::{Limits, SessionLimits};
use pvsd::truth::Truth;
use pvsd_proto::json::{FrameResponse, UserJoined, WalkthroughCreated, WalkthroughInfo};
use serde_json::json;

/// Flat ground at y = 0 and one wall, x 20–21, z −10–10, 6 m high, both
/// flagged as occluders (as `pvsd gen` flags walls).
fn yard() -> Arc<Scene> {
    let mut b = SceneBuilder::new("yard");
    b.begin_object("ground", Some(true));
    let g = |x: f64, z: f64| DVec3::new(x, 0.0, z);
    b.add_triangles(
        [
            [g(-100.0, -100.0), g(-100.0, 100.0), g(100.0, 100.0)],
            [g(-100.0, -100.0), g(100.0, 100.0), g(100.0, -100.0)],
        ],
        false,
    );
    b.begin_object("wall", Some(true));
    b.add_triangles(
        cuboid(Vec3::new(20.0, 0.0, -10.0), Vec3::new(21.0, 6.0, 10.0)),
        false,
    );
    Arc::new(b.finish())
}

fn camera(eye: [f64; 3], forward: [f64; 3]) -> Camera {
    Camera {
        eye: DVec3::from(eye),
        forward: DVec3::from(forward),
        ..Camera::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn users_see_each_other_in_the_open_not_behind_their_backs_or_a_wall() {
    let scene = yard();
    let methods = common::prepare(scene.clone()).names();
    assert!(
        methods.contains(&"horizon") && methods.contains(&"occlusion_tree"),
        "{methods:?}"
    );
    let s = Server::with(vec![scene], Limits::default()).await;
    let c = reqwest::Client::new();
    // A looks +x at B; C stands behind A; D stands behind the wall.
    let poses = [
        ("a", camera([0.0, 1.7, 0.0], [1.0, 0.0, 0.0])),
        ("b", camera([10.0, 1.7, 0.0], [-1.0, 0.0, 0.0])),
        ("c", camera([-10.0, 1.7, 0.0], [1.0, 0.0, 0.0])),
        ("d", camera([30.0, 1.7, 0.0], [-1.0, 0.0, 0.0])),
    ];
    for method in methods {
        let w: WalkthroughCreated = fetch(
            c.post(s.url("/walkthroughs"))
                .json(&json!({"scene": "yard", "method": method})),
        )
        .await;
        assert_eq!(w.method, method);
        let mut users = BTreeMap::new();
        for (name, _) in &poses {
            let u: UserJoined =
                fetch(c.post(s.url(&format!("/walkthroughs/{}/users", w.walkthrough)))).await;
            users.insert(*name, u);
        }
        let name_of = |id: &str| *users.iter().find(|(_, u)| u.user == id).unwrap().0;
        let frame = |name: &str, cam: &Camera| {
            let url = s.url(&format!("/sessions/{}/frames", users[name].session));
            let req = c.post(url).json(&view_json(cam));
            async move { fetch::<FrameResponse>(req).await }
        };
        // First round: poses; nobody has one before its own first frame.
        let first = frame("a", &poses[0].1).await;
        assert_eq!(first.users_visible, Some(vec![]));
        for (name, cam) in &poses[1..] {
            frame(name, cam).await;
        }
        let mut seen = BTreeMap::new();
        for (name, cam) in &poses {
            let f = frame(name, cam).await;
            let mut names: Vec<&str> = f
                .users_visible
                .unwrap()
                .iter()
                .map(|u| name_of(u))
                .collect();
            names.sort();
            seen.insert(*name, names);
        }
        let occludes = method != "frustum";
        assert_eq!(
            seen["a"],
            if occludes { vec!["b"] } else { vec!["b", "d"] },
            "{method}"
        );
        // B looks back past A at C (avatars hide nothing).
        assert_eq!(seen["b"], ["a", "c"], "{method}");
        assert_eq!(
            seen["c"],
            if occludes {
                vec!["a", "b"]
            } else {
                vec!["a", "b", "d"]
            },
            "{method}"
        );
        let behind_wall: Vec<&str> = if occludes {
            vec![]
        } else {
            vec!["a", "b", "c"]
        };
        assert_eq!(seen["d"], behind_wall, "{method}: the wall hides everyone");

        let info: WalkthroughInfo =
            fetch(c.get(s.url(&format!("/walkthroughs/{}", w.walkthrough)))).await;
        assert_eq!(info.users.len(), 4);
        assert_eq!(info.scene, "yard");
        let b = info
            .users
            .iter()
            .find(|u| u.user == users["b"].user)
            .unwrap();
        assert_eq!(b.pose.as_ref().unwrap().eye, [10.0, 1.7, 0.0]);
        assert_eq!(b.frames, 2);
        // B leaves: A no longer sees it, the walkthrough no longer lists it.
        let r = c
            .delete(s.url(&format!("/sessions/{}", users["b"].session)))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 204);
        let f = frame("a", &poses[0].1).await;
        assert!(!f.users_visible.unwrap().contains(&users["b"].user));
        let info: WalkthroughInfo =
            fetch(c.get(s.url(&format!("/walkthroughs/{}", w.walkthrough)))).await;
        assert_eq!(info.users.len(), 3);
    }
    let r = c.get(s.url("/walkthroughs/nope")).send().await.unwrap();
    assert_eq!(r.status(), 404);
    let r = c
        .post(s.url("/walkthroughs"))
        .json(&json!({"scene": "yard", "method": "bogus"}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_user_whose_session_expires_leaves_the_walkthrough() {
    let limits = Limits {
        sessions: SessionLimits {
            idle: Duration::from_millis(600),
            ..SessionLimits::default()
        },
        ..Limits::default()
    };
    let s = Server::with(vec![yard()], limits).await;
    let c = reqwest::Client::new();
    let w: WalkthroughCreated = fetch(
        c.post(s.url("/walkthroughs"))
            .json(&json!({"scene": "yard"})),
    )
    .await;
    let join = || async {
        fetch::<UserJoined>(c.post(s.url(&format!("/walkthroughs/{}/users", w.walkthrough)))).await
    };
    let (stays, idles) = (join().await, join().await);
    let view = view_json(&camera([0.0, 1.7, 0.0], [1.0, 0.0, 0.0]));
    for i in 0..12 {
        let who = if i == 0 { &idles } else { &stays };
        let r = c
            .post(s.url(&format!("/sessions/{}/frames", who.session)))
            .json(&view)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let info: WalkthroughInfo =
        fetch(c.get(s.url(&format!("/walkthroughs/{}", w.walkthrough)))).await;
    let ids: Vec<&str> = info.users.iter().map(|u| u.user.as_str()).collect();
    assert_eq!(ids, [stays.user.as_str()]);
    let r = c
        .post(s.url(&format!("/sessions/{}/frames", idles.session)))
        .json(&view)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 410);
}

/// Avatars as occludees against ground truth: the scene plus the avatars as real
/// boxes is rendered; every avatar that shows a pixel must be reported
/// visible by every method of the scene.
#[test]
fn users_visible_never_drops_an_avatar_truth_shows() {
    avatars_against_truth([0.0; 3]);
}

/// DESIGN's numerical extreme: the same far from the origin.
#[test]
fn users_visible_never_drops_an_avatar_truth_shows_at_1e6() {
    avatars_against_truth([1e6, 0.0, 1e6]);
}

fn avatars_against_truth(offset: [f32; 3]) {
    let scene = city_scene(300, 11, offset);
    let params = |kind, seed| WalkParams {
        kind,
        frames: 24,
        seed,
        viewport: CHECK_VIEWPORT,
        ..WalkParams::default()
    };
    let cams = walk(&scene, &params(WalkKind::Street, 5)).unwrap();
    // Avatars where walkers stand: along this walk (ahead of and behind
    // the camera) and on other streets.
    let mut eyes: Vec<DVec3> = cams.iter().skip(1).step_by(2).map(|c| c.eye).collect();
    for seed in [6, 7] {
        eyes.extend(
            walk(&scene, &params(WalkKind::Street, seed))
                .unwrap()
                .iter()
                .step_by(3)
                .map(|c| c.eye),
        );
    }
    let boxes: Vec<_> = eyes.iter().map(|&e| avatar(e, scene.origin)).collect();
    // The same scene with the avatars as objects, for truth.
    let mut b = SceneBuilder::new("city+avatars");
    for o in scene.objects() {
        b.begin_object(o.name.clone(), o.occluder_hint);
        let origin = scene.origin;
        b.add_triangles(
            scene
                .object_triangles(o)
                .iter()
                .map(|t| t.map(|v| v.as_dvec3() + origin)),
            false,
        );
    }
    let first = b.object_count() as u32;
    for bx in &boxes {
        b.begin_object("avatar", Some(false));
        // Built in local coordinates, moved to the world in f64: at 1e6 an
        // f32 world box would not be the box the method tests.
        let mut m = pvsd::scene::generate::MeshBuilder::new();
        m.cuboid(bx.min, bx.max, true);
        b.add_triangles(
            m.build(false)
                .triangles()
                .map(|t| t.map(|v| v.as_dvec3() + scene.origin)),
            false,
        );
    }
    let with_avatars = b.finish();
    let library = common::prepare(scene.clone());
    for name in library.names() {
        let spec: MethodSpec = name.parse().unwrap();
        let (method, cache) = library.prepare_client(&spec).unwrap();
        let mut job = Some(CullJob::new(View::new(cams[0], &scene).unwrap(), cache));
        let (mut shown, mut culled_in_frustum) = (0, 0);
        for (f, cam) in cams.iter().enumerate() {
            let view = View::new(*cam, &scene).unwrap();
            let mut next = job.take().unwrap();
            next.view = view;
            next.occludees.set_boxes(boxes.iter().copied());
            let culled = library.cull_blocking(&method, next).unwrap();
            assert!(culled.stats.fallback.is_none(), "{name} fell back");
            let visible = culled.job.occludees.visible().to_vec();
            job = Some(culled.job);
            let truth = Truth::render(&with_avatars, cam).unwrap();
            for id in truth.visible().into_iter().filter(|&id| id >= first) {
                let i = (id - first) as usize;
                shown += 1;
                assert!(
                    visible[i],
                    "{name} frame {f}: avatar {i} at {:?} shows but was dropped",
                    eyes[i]
                );
            }
            culled_in_frustum += boxes
                .iter()
                .zip(&visible)
                .filter(|(b, v)| !**v && view.frustum().intersects(b))
                .count();
        }
        eprintln!("{name}: {shown} avatars shown, {culled_in_frustum} culled inside the frustum");
        assert!(
            shown > 0,
            "the walk shows no avatar: the check checks nothing"
        );
        if name != "frustum" {
            assert!(
                culled_in_frustum > 0,
                "{name} hides no avatar: is it testing them?"
            );
        }
    }
}
