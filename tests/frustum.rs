//! `frustum` returns exactly the objects whose boxes pass the frustum test
//! (hierarchical = brute force), never misses a box that holds a point of the
//! frustum (checked by sampling, independently of the plane test), and does
//! so at every numerical extreme of DESIGN.

mod common;

use std::sync::Arc;

use common::{city_scene, office_scene, random_camera, rng, shared_scene};
use glam::{DMat4, DVec3};
use pvsd::cull::frustum::FrustumCulling;
use pvsd::cull::{MethodSpec, SceneMethods, View, VisibleSet};
use pvsd::geom::Camera;
use pvsd::scene::Scene;
use rand::Rng;

fn cull(methods: &SceneMethods, cam: Camera) -> Vec<u32> {
    let view = View::new(cam, methods.scene()).unwrap();
    let mut out = VisibleSet::new();
    let stats = methods
        .cull_once(&MethodSpec::named("frustum").unwrap(), &view, &mut out)
        .unwrap();
    assert_eq!(stats.visible as usize, out.len());
    assert!(
        out.ids().windows(2).all(|w| w[0] < w[1]),
        "sorted and unique"
    );
    out.ids().to_vec()
}

/// Hierarchical equals brute force, and every object with a sampled point of
/// its triangles inside the view is in the answer. The sampling check is
/// independent of the code under test: points lie on the real geometry, and
/// "inside" is decided by a glam projection matrix, not by `Frustum`.
fn check_view(methods: &SceneMethods, cam: Camera, per_object: usize, seed: u64) -> Vec<u32> {
    let scene = methods.scene();
    let got = cull(methods, cam);
    let view = View::new(cam, scene).unwrap();
    assert_eq!(
        got,
        FrustumCulling::reference(scene, view.frustum()),
        "hierarchical != brute force for {cam:?}"
    );
    let basis = cam.basis().unwrap();
    let clip_from_local =
        DMat4::perspective_rh(cam.fov_y_deg.to_radians(), cam.aspect, cam.near, cam.far)
            * DMat4::look_to_rh(view.eye(), basis.forward, basis.up);
    // Stay clear of the boundary by a sliver, so rounding cannot make a point
    // that is outside look inside.
    let inside = |p: DVec3| {
        let c = clip_from_local * p.extend(1.0);
        let m = 1.0 - 1e-6;
        c.w > 0.0
            && c.x.abs() <= m * c.w
            && c.y.abs() <= m * c.w
            && c.z >= 1e-6 * c.w
            && c.z <= m * c.w
    };
    let mut r = rng(seed);
    let mut seen = 0;
    for o in scene.objects() {
        let tris = scene.object_triangles(o);
        for _ in 0..per_object.min(tris.len() * 3) {
            let t = tris[r.random_range(0..tris.len())];
            let (a, b): (f64, f64) = (r.random(), r.random());
            let (a, b) = if a + b > 1.0 {
                (1.0 - a, 1.0 - b)
            } else {
                (a, b)
            };
            let p = t[0].as_dvec3() + (t[1] - t[0]).as_dvec3() * a + (t[2] - t[0]).as_dvec3() * b;
            if inside(p) {
                seen += 1;
                assert!(
                    got.binary_search(&o.id).is_ok(),
                    "object {} has point {p} in view but was culled",
                    o.id
                );
            }
        }
    }
    SAMPLED.with(|c| c.set(c.get() + seen));
    got
}

