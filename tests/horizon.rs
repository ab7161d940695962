//! `horizon` (Downs et al.): zero misses through the shared check on a 10k
//! city and at offsets of 1e6 and 1e7 (the 1k city is a row of the table in
//! tests/conservative.rs), at DESIGN's extremes for every method (straight up and down, the eye on a
//! prism face or inside a building, tall thin towers, huge offsets); prisms
//! inside their buildings by an independent ray-parity check; the LOD
//! bound against ground truth's pixel counts; where the method is listed.

mod common;

use std::sync::Arc;

use common::{
    assert_conservative, assert_seen, city_scene, cuboid, office_scene, rng, shared_scene,
};
use glam::{DVec2, DVec3, Vec3};
use pvsd::cull::horizon::HorizonCulling;
use pvsd::cull::{MethodSpec, Registry, SceneMethods, View, VisibleSet};
use pvsd::eval::WalkKind;
use pvsd::geom::Camera;
use pvsd::scene::Scene;
use pvsd::truth::Truth;
use rand::Rng;

#[test]
fn conservative_on_a_10k_city() {
    let scene = city_scene(10_000, 1, [0.0; 3]);
    let h = HorizonCulling::new(scene.clone()).unwrap();
    h.quadtree().validate(&scene).unwrap();
    for name in ["Sponza", "2CylinderEngine"] {
        let s = shared_scene(name);
        pvsd::spatial::QuadTree::build(&s).validate(&s).unwrap();
    }
    assert_conservative(&scene, "horizon", &[WalkKind::Street, WalkKind::Orbit], 12);
}

#[test]
fn conservative_far_from_the_origin_and_the_same_answer() {
    let near = city_scene(300, 5, [0.0; 3]);
    for offset in [1e6f32, 1e7] {
        let far = city_scene(300, 5, [offset, 0.0, -offset]);
        assert_conservative(&far, "horizon", &[WalkKind::Street], 15);
        // The same views, translated, give the same ids.
        let (a, b) = (common::prepare(near.clone()), common::prepare(far.clone()));
        let shift = DVec3::new(offset as f64, 0.0, -offset as f64);
        let params = pvsd::eval::WalkParams {
            kind: WalkKind::Street,
            frames: 10,
            ..Default::default()
        };
        for cam in pvsd::eval::walk(&near, &params).unwrap() {
            let moved = Camera {
                eye: cam.eye + shift,
                ..cam
            };
            assert_eq!(
                answer(&a, "horizon", cam),
                answer(&b, "horizon", moved),
                "offset {offset}"
            );
        }
    }
}

/// The ids `spec` returns for `cam`.
fn answer(methods: &SceneMethods, spec: &str, cam: Camera) -> Vec<u32> {
    let view = View::new(cam, methods.scene()).unwrap();
    let mut out = VisibleSet::new();
    methods
        .cull_once(&spec.parse().unwrap(), &view, &mut out)
        .unwrap();
    out.ids().to_vec()
}

#[test]
fn culls_with_other_column_counts_in_turn_answer_as_alone() {
    // One method lends its sweep buffers to every client: a 64-column and
    // a 1024-column client in turns must answer as each does on a method
    // of its own.
    let scene = city_scene(300, 4, [0.0; 3]);
    let shared = common::prepare(scene.clone());
    let params = pvsd::eval::WalkParams {
        kind: WalkKind::Street,
        frames: 12,
        ..Default::default()
    };
    let cams = pvsd::eval::walk(&scene, &params).unwrap();
    let mut in_turns = Vec::new();
    for &cam in &cams {
        for spec in ["horizon:columns=64", "horizon"] {
            in_turns.push(answer(&shared, spec, cam));
        }
    }
    let (coarse, fine) = (common::prepare(scene.clone()), common::prepare(scene));
    let alone: Vec<Vec<u32>> = cams
        .iter()
        .flat_map(|&cam| {
            [
                answer(&coarse, "horizon:columns=64", cam),
                answer(&fine, "horizon", cam),
            ]
        })
        .collect();
    assert_eq!(in_turns, alone);
    // The coarse horizon hides less somewhere on the walk, so the two
    // clients really do sweep with different columns.
    assert!(in_turns.chunks(2).any(|p| p[0].len() > p[1].len()));
}

/// Every method's answer for `cam` holds every truth-visible object
/// ([`common::check_camera`]); returns how many objects the truth saw.
fn check_camera(methods: &SceneMethods, cam: Camera) -> usize {
    common::check_camera(methods, &Registry::standard(), cam)
}

fn world_box(s: &Scene, id: u32) -> (DVec3, DVec3) {
    let b = s.objects()[id as usize].bounds;
    (b.min.as_dvec3() + s.origin, b.max.as_dvec3() + s.origin)
}

