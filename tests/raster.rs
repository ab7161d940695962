//! `raster`'s known answers — a box behind a wall, seen through a one-pixel
//! slit, behind a see-through wall, a wall edge-on, an eye on a wall's
//! plane, boxes and walls across the near plane — and its SIMD and scalar
//! paths answering alike on random scenes. Its walks over generated and
//! real scenes are in the conservativeness table (tests/conservative.rs),
//! its extremes in tests/ddo.rs and tests/extremes (every method is checked
//! there).

mod common;

use std::sync::Arc;

use glam::{DVec3, Vec3};
use proptest::prelude::*;
use pvsd::cull::{MethodSpec, SceneMethods, View, VisibleSet};
use pvsd::geom::Camera;
use pvsd::scene::{Scene, SceneBuilder};
use pvsd::truth::Truth;

const VIEWPORT: [u32; 2] = [512, 320];

/// A closed box's triangles.
fn solid(min: Vec3, max: Vec3) -> Vec<[DVec3; 3]> {
    let (a, b) = (min.as_dvec3(), max.as_dvec3());
    let c = |i: usize| {
        DVec3::new(
            if i & 1 == 0 { a.x } else { b.x },
            if i & 2 == 0 { a.y } else { b.y },
            if i & 4 == 0 { a.z } else { b.z },
        )
    };
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    quads
        .iter()
        .flat_map(|q| [[c(q[0]), c(q[1]), c(q[2])], [c(q[0]), c(q[2]), c(q[3])]])
        .collect()
}

/// The rectangle `x0..x1 × y0..y1` in the plane `z`.
fn rect(x0: f64, x1: f64, y0: f64, y1: f64, z: f64) -> Vec<[DVec3; 3]> {
    let p = |x, y| DVec3::new(x, y, z);
    vec![
        [p(x0, y0), p(x1, y0), p(x1, y1)],
        [p(x0, y0), p(x1, y1), p(x0, y1)],
    ]
}

/// A 10 × 10 wall in the plane z = 0 (with a vertical slit `x0..x1` left
/// open when asked), object 0, and a unit box 2–3 units behind it, object 1.
fn wall_and_box(slit: Option<(f64, f64)>, see_through: bool) -> Arc<Scene> {
    wall_and_box_at(slit, see_through, DVec3::ZERO)
}

/// [`wall_and_box`] moved by `offset`.
fn wall_and_box_at(slit: Option<(f64, f64)>, see_through: bool, offset: DVec3) -> Arc<Scene> {
    let shift = |tris: Vec<[DVec3; 3]>| -> Vec<[DVec3; 3]> {
        tris.into_iter().map(|t| t.map(|v| v + offset)).collect()
    };
    let mut b = SceneBuilder::new("wall");
    b.begin_object("wall", None);
    match slit {
        None => b.add_triangles(shift(rect(-5.0, 5.0, -5.0, 5.0, 0.0)), see_through),
        Some((x0, x1)) => {
            b.add_triangles(shift(rect(-5.0, x0, -5.0, 5.0, 0.0)), see_through);
            b.add_triangles(shift(rect(x1, 5.0, -5.0, 5.0, 0.0)), see_through);
        }
    }
    b.begin_object("box", None);
    b.add_triangles(
        shift(solid(
            Vec3::new(-0.5, -0.5, -3.0),
            Vec3::new(0.5, 0.5, -2.0),
        )),
        false,
    );
    Arc::new(b.finish())
}

fn camera(eye: DVec3, forward: DVec3) -> Camera {
    Camera {
        eye,
        forward,
        viewport: VIEWPORT,
        ..Camera::default()
    }
}

/// `raster`'s answer with `options`.
fn raster(methods: &SceneMethods, cam: Camera, options: &str) -> Vec<u32> {
    let spec: MethodSpec = if options.is_empty() {
        "raster".parse().unwrap()
    } else {
        format!("raster:{options}").parse().unwrap()
    };
    let view = View::new(cam, methods.scene()).unwrap();
    let mut out = VisibleSet::new();
    methods.cull_once(&spec, &view, &mut out).unwrap();
    out.ids().to_vec()
}

const OPTIONS: [&str; 4] = ["", "cell=1", "simd=false", "splits=0:min_size=0"];

/// Every option set's answer holds what truth sees, and is `expected`.
fn check(scene: &Arc<Scene>, cam: Camera, expected: &[u32]) {
    let methods = SceneMethods::prepare(scene.clone());
    let truth = Truth::render(scene, &cam).unwrap().visible();
    for options in OPTIONS {
        let got = raster(&methods, cam, options);
        for v in &truth {
            assert!(got.contains(v), "{v} dropped with {options:?} from {cam:?}");
        }
        assert_eq!(got, expected, "with {options:?} from {cam:?}");
    }
}

