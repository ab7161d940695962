//! The object-space occlusion methods: `occlusion_tree` (fse, fme, fmc) and
//! `supporting_planes`. Zero misses at DESIGN's extremes (every registry
//! method, through the shared camera check; walks are in the table of
//! tests/conservative.rs); the occlusion tree against a brute-force
//! ray-casting reference on random occluder sets; the modified tree never
//! finer than the exact one.

mod common;

use common::{assert_seen, check_camera, office_scene, rng};
use glam::{DVec3, Vec3};
use pvsd::cull::occlusion::Visibility;
use pvsd::cull::occlusion_tree::{Entry, LeafTest, OcclusionTree};
use pvsd::cull::{MethodSpec, Registry};
use pvsd::geom::{Aabb, Camera, ConvexPolygon};
use rand::Rng;

#[test]
fn methods_are_listed_only_where_there_are_occluders() {
    let office = common::prepare(office_scene(1, [0.0; 3]));
    for m in ["frustum", "occlusion_tree", "supporting_planes"] {
        assert!(office.names().contains(&m), "{:?}", office.names());
    }
    // A scene of points and segments has no polygon to hide anything.
    let mut b = pvsd::scene::SceneBuilder::new("dust");
    b.begin_object("speck", None);
    b.add_triangles([[DVec3::ZERO, DVec3::X, DVec3::X * 2.0]], false);
    let dust = common::prepare(std::sync::Arc::new(b.finish()));
    // gpu needs no occluders, only a device.
    let names: Vec<&str> = dust.names().into_iter().filter(|&n| n != "gpu").collect();
    assert_eq!(names, ["frustum"]);
    let e = dust.get("occlusion_tree").err().unwrap().to_string();
    assert!(e.contains("not supported by scene 'dust'"), "{e}");
}

#[test]
fn options_are_checked_by_name() {
    let office = common::prepare(office_scene(1, [0.0; 3]));
    for (spec, want) in [
        (
            "occlusion_tree:variant=fxx",
            "option 'variant' of method 'occlusion_tree' must be fme, fmc or fse",
        ),
        ("occlusion_tree:k=0", "option 'k'"),
        ("occlusion_tree:lambda=-1", "option 'lambda'"),
        (
            "supporting_planes:variant=fme",
            "unknown option 'variant' for method 'supporting_planes'",
        ),
    ] {
        let e = office
            .prepare_client(&spec.parse::<MethodSpec>().unwrap())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains(want), "{spec}: {e}");
    }
}

#[test]
fn extremes_eye_on_occluder_planes_edge_on_and_inside_walls() {
    let methods = common::prepare(office_scene(1, [0.0; 3]));
    let registry = Registry::standard();
    let s = methods.scene().clone();
    let mut r = rng(11);
    // Objects the truth saw, per camera: a camera that sees nothing checks nothing.
    let mut seen = Vec::new();
    for o in s
        .objects()
        .iter()
        .filter(|o| o.name.starts_with("wall_0"))
        .step_by(7)
    {
        let (lo, hi) = (
            o.bounds.min.as_dvec3() + s.origin,
            o.bounds.max.as_dvec3() + s.origin,
        );
        let mid = (lo + hi) * 0.5;
        // On the wall's face plane, looking along it (the wall edge-on) and across it.
        for eye in [
            DVec3::new(lo.x, mid.y, mid.z),
            DVec3::new(mid.x, mid.y, hi.z),
            hi,
            mid,
        ] {
            for forward in [
                DVec3::X,
                DVec3::Z,
                DVec3::NEG_X,
                DVec3::new(0.3, -0.2, -1.0),
            ] {
                seen.push(check_camera(
                    &methods,
                    &registry,
                    Camera {
                        eye,
                        forward,
                        near: r.random_range(1e-6..0.1),
                        ..Camera::default()
                    },
                ));
            }
        }
    }
    // Straight up and down, fov and aspect extremes. Regression: at fov 179°
    // and aspect 100 a door pier partly nearer than the near plane hid a wall
    // that the image shows through the clipped-away part; occluders are now
    // clipped to the near plane before they hide anything.
    // A room of the office (generated at no offset: world = local).
    let eye = DVec3::new(7.3, 1.7, 5.1);
    for cam in [
        Camera {
            eye,
            forward: DVec3::Y,
            up: DVec3::Z,
            ..Camera::default()
        },
        Camera {
            eye,
            forward: DVec3::NEG_Y,
            up: DVec3::X,
            ..Camera::default()
        },
        Camera {
            eye,
            forward: DVec3::X,
            fov_y_deg: 179.0,
            aspect: 100.0,
            ..Camera::default()
        },
        Camera {
            eye,
            forward: DVec3::X,
            fov_y_deg: 0.01,
            aspect: 0.01,
            far: 1e9,
            ..Camera::default()
        },
    ] {
        seen.push(check_camera(&methods, &registry, cam));
    }
    // An eye inside a wall, looking along it, may see nothing at all.
    assert_seen(&seen, 0.95);
}