thread_local! {
    /// Sampled points that fell in view on this test's thread: proof the
    /// sampling check had something to check.
    static SAMPLED: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

fn sampled_in_view() -> usize {
    SAMPLED.with(|c| c.get())
}

fn prepared(scene: Arc<Scene>) -> SceneMethods {
    common::prepare(scene)
}

#[test]
fn equals_brute_force_on_random_views() {
    for (scene, views) in [
        (city_scene(1000, 1, [0.0; 3]), 150u32),
        (office_scene(1, [0.0; 3]), 150),
        (shared_scene("Sponza"), 100),
        (shared_scene("2CylinderEngine"), 60),
    ] {
        let m = prepared(scene);
        let mut r = rng(42);
        let mut nonempty = 0;
        let before = sampled_in_view();
        for i in 0..views {
            let cam = random_camera(&mut r, m.scene(), 0.2);
            nonempty += !check_view(&m, cam, 30, i as u64).is_empty() as u32;
        }
        assert!(
            nonempty > views / 4,
            "{}: the views see something ({nonempty})",
            m.scene().id
        );
        assert!(
            sampled_in_view() - before > 1000,
            "{}: points sampled in view",
            m.scene().id
        );
    }
}

#[test]
fn translated_scenes_give_the_same_answer() {
    let base = prepared(city_scene(300, 4, [0.0; 3]));
    for offset in [[1e6f32, 0.0, 1e6], [1e7, 1e7, -1e7]] {
        let moved = prepared(city_scene(300, 4, offset));
        // The root node rotates the city, then translates it by `offset`.
        let shift = DVec3::new(offset[0] as f64, offset[1] as f64, offset[2] as f64);
        let mut r = rng(9);
        for i in 0..150 {
            let cam = random_camera(&mut r, base.scene(), 0.2);
            let a = check_view(&base, cam, 10, i);
            let b = check_view(
                &moved,
                Camera {
                    eye: cam.eye + shift,
                    ..cam
                },
                10,
                i,
            );
            assert_eq!(a, b, "offset {offset:?}, view {i}");
        }
    }
}

#[test]
fn tiny_huge_and_degenerate_objects() {
    let m = prepared(common::scales_scene());
    let mut r = rng(5);
    for i in 0..200 {
        let mut cam = random_camera(&mut r, m.scene(), 0.0);
        cam.far = 1e6;
        check_view(&m, cam, 20, i);
    }
}

fn look(eye: DVec3, forward: DVec3, up: DVec3) -> Camera {
    Camera {
        eye,
        forward,
        up,
        ..Camera::default()
    }
}

#[test]
fn extreme_cameras() {
    let m = prepared(city_scene(500, 6, [0.0; 3]));
    let s = m.scene().clone();
    let (lo, hi) = s.to_world(&s.bounds());
    let mid = (lo + hi) * 0.5 + DVec3::Y * 1.7;
    let mut cams = vec![
        Camera {
            near: 1e-6,
            far: 1e9,
            ..look(mid, DVec3::X, DVec3::Y)
        },
        Camera {
            fov_y_deg: 0.01,
            ..look(mid, DVec3::new(1.0, 0.0, 0.3), DVec3::Y)
        },
        Camera {
            fov_y_deg: 179.0,
            ..look(mid, DVec3::new(1.0, 0.0, 0.3), DVec3::Y)
        },
        Camera {
            aspect: 0.01,
            ..look(mid, DVec3::Z, DVec3::Y)
        },
        Camera {
            aspect: 100.0,
            ..look(mid, DVec3::Z, DVec3::Y)
        },
        Camera {
            fov_y_deg: 179.0,
            aspect: 100.0,
            ..look(mid, DVec3::Z, DVec3::Y)
        },
        look(mid, DVec3::Y, DVec3::Z),     // straight up
        look(mid, DVec3::NEG_Y, DVec3::X), // straight down
        look(
            DVec3::new(mid.x, hi.y + 100.0, mid.z),
            DVec3::NEG_Y,
            DVec3::Z,
        ), // down from above
    ];
    // Eye exactly on the root's split plane, on box corners, inside boxes.
    let tree = pvsd::spatial::KdTree::build(&s, Default::default());
    if let pvsd::spatial::NodeKind::Inner { axis, split, .. } = tree.root().unwrap().kind {
        let mut eye = mid - s.origin;
        eye[axis as usize] = split as f64;
        cams.push(look(eye + s.origin, DVec3::X, DVec3::Y));
    }
    for o in s.objects().iter().step_by(50) {
        let corner = s.origin + o.bounds.max.as_dvec3();
        cams.push(look(corner, DVec3::new(-1.0, -0.2, 0.1), DVec3::Y));
        let inside = s.origin + o.bounds.center().as_dvec3();
        let cam = look(inside, DVec3::new(0.3, 0.1, 1.0), DVec3::Y);
        let got = check_view(&m, cam, 20, o.id as u64);
        assert!(
            got.contains(&o.id),
            "the object around the eye ({}) is seen",
            o.name
        );
    }
    for (i, cam) in cams.into_iter().enumerate() {
        check_view(&m, cam, 50, i as u64);
    }
}

#[test]
fn looking_away_sees_nothing_and_from_above_sees_much() {
    let m = prepared(city_scene(200, 2, [0.0; 3]));
    let s = m.scene().clone();
    let (lo, hi) = s.to_world(&s.bounds());
    let far_away = DVec3::new(hi.x + 1000.0, 2.0, hi.z + 1000.0);
    assert!(cull(&m, look(far_away, DVec3::new(1.0, 0.0, 1.0), DVec3::Y)).is_empty());
    let above = DVec3::new((lo.x + hi.x) / 2.0, 3000.0, (lo.z + hi.z) / 2.0);
    let all = cull(
        &m,
        Camera {
            fov_y_deg: 90.0,
            aspect: 1.0,
            ..look(above, DVec3::NEG_Y, DVec3::Z)
        },
    );
    assert_eq!(
        all.len(),
        s.objects().len(),
        "the whole city from high above"
    );
}

/// Regression: the city's ground quad is referenced by every kd leaf. With
/// node bounds as unions of whole boxes, every node's bounds was the whole
/// city and a 10° view tested all 1933 nodes; bounds clipped to the cells
/// keep the hierarchy useful.
#[test]
fn issue_2_a_ground_plane_does_not_defeat_the_hierarchy() {
    let m = prepared(city_scene(1000, 1, [0.0; 3]));
    let tree = pvsd::spatial::KdTree::build(m.scene(), Default::default());
    let cam = Camera {
        fov_y_deg: 10.0,
        ..look(
            DVec3::new(400.0, 1.7, 150.0),
            DVec3::new(1.0, 0.0, 0.27),
            DVec3::Y,
        )
    };
    let view = View::new(cam, m.scene()).unwrap();
    let mut out = VisibleSet::new();
    let stats = m
        .cull_once(&MethodSpec::named("frustum").unwrap(), &view, &mut out)
        .unwrap();
    assert!(stats.visible > 20, "{stats:?}");
    assert!(
        stats.nodes_tested * 4 < tree.nodes().len() as u64,
        "{} of {} nodes tested",
        stats.nodes_tested,
        tree.nodes().len()
    );
}