#[test]
fn extremes_vertical_views_prism_faces_inside_buildings() {
    let methods = common::prepare(city_scene(400, 9, [0.0; 3]));
    let s = methods.scene().clone();
    let h = HorizonCulling::new(s.clone()).unwrap();
    let mut r = rng(3);
    let street = {
        // A point of a street: the middle of the city, at eye height.
        let (lo, hi) = (
            s.bounds().min.as_dvec3() + s.origin,
            s.bounds().max.as_dvec3() + s.origin,
        );
        DVec3::new((lo.x + hi.x) * 0.5, 1.7, (lo.z + hi.z) * 0.5)
    };
    // Straight up and down, from the street and from above the roofs, with
    // wide and narrow views; and a pitched view whose frustum holds the zenith.
    // Narrow views straight up see only sky: half of these see something.
    let mut seen = Vec::new();
    for eye in [street, street + DVec3::Y * 40.0, street + DVec3::Y * 400.0] {
        for (forward, up) in [
            (DVec3::Y, DVec3::Z),
            (DVec3::NEG_Y, DVec3::X),
            (DVec3::new(0.3, 1.0, 0.1), DVec3::Y),
            (DVec3::new(1.0, -2.0, 0.4), DVec3::Y),
        ] {
            for fov in [0.01, 60.0, 179.0] {
                seen.push(check_camera(
                    &methods,
                    Camera {
                        eye,
                        forward,
                        up,
                        fov_y_deg: fov,
                        far: 1e9,
                        near: 1e-6,
                        ..Camera::default()
                    },
                ));
            }
        }
    }
    assert_seen(&seen, 0.5);
    // Most of these see the ground or a building (an eye inside a box's
    // corner may see nothing but the inside of walls the near plane clips).
    let mut seen = Vec::new();
    // On a prism's face and corner, inside a building's box, on its roof.
    for o in s
        .objects()
        .iter()
        .filter(|o| o.name.starts_with("building"))
        .step_by(37)
    {
        let (lo, hi) = world_box(&s, o.id);
        let prism = &h.prisms().of(o.id)[0];
        let p = prism.footprint[0] + DVec2::new(s.origin.x, s.origin.z);
        let q = prism.footprint[1] + DVec2::new(s.origin.x, s.origin.z);
        let top = prism.top + s.origin.y;
        let mid = (p + q) * 0.5;
        for eye in [
            DVec3::new(mid.x, 1.7, mid.y),
            DVec3::new(p.x, top, p.y),
            DVec3::new(mid.x, top, mid.y),
            (lo + hi) * 0.5,
            DVec3::new((lo.x + hi.x) * 0.5, hi.y, (lo.z + hi.z) * 0.5),
            lo,
        ] {
            let yaw: f64 = r.random_range(0.0..std::f64::consts::TAU);
            seen.push(check_camera(
                &methods,
                Camera {
                    eye,
                    forward: DVec3::new(yaw.cos(), r.random_range(-0.3..0.3), yaw.sin()),
                    fov_y_deg: r.random_range(20.0..120.0),
                    aspect: [0.01, 1.6, 100.0][r.random_range(0..3)],
                    ..Camera::default()
                },
            ));
        }
    }
    assert_seen(&seen, 0.9);
    // Below the ground: frustum culling only.
    let below = Camera {
        eye: street - DVec3::Y * 10.0,
        forward: DVec3::new(1.0, 0.5, 0.0),
        ..Camera::default()
    };
    assert_eq!(
        answer(&methods, "horizon", below),
        answer(&methods, "frustum", below)
    );
}