/// Whether the segment eye → p passes through a polygon before reaching p.
fn blocked(eye: DVec3, p: DVec3, polys: &[ConvexPolygon]) -> bool {
    polys.iter().any(|poly| {
        let Some(plane) = poly.plane() else {
            return false;
        };
        let (de, dp) = (plane.signed_distance(eye), plane.signed_distance(p));
        if de.abs() < 1e-12 || (de > 0.0) == (dp > 0.0) || dp.abs() < 1e-9 {
            return false;
        }
        let h = eye + (p - eye) * (de / (de - dp));
        let v = &poly.vertices;
        let n = plane.normal;
        (0..v.len()).all(|i| (v[(i + 1) % v.len()] - v[i]).cross(h - v[i]).dot(n) > 1e-9)
    })
}

fn random_quad(r: &mut rand_chacha::ChaCha8Rng) -> ConvexPolygon {
    let c = DVec3::new(
        r.random_range(-6.0..6.0),
        r.random_range(-6.0..6.0),
        r.random_range(-20.0..-3.0),
    );
    let (u, v) = (common::random_unit(r), common::random_unit(r));
    let w = u.cross(v).normalize();
    let u = u.normalize() * r.random_range(0.5..4.0);
    let v = w.cross(u).normalize() * r.random_range(0.5..4.0);
    let mut q = vec![c - u - v, c + u - v, c + u + v, c - u + v];
    if r.random_bool(0.3) {
        // Coplanar coincident twins and shared edges happen in real scenes.
        q.reverse();
    }
    ConvexPolygon::new(q)
}

fn random_box(r: &mut rand_chacha::ChaCha8Rng) -> Aabb {
    let c = Vec3::new(
        r.random_range(-8.0..8.0),
        r.random_range(-8.0..8.0),
        r.random_range(-30.0..-2.0),
    );
    let h = Vec3::new(
        r.random_range(0.05..2.0),
        r.random_range(0.05..2.0),
        r.random_range(0.05..2.0),
    );
    Aabb::new(c - h, c + h)
}

/// Points on the box's faces and inside it.
fn samples(b: &Aabb, r: &mut rand_chacha::ChaCha8Rng, n: usize) -> Vec<DVec3> {
    (0..n)
        .map(|i| {
            let mut t = DVec3::new(r.random(), r.random(), r.random());
            if i % 2 == 0 {
                t[i / 2 % 3] = if r.random_bool(0.5) { 0.0 } else { 1.0 };
            }
            b.min.as_dvec3() + (b.max - b.min).as_dvec3() * t
        })
        .collect()
}