#[test]
fn a_box_behind_a_wall_is_culled() {
    let scene = wall_and_box(None, false);
    check(&scene, camera(DVec3::new(0.3, 0.2, 10.0), -DVec3::Z), &[0]);
    // From behind, the box stands in front of the wall.
    check(
        &scene,
        camera(DVec3::new(0.3, 0.2, -10.0), DVec3::Z),
        &[0, 1],
    );
}

#[test]
fn a_box_seen_through_a_one_pixel_slit_is_kept() {
    // Pixel column 256's centres cross the wall's plane, 10 units away,
    // at x = (256.5 / 256 − 1) · tan 30° · 1.6 · 10; columns are 0.036
    // units apart there. The slit is 0.8 of a column wide around it:
    // exactly one column of pixel centres sees through.
    let half_width = (30f64.to_radians().tan() * 1.6) * 10.0;
    let x = (256.5 / 256.0 - 1.0) * half_width;
    let column = 2.0 * half_width / 512.0;
    let scene = wall_and_box(Some((x - 0.4 * column, x + 0.4 * column)), false);
    let cam = camera(DVec3::new(0.0, 0.0, 10.0), -DVec3::Z);
    let truth = Truth::render(&scene, &cam).unwrap().visible();
    assert_eq!(truth, vec![0, 1], "truth sees the box through the slit");
    check(&scene, cam, &[0, 1]);
    // Moved off the column's centres, the slit shows nothing, and at the
    // viewport's own resolution the box is culled. (A cell of 2×2 pixels
    // straddles the slit, and neither half of the wall covers all of its
    // centres: there the box stays.)
    let shut = wall_and_box(Some((x + 0.1 * column, x + 0.45 * column)), false);
    assert_eq!(Truth::render(&shut, &cam).unwrap().visible(), vec![0]);
    let methods = SceneMethods::prepare(shut);
    assert_eq!(raster(&methods, cam, "cell=1"), vec![0]);
    assert_eq!(raster(&methods, cam, "cell=2"), vec![0, 1]);
}

#[test]
fn a_sliver_narrower_than_min_width_is_not_drawn() {
    // A post 0.4 wide and 10 tall, 10 units away: 11 pixels (5.5 cells)
    // wide on screen, and a box a quarter as wide just behind it. Its
    // width is judged at the nearest depth of a sphere around it, 5 units
    // away: 22 pixels, 11 cells.
    let mut b = SceneBuilder::new("post");
    b.begin_object("post", None);
    b.add_triangles(rect(-0.2, 0.2, -5.0, 5.0, 0.0), false);
    b.begin_object("box", None);
    b.add_triangles(
        solid(Vec3::new(-0.05, -0.5, -1.0), Vec3::new(0.05, 0.5, -0.5)),
        false,
    );
    let scene = Arc::new(b.finish());
    let cam = camera(DVec3::new(0.0, 0.2, 10.0), -DVec3::Z);
    assert_eq!(Truth::render(&scene, &cam).unwrap().visible(), vec![0]);
    let methods = SceneMethods::prepare(scene);
    // Drawn at the default (one cell), with no bound and up to 11 cells;
    // not drawn when asked for 12, so the box behind it stays.
    assert_eq!(raster(&methods, cam, ""), vec![0]);
    assert_eq!(raster(&methods, cam, "min_width=0"), vec![0]);
    assert_eq!(raster(&methods, cam, "min_width=10"), vec![0]);
    assert_eq!(raster(&methods, cam, "min_width=12"), vec![0, 1]);
}

#[test]
fn a_see_through_wall_hides_nothing() {
    check(
        &wall_and_box(None, true),
        camera(DVec3::new(0.0, 0.0, 10.0), -DVec3::Z),
        &[0, 1],
    );
}

#[test]
fn a_wall_edge_on_and_an_eye_on_its_plane_hide_nothing() {
    let scene = wall_and_box(None, false);
    // Looking along the wall's plane from outside it, at the box: the
    // wall covers no pixel centre (truth does not see it either).
    let eye = DVec3::new(20.0, 0.0, 0.0);
    check(&scene, camera(eye, DVec3::new(0.0, 0.0, -2.5) - eye), &[1]);
    // The eye in the wall's plane, inside its outline, looking at the box:
    // the wall is seen edge-on too.
    let eye = DVec3::new(0.1, 0.2, 0.0);
    check(&scene, camera(eye, DVec3::new(0.0, 0.0, -2.5) - eye), &[1]);
}