#[test]
fn tall_thin_towers_hide_and_are_seen_correctly() {
    // Towers 1 m wide and 200 m tall in a row, and small boxes behind them.
    let mut b = pvsd::scene::SceneBuilder::new("towers");
    let quad = |y: f64| {
        [
            [
                DVec3::new(-50.0, y, -50.0),
                DVec3::new(-50.0, y, 50.0),
                DVec3::new(50.0, y, 50.0),
            ],
            [
                DVec3::new(-50.0, y, -50.0),
                DVec3::new(50.0, y, 50.0),
                DVec3::new(50.0, y, -50.0),
            ],
        ]
    };
    b.begin_object("ground", None);
    b.add_triangles(quad(0.0), false);
    for i in 0..30 {
        let x = -30.0 + 2.0 * i as f32;
        b.begin_object(format!("tower_{i}"), None);
        b.add_triangles(
            cuboid(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 200.0, 1.0)),
            false,
        );
        b.begin_object(format!("box_{i}"), None);
        b.add_triangles(
            cuboid(Vec3::new(x, 0.0, 10.0), Vec3::new(x + 0.5, 0.5, 10.5)),
            false,
        );
    }
    let methods = common::prepare(Arc::new(b.finish()));
    let mut r = rng(8);
    let mut seen = Vec::new();
    for _ in 0..40 {
        let eye = DVec3::new(
            r.random_range(-40.0..40.0),
            r.random_range(0.0..3.0),
            r.random_range(-30.0..-2.0),
        );
        let target = DVec3::new(
            r.random_range(-30.0..30.0),
            r.random_range(0.0..100.0),
            10.0,
        );
        seen.push(check_camera(
            &methods,
            Camera {
                eye,
                forward: target - eye,
                ..Camera::default()
            },
        ));
    }
    // Every camera looks at the towers.
    assert_seen(&seen, 1.0);
    // Seen through the gaps, the boxes behind are not all culled.
    let eye = DVec3::new(0.25, 0.25, -20.0);
    let got = answer(
        &methods,
        "horizon",
        Camera {
            eye,
            forward: DVec3::Z,
            ..Camera::default()
        },
    );
    assert!(got.iter().any(|&id| {
        methods.scene().objects()[id as usize]
            .name
            .starts_with("box")
    }));
}

/// Whether `p` is enclosed by the object: every one of several random
/// rays going up from it hits one of its triangles (a point outside a
/// building, or in a gap of its shell, has rays that escape). Independent
/// of how prisms are proven; rays going down would leave through the open
/// bottom that stands on the ground. Triangles are grown by 1e-4 of their
/// size: generated facades meet their roofs with one-`f32`-ulp cracks
/// (rounding), which rays from a point a millimetre inside can slip through.
fn inside(s: &Scene, id: u32, p: DVec3, r: &mut rand_chacha::ChaCha8Rng) -> bool {
    let o = &s.objects()[id as usize];
    (0..8).all(|_| {
        let dir = DVec3::new(
            r.random_range(-1.0..1.0),
            r.random_range(0.05..1.0),
            r.random_range(-1.0..1.0),
        );
        s.object_triangles(o).iter().any(|t| {
            let [a, b, c] = t.map(|v| v.as_dvec3());
            let (e1, e2) = (b - a, c - a);
            let q = dir.cross(e2);
            let det = e1.dot(q);
            if det.abs() < 1e-12 {
                return false;
            }
            let sv = p - a;
            let u = sv.dot(q) / det;
            let k = sv.cross(e1);
            let v = dir.dot(k) / det;
            let t = e2.dot(k) / det;
            const GROW: f64 = 1e-4;
            u >= -GROW && v >= -GROW && u + v <= 1.0 + GROW && t > 0.0
        })
    })
}

#[test]
fn prisms_lie_inside_their_buildings() {
    let s = city_scene(300, 4, [0.0; 3]);
    let h = HorizonCulling::new(s.clone()).unwrap();
    let ground = h.prisms().ground();
    let mut r = rng(21);
    let mut checked = 0;
    for o in s
        .objects()
        .iter()
        .filter(|o| o.name.starts_with("building"))
    {
        let prisms = h.prisms().of(o.id);
        assert!(!prisms.is_empty(), "{} has no prism", o.name);
        for p in prisms {
            for _ in 0..20 {
                // A random point of the prism: a convex mix of its corners.
                let w: Vec<f64> = p
                    .footprint
                    .iter()
                    .map(|_| r.random_range(0.0..1.0))
                    .collect();
                let total: f64 = w.iter().sum();
                let xz: DVec2 = p
                    .footprint
                    .iter()
                    .zip(&w)
                    .map(|(v, w)| *v * *w)
                    .sum::<DVec2>()
                    / total;
                let y = r.random_range(ground + 1e-3..p.top);
                assert!(
                    inside(&s, o.id, DVec3::new(xz.x, y, xz.y), &mut r),
                    "{}: {xz} {y}",
                    o.name
                );
                checked += 1;
            }
            // Corners of the top, just inside.
            for v in &p.footprint {
                assert!(
                    inside(&s, o.id, DVec3::new(v.x, p.top, v.y), &mut r),
                    "{} corner {v}",
                    o.name
                );
            }
        }
    }
    assert!(checked > 5000);
}