#[test]
fn trees_agree_with_brute_force_ray_casting() {
    let mut r = rng(5);
    let eye = DVec3::ZERO;
    let (mut invisible, mut full) = (0, 0);
    // MOBSP's invisible answers, per in-leaf test and clipping: a tree that
    // never answered Invisible would pass every assertion below.
    let mut mobsp_invisible = [0usize; 4];
    for round in 0..300 {
        let mut polys: Vec<ConvexPolygon> = (0..r.random_range(1..10))
            .map(|_| random_quad(&mut r))
            .collect();
        if round % 5 == 0 {
            polys.push(polys[0].clone()); // a coincident twin
        }
        let exact = OcclusionTree::build(eye, &polys, false, 1e-9);
        let modified = OcclusionTree::build(eye, &polys, true, 1e-9);
        for _ in 0..20 {
            let b = random_box(&mut r);
            let pts = samples(&b, &mut r, 200);
            let hidden = pts.iter().filter(|&&p| blocked(eye, p, &polys)).count();
            let obsp = exact.box_visibility_exact(&b);
            // The exact test: invisible only if every sample is hidden; fully
            // visible only if no sample on a face towards the eye is hidden.
            if obsp == Visibility::Invisible {
                invisible += 1;
                assert_eq!(
                    hidden,
                    pts.len(),
                    "OBSP called a visible box invisible: {b:?}"
                );
            }
            if obsp == Visibility::Full {
                full += 1;
            }
            let cases = [LeafTest::Exact, LeafTest::Conservative]
                .into_iter()
                .flat_map(|test| [(test, false), (test, true)]);
            for (t, (test, clip)) in cases.enumerate() {
                let mobsp = modified.region_visibility(&b, test, clip);
                if !clip {
                    // Clipping the region at crossed planes only finds more hidden.
                    let clipped = modified.region_visibility(&b, test, true);
                    if mobsp == Visibility::Invisible {
                        assert_eq!(clipped, Visibility::Invisible, "{b:?}");
                    }
                }
                if mobsp == Visibility::Invisible {
                    mobsp_invisible[t] += 1;
                    assert_eq!(
                        hidden,
                        pts.len(),
                        "MOBSP ({test:?}, clip {clip}) called a visible box invisible: {b:?}"
                    );
                    // Never finer than the exact tree.
                    assert_eq!(
                        obsp,
                        Visibility::Invisible,
                        "MOBSP finer than OBSP for {b:?}"
                    );
                }
            }
        }
    }
    assert!(
        invisible > 100 && full > 100,
        "the random cases exercise both answers: {invisible} invisible, {full} full"
    );
    assert!(
        mobsp_invisible.iter().all(|&n| n > 50),
        "MOBSP hides boxes with both in-leaf tests: {mobsp_invisible:?}"
    );
    // Fig. 8: boxes behind two occluders, sticking out of each one's shadow
    // into the other's, are found hidden only with the region clipped.
    assert!(
        mobsp_invisible[1] > mobsp_invisible[0] && mobsp_invisible[3] > mobsp_invisible[2],
        "clipping finds more hidden: {mobsp_invisible:?}"
    );
}

#[test]
fn a_box_inside_another_searched_from_its_entry_answers_as_from_the_root() {
    let mut r = rng(11);
    let eye = DVec3::ZERO;
    let mut below_root = 0;
    for _ in 0..200 {
        let polys: Vec<ConvexPolygon> = (0..r.random_range(1..10))
            .map(|_| random_quad(&mut r))
            .collect();
        let tree = OcclusionTree::build(eye, &polys, true, 1e-9);
        for _ in 0..20 {
            let b = random_box(&mut r);
            // A box inside `b` (sharing a face with it now and then).
            let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
            let mut t = [DVec3::ZERO; 2].map(|_| DVec3::new(r.random(), r.random(), r.random()));
            if r.random_bool(0.3) {
                t[0].x = 0.0;
            }
            let (p, q) = (lo + (hi - lo) * t[0], lo + (hi - lo) * t[1]);
            let inner = Aabb::new(p.min(q).as_vec3().max(b.min), p.max(q).as_vec3().min(b.max));
            for test in [LeafTest::Exact, LeafTest::Conservative] {
                for clip in [false, true] {
                    let (whole, entry) = tree.region_visibility_from(&b, test, clip, Entry::ROOT);
                    assert_eq!(whole, tree.region_visibility(&b, test, clip));
                    below_root += usize::from(entry != Entry::ROOT);
                    assert_eq!(
                        tree.region_visibility_from(&inner, test, clip, entry).0,
                        tree.region_visibility(&inner, test, clip),
                        "{inner:?} inside {b:?} ({test:?}, clip {clip})"
                    );
                }
            }
        }
    }
    assert!(below_root > 1000, "entries below the root: {below_root}");
}