#[test]
fn nothing_nearer_than_the_near_plane_hides_and_a_box_across_it_stays() {
    let mut b = SceneBuilder::new("near");
    b.begin_object("wall", None);
    b.add_triangles(rect(-5.0, 5.0, -5.0, 5.0, 9.97), false);
    b.begin_object("box", None);
    b.add_triangles(
        solid(Vec3::new(-0.5, -0.5, 9.5), Vec3::new(0.5, 0.5, 9.95)),
        false,
    );
    b.begin_object("far", None);
    b.add_triangles(
        solid(Vec3::new(-0.5, -0.5, -3.0), Vec3::new(0.5, 0.5, -2.0)),
        false,
    );
    let scene = Arc::new(b.finish());
    // The wall lies 0.03 from the eye, inside the near distance (0.1): not
    // drawn by truth, it hides nothing; the box reaches across the near plane.
    let cam = Camera {
        near: 0.1,
        ..camera(DVec3::new(0.0, 0.0, 10.0), -DVec3::Z)
    };
    check(&scene, cam, &[1]);
}

/// DESIGN's extremes on the wall and box: moved 1e6 and 1e7 away, eyes
/// on the box's corner and inside it, looking straight down, aspect 0.01
/// and 100, near 1e-6 and far 1e9, fov 0.01° and 179°. Every option set
/// keeps what truth sees, and the wall still hides the box from in front.
#[test]
fn extremes_of_the_wall_and_box() {
    for offset in [
        DVec3::ZERO,
        DVec3::new(1e6, -1e6, 1e6),
        DVec3::new(1e7, 1e7, -1e7),
    ] {
        let scene = wall_and_box_at(None, false, offset);
        let methods = SceneMethods::prepare(scene.clone());
        let at = |x: f64, y: f64, z: f64| DVec3::new(x, y, z) + offset;
        let box_centre = at(0.0, 0.0, -2.5);
        let mut cams = vec![
            camera(at(0.5, 0.5, -2.0), at(0.0, 0.0, 10.0) - at(0.5, 0.5, -2.0)),
            camera(at(0.1, 0.2, -2.4), DVec3::Z),
            Camera {
                up: DVec3::Z,
                ..camera(at(0.0, 20.0, -2.5), -DVec3::Y)
            },
            Camera {
                near: 1e-6,
                far: 1e9,
                ..camera(at(0.0, 0.0, 10.0), -DVec3::Z)
            },
        ];
        for (aspect, fov) in [(0.01, 60.0), (100.0, 60.0), (1.6, 0.01), (1.6, 179.0)] {
            cams.push(Camera {
                aspect,
                fov_y_deg: fov,
                ..camera(at(3.0, 1.0, -12.0), box_centre - at(3.0, 1.0, -12.0))
            });
        }
        for cam in cams {
            let truth = Truth::render(&scene, &cam).unwrap().visible();
            for options in OPTIONS {
                let got = raster(&methods, cam, options);
                for v in &truth {
                    assert!(got.contains(v), "{v} dropped with {options:?} from {cam:?}");
                }
            }
        }
        let front = camera(at(0.3, 0.2, 10.0), -DVec3::Z);
        assert_eq!(raster(&methods, front, ""), vec![0], "at {offset}");
    }
}

/// The faces of the box `min..max`, each split into `n × n` squares whose
/// inner corners are pushed in and out by up to 0.03 (so no two triangles
/// merge): a closed skin of triangles too small to draw one by one.
fn skin(min: DVec3, max: DVec3, n: usize) -> Vec<[DVec3; 3]> {
    let mut out = Vec::new();
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for at in [min[axis], max[axis]] {
            let p = |a: usize, b: usize| {
                let mut c = DVec3::ZERO;
                c[axis] = at;
                c[u] = min[u] + (max[u] - min[u]) * a as f64 / n as f64;
                c[v] = min[v] + (max[v] - min[v]) * b as f64 / n as f64;
                if a != 0 && a != n && b != 0 && b != n {
                    c[axis] += 0.015 * ((a * 7 + b * 13) % 5) as f64 - 0.03;
                }
                c
            };
            for a in 0..n {
                for b in 0..n {
                    out.push([p(a, b), p(a + 1, b), p(a + 1, b + 1)]);
                    out.push([p(a, b), p(a + 1, b + 1), p(a, b + 1)]);
                }
            }
        }
    }
    out
}