#[test]
fn lod_areas_bound_the_pixels_and_min_area_is_aggressive() {
    let methods = common::prepare(city_scene(1000, 3, [0.0; 3]));
    let s = methods.scene().clone();
    let params = pvsd::eval::WalkParams {
        kind: WalkKind::Street,
        frames: 12,
        viewport: [320, 200],
        ..Default::default()
    };
    let spec: MethodSpec = "horizon:areas=true".parse().unwrap();
    let mut checked = 0;
    for cam in pvsd::eval::walk(&s, &params).unwrap() {
        let view = View::new(cam, &s).unwrap();
        let mut out = VisibleSet::new();
        methods.cull_once(&spec, &view, &mut out).unwrap();
        let areas = out.areas().expect("areas were asked for");
        assert_eq!(areas.len(), out.len());
        let truth = Truth::render(&s, &cam).unwrap();
        for (id, area) in out.ids().iter().zip(&areas) {
            let px = truth.pixels(*id) as f64;
            assert!(
                *area >= px,
                "{}: bound {area} < {px} pixels",
                s.objects()[*id as usize].name
            );
            assert!(*area <= 320.0 * 200.0);
            checked += (px > 0.0) as u32;
        }
    }
    assert!(checked > 50);
    let spec: MethodSpec = "horizon:min_area=50".parse().unwrap();
    let (method, cache) = methods.prepare_client(&spec).unwrap();
    assert!(!cache.is_conservative());
    assert_eq!(method.name(), "horizon");
}

#[test]
fn listed_only_for_height_fields_with_the_reason() {
    let city = common::prepare(city_scene(50, 1, [0.0; 3]));
    assert!(city.names().contains(&"horizon"));
    assert!(city.get("horizon").is_ok());
    // The office's ground-floor walls are solids standing on the lowest
    // level, so it gets prisms; whatever a scene lists must be conservative.
    let office = office_scene(1, [0.0; 3]);
    let reason = |m: &SceneMethods| {
        m.unsupported()
            .iter()
            .find(|u| u.method == "horizon")
            .map(|u| u.reason.clone())
    };
    if common::prepare(office.clone()).names().contains(&"horizon") {
        assert_conservative(&office, "horizon", &[WalkKind::Random], 20);
    }
    // Real scenes: whatever is listed must be conservative; what is not says why.
    for name in ["Sponza", "2CylinderEngine", "ReciprocatingSaw"] {
        let scene = shared_scene(name);
        let m = common::prepare(scene.clone());
        if m.names().contains(&"horizon") {
            assert_conservative(&scene, "horizon", &[WalkKind::Orbit], 12);
        } else {
            assert!(reason(&m).is_some(), "{name}");
        }
    }
}

#[test]
fn options_are_checked() {
    let m = common::prepare(city_scene(20, 1, [0.0; 3]));
    for (spec, want) in [
        ("horizon:k=3", "unknown option 'k'"),
        ("horizon:min_area=-1", "min_area"),
        ("horizon:columns=3", "columns"),
        ("horizon:areas=maybe", "areas"),
    ] {
        let e = m
            .prepare_client(&spec.parse().unwrap())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains(want), "{spec}: {e}");
    }
}

#[test]
fn a_mask_hides_below_its_top_and_not_above() {
    // A 10 m block 20–30 m ahead; behind it at 60 m, a 17 m and a 30 m pole.
    // Seen from 1.7 m, the block's near roof edge hides up to 26.6 m there;
    // its mask (top over the far depth) claims up to 18.3 m.
    let mut b = pvsd::scene::SceneBuilder::new("block");
    b.begin_object("ground", None);
    b.add_triangles(
        cuboid(
            Vec3::new(-100.0, -1.0, -100.0),
            Vec3::new(100.0, 0.0, 100.0),
        )[8..10]
            .to_vec(),
        false,
    );
    b.begin_object("block", None);
    b.add_triangles(
        cuboid(Vec3::new(-5.0, 0.0, 20.0), Vec3::new(5.0, 10.0, 30.0)),
        false,
    );
    b.begin_object("low_pole", None);
    b.add_triangles(
        cuboid(Vec3::new(-1.5, 0.0, 60.0), Vec3::new(-0.5, 17.0, 61.0)),
        false,
    );
    b.begin_object("high_pole", None);
    b.add_triangles(
        cuboid(Vec3::new(0.5, 0.0, 60.0), Vec3::new(1.5, 30.0, 61.0)),
        false,
    );
    let methods = common::prepare(Arc::new(b.finish()));
    let cam = Camera {
        eye: DVec3::new(0.0, 1.7, 0.0),
        forward: DVec3::Z,
        ..Camera::default()
    };
    assert!(check_camera(&methods, cam) > 0);
    let got = answer(&methods, "horizon", cam);
    let name = |id: &u32| methods.scene().objects()[*id as usize].name.clone();
    let names: Vec<String> = got.iter().map(name).collect();
    assert!(names.contains(&"high_pole".to_string()), "{names:?}");
    assert!(!names.contains(&"low_pole".to_string()), "{names:?}");
}