#[test]
fn degenerate_occluders_hide_nothing() {
    let eye = DVec3::ZERO;
    let behind = Aabb::new(Vec3::new(-0.1, -0.1, -20.0), Vec3::new(0.1, 0.1, -19.0));
    // Edge-on (the eye in its plane), zero area, and the eye in line with an edge.
    let edge_on = ConvexPolygon::new(vec![
        DVec3::new(-5.0, 0.0, -5.0),
        DVec3::new(5.0, 0.0, -5.0),
        DVec3::new(5.0, 0.0, -30.0),
        DVec3::new(-5.0, 0.0, -30.0),
    ]);
    let flat = ConvexPolygon::new(vec![
        DVec3::new(-5.0, 0.0, -10.0),
        DVec3::new(0.0, 0.0, -10.0),
        DVec3::new(5.0, 0.0, -10.0),
    ]);
    for polys in [vec![edge_on], vec![flat]] {
        for modified in [false, true] {
            let t = OcclusionTree::build(eye, &polys, modified, 1e-9);
            assert_ne!(t.box_visibility_exact(&behind), Visibility::Invisible);
            assert_ne!(
                t.region_visibility(&behind, LeafTest::Exact, false),
                Visibility::Invisible
            );
        }
    }
    // A real wall does hide it, and a box straddling the wall's plane is not hidden.
    let wall = ConvexPolygon::new(vec![
        DVec3::new(-5.0, -5.0, -10.0),
        DVec3::new(5.0, -5.0, -10.0),
        DVec3::new(5.0, 5.0, -10.0),
        DVec3::new(-5.0, 5.0, -10.0),
    ]);
    let t = OcclusionTree::build(eye, [&wall], true, 1e-9);
    assert_eq!(
        t.region_visibility(&behind, LeafTest::Exact, false),
        Visibility::Invisible
    );
    let straddling = Aabb::new(Vec3::new(-0.1, -0.1, -11.0), Vec3::new(0.1, 0.1, -9.0));
    assert_eq!(
        t.region_visibility(&straddling, LeafTest::Exact, true),
        Visibility::Partial
    );
    // The eye exactly on the wall's plane: no shadow at all.
    let t = OcclusionTree::build(DVec3::new(0.0, 0.0, -10.0), [&wall], true, 1e-9);
    assert_eq!(t.node_count(), 1);
}

/// A camera that stands still (three frames of each view) lets a session
/// keep its occlusion tree when it picks the same occluders again: the
/// answers stay conservative.
#[test]
fn a_camera_standing_still_keeps_its_answers_conservative() {
    use pvsd::eval::{Contender, EvalParams, WalkKind, WalkParams};
    let office = common::prepare(office_scene(3, [0.0; 3]));
    let walk = WalkParams {
        kind: WalkKind::Random,
        frames: 12,
        viewport: common::CHECK_VIEWPORT,
        ..WalkParams::default()
    };
    let cameras: Vec<Camera> = pvsd::eval::walk(office.scene(), &walk)
        .unwrap()
        .into_iter()
        .flat_map(|c| [c, c, c])
        .collect();
    let params = EvalParams {
        walk,
        ..EvalParams::default()
    };
    let specs = [
        "occlusion_tree",
        "occlusion_tree:variant=fmc",
        "supporting_planes",
    ];
    let contenders = specs
        .iter()
        .map(|s| Contender::from_spec(&office, &s.parse().unwrap()).unwrap())
        .collect();
    let report = pvsd::eval::run(office.scene(), contenders, &cameras, &params, |_| {}).unwrap();
    for m in &report.methods {
        assert!(m.mean_truth > 0.0);
        assert_eq!(m.misses, 0, "{}: {:?}", m.method, m.miss_examples);
    }
}