/// A hollow box of tiny triangles (object 0: walls 0.2 thick, both skins
/// closed), a box in its hollow (1) and one behind it (2). From outside,
/// its proxies hide both boxes, which its triangles alone (each under
/// `min_size`) do not; from inside its hollow, proxies are not drawn and
/// what truth sees is kept.
#[test]
fn proxies_inside_a_skin_of_tiny_triangles_hide_what_it_hides() {
    let (lo, hi) = (DVec3::splat(-2.0), DVec3::splat(2.0));
    let mut b = SceneBuilder::new("shell");
    b.begin_object("shell", None);
    b.add_triangles(skin(lo, hi, 40), false);
    b.add_triangles(skin(lo + 0.2, hi - 0.2, 40), false);
    b.begin_object("inside", None);
    b.add_triangles(solid(Vec3::splat(-0.3), Vec3::splat(0.3)), false);
    b.begin_object("behind", None);
    b.add_triangles(
        solid(Vec3::new(-0.5, -0.5, -6.0), Vec3::new(0.5, 0.5, -5.0)),
        false,
    );
    let scene = Arc::new(b.finish());
    let methods = SceneMethods::prepare(scene.clone());
    let outside = camera(DVec3::new(0.3, 0.4, 12.0), -DVec3::Z);
    assert_eq!(Truth::render(&scene, &outside).unwrap().visible(), vec![0]);
    assert_eq!(raster(&methods, outside, ""), vec![0]);
    assert_eq!(raster(&methods, outside, "cell=1"), vec![0]);
    assert_eq!(raster(&methods, outside, "proxies=false"), vec![0, 1, 2]);
    // In the hollow, looking at the inner box and past it.
    for eye in [DVec3::new(0.1, 0.2, 1.5), DVec3::new(1.7, 1.7, 1.7)] {
        let cam = camera(eye, -eye);
        let truth = Truth::render(&scene, &cam).unwrap().visible();
        assert!(truth.contains(&1), "{truth:?} from {eye}");
        for options in ["", "cell=1", "proxies=false"] {
            let got = raster(&methods, cam, options);
            for v in &truth {
                assert!(got.contains(v), "{v} dropped with {options:?} from {eye}");
            }
        }
    }

    // An eye just outside the skin whose near plane cuts into the wall,
    // and a box inside the wall: truth sees into the wall through the cut,
    // so no proxy may be drawn.
    let mut b = SceneBuilder::new("cut");
    b.begin_object("shell", None);
    b.add_triangles(skin(lo, hi, 40), false);
    b.add_triangles(skin(lo + 0.2, hi - 0.2, 40), false);
    b.begin_object("in the wall", None);
    b.add_triangles(
        solid(Vec3::new(-0.3, -0.3, 1.84), Vec3::new(0.3, 0.3, 1.9)),
        false,
    );
    let scene = Arc::new(b.finish());
    let methods = SceneMethods::prepare(scene.clone());
    let cam = Camera {
        near: 0.12,
        ..camera(DVec3::new(0.05, 0.02, 2.05), -DVec3::Z)
    };
    let truth = Truth::render(&scene, &cam).unwrap().visible();
    assert!(truth.contains(&1), "{truth:?}");
    for options in ["", "cell=1", "min_size=0"] {
        let got = raster(&methods, cam, options);
        for v in &truth {
            assert!(
                got.contains(v),
                "{v} dropped with {options:?} through the cut"
            );
        }
    }
}

/// Some closed boxes and walls at random (a few shared-plane and touching).
fn random_scene(seed: u64) -> Arc<Scene> {
    use rand::Rng;
    let mut r = common::rng(seed);
    let mut b = SceneBuilder::new("random");
    for i in 0..12 {
        b.begin_object(format!("o{i}"), None);
        let lo = Vec3::new(
            r.random_range(-10.0..10.0),
            r.random_range(-3.0..3.0),
            r.random_range(-10.0..10.0),
        );
        let size = Vec3::new(
            r.random_range(0.1..6.0),
            r.random_range(0.1..4.0),
            r.random_range(0.1..6.0),
        );
        if i % 3 == 0 {
            let z = lo.z as f64;
            b.add_triangles(
                rect(
                    lo.x as f64,
                    (lo + size).x as f64,
                    lo.y as f64,
                    (lo + size).y as f64,
                    z,
                ),
                false,
            );
        } else {
            b.add_triangles(solid(lo, lo + size), false);
        }
    }
    Arc::new(b.finish())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// The AVX2 and the plain loops give the same answer, and both hold
    /// what truth sees.
    #[test]
    fn simd_and_scalar_answer_alike(seed in 0u64..1000, yaw in 0.0f64..std::f64::consts::TAU, pitch in -0.8f64..0.8) {
        let scene = random_scene(seed);
        let methods = SceneMethods::prepare(scene.clone());
        let eye = DVec3::new(yaw.sin() * 16.0, pitch * 6.0, yaw.cos() * 16.0);
        let cam = camera(eye, DVec3::new(0.0, pitch * 2.0, 0.0) - eye);
        let truth = Truth::render(&scene, &cam).unwrap().visible();
        for cell in ["cell=1", "cell=2"] {
            let fast = raster(&methods, cam, cell);
            let plain = raster(&methods, cam, &format!("{cell}:simd=false"));
            prop_assert_eq!(&fast, &plain);
            for v in &truth {
                prop_assert!(fast.contains(v), "{} dropped", v);
            }
        }
    }
}
