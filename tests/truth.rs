//! Ground truth on hand-built scenes whose answers are known.

mod common;

use common::{city_scene, shared_scene};
use glam::{DVec3, Vec3};
use pvsd::geom::Camera;
use pvsd::scene::generate::MeshBuilder;
use pvsd::scene::{Scene, SceneBuilder};
use pvsd::truth::Truth;

/// An object made with a `MeshBuilder`.
struct Part {
    name: &'static str,
    mesh: MeshBuilder,
    see_through: bool,
}

fn part(name: &'static str, f: impl FnOnce(&mut MeshBuilder)) -> Part {
    let mut mesh = MeshBuilder::new();
    f(&mut mesh);
    Part {
        name,
        mesh,
        see_through: false,
    }
}

fn scene(parts: Vec<Part>) -> Scene {
    let mut b = SceneBuilder::new("hand");
    for p in parts {
        b.begin_object(p.name, None);
        let m = p.mesh.build(p.see_through);
        b.add_triangles(
            m.triangles().map(|t| t.map(|v| v.as_dvec3())),
            m.see_through,
        );
    }
    b.finish()
}

/// A camera at the origin looking down -Z, square image of `px` pixels.
fn camera(px: u32) -> Camera {
    Camera {
        eye: DVec3::ZERO,
        forward: DVec3::NEG_Z,
        up: DVec3::Y,
        fov_y_deg: 60.0,
        aspect: 1.0,
        near: 0.1,
        far: 100.0,
        viewport: [px, px],
    }
}

/// A wall facing the camera at depth `z`, spanning x0..x1 and y0..y1.
fn wall(m: &mut MeshBuilder, x0: f32, x1: f32, y0: f32, y1: f32, z: f32) {
    m.quad(
        Vec3::new(x0, y0, z),
        Vec3::new(x1, y0, z),
        Vec3::new(x1, y1, z),
        Vec3::new(x0, y1, z),
    );
}

fn cube(m: &mut MeshBuilder, center: Vec3, half: f32) {
    m.cuboid(center - Vec3::splat(half), center + Vec3::splat(half), true);
}

fn names(s: &Scene, ids: &[u32]) -> Vec<String> {
    ids.iter()
        .map(|&i| s.objects()[i as usize].name.clone())
        .collect()
}

#[test]
fn a_box_behind_a_wall_is_hidden() {
    let s = scene(vec![
        part("wall", |m| wall(m, -10.0, 10.0, -10.0, 10.0, -5.0)),
        part("box", |m| cube(m, Vec3::new(0.0, 0.0, -8.0), 0.5)),
    ]);
    let t = Truth::render(&s, &camera(64)).unwrap();
    assert_eq!(names(&s, &t.visible()), ["wall"]);
    assert_eq!(t.pixels(0), 64 * 64, "the wall fills the image");
}

#[test]
fn a_box_seen_through_a_one_pixel_slit_is_visible() {
    // At depth 5 a pixel of a 101-pixel, 60° image is 2·5·tan 30° / 101 ≈ 0.057
    // wide; the slit is 0.07 wide around x = 0, so it holds the centre column.
    let s = scene(vec![
        part("left", |m| wall(m, -10.0, -0.035, -10.0, 10.0, -5.0)),
        part("right", |m| wall(m, 0.035, 10.0, -10.0, 10.0, -5.0)),
        part("box", |m| cube(m, Vec3::new(0.0, 0.0, -8.0), 0.5)),
    ]);
    let t = Truth::render(&s, &camera(101)).unwrap();
    assert_eq!(names(&s, &t.visible()), ["left", "right", "box"]);
    let columns: Vec<u32> = (0..101)
        .filter(|&x| (0..101).any(|y| t.winner_at(x, y) == 2))
        .collect();
    assert_eq!(columns, [50], "the box shows in the one centre column");
    // Close the slit and the box is gone.
    let closed = scene(vec![
        part("left", |m| wall(m, -10.0, 0.0, -10.0, 10.0, -5.0)),
        part("right", |m| wall(m, 0.0, 10.0, -10.0, 10.0, -5.0)),
        part("box", |m| cube(m, Vec3::new(0.0, 0.0, -8.0), 0.5)),
    ]);
    let t = Truth::render(&closed, &camera(101)).unwrap();
    assert_eq!(
        names(&closed, &t.visible()),
        ["left", "right"],
        "no crack on the shared edge"
    );
}

#[test]
fn objects_beyond_far_or_nearer_than_near_are_not_seen() {
    let s = scene(vec![
        part("far_box", |m| cube(m, Vec3::new(0.0, 0.0, -150.0), 1.0)),
        part("near_box", |m| cube(m, Vec3::new(0.0, 0.0, -0.05), 0.02)),
        part("across_near", |m| {
            cube(m, Vec3::new(0.02, 0.0, -0.12), 0.03)
        }),
        part("across_far", |m| {
            cube(m, Vec3::new(-20.0, 0.0, -100.0), 5.0)
        }),
    ]);
    let t = Truth::render(&s, &camera(64)).unwrap();
    assert_eq!(names(&s, &t.visible()), ["across_near", "across_far"]);
}

#[test]
fn a_thin_pole_a_huge_floor_and_what_is_under_it() {
    // 64 px over 2·10·tan 30° ≈ 11.5 units at depth 10: a pixel is 0.18 wide.
    let s = scene(vec![
        part("pole", |m| {
            m.cuboid(
                Vec3::new(-0.2, -3.0, -10.2),
                Vec3::new(0.2, 3.0, -9.8),
                true,
            )
        }),
        part("floor", |m| {
            m.quad(
                Vec3::new(-5e4, -1.7, 5e4),
                Vec3::new(5e4, -1.7, 5e4),
                Vec3::new(5e4, -1.7, -5e4),
                Vec3::new(-5e4, -1.7, -5e4),
            )
        }),
        part("cellar", |m| cube(m, Vec3::new(0.0, -10.0, -10.0), 2.0)),
    ]);
    let mut cam = camera(64);
    cam.far = 1e6;
    let t = Truth::render(&s, &cam).unwrap();
    assert_eq!(names(&s, &t.visible()), ["pole", "floor"]);
    assert!(
        (2 * 20..=3 * 40).contains(&t.pixels(0)),
        "a pole 2–3 pixels wide: {}",
        t.pixels(0)
    );
}

#[test]
fn an_object_around_the_camera_is_seen_and_what_is_outside_it_is_not() {
    let s = scene(vec![
        part("room", |m| {
            m.cuboid(Vec3::splat(-3.0), Vec3::splat(3.0), true)
        }),
        part("outside", |m| cube(m, Vec3::new(0.0, 0.0, -10.0), 1.0)),
    ]);
    for forward in [DVec3::NEG_Z, DVec3::X, DVec3::new(0.3, 0.2, 1.0)] {
        let t = Truth::render(
            &s,
            &Camera {
                forward,
                ..camera(32)
            },
        )
        .unwrap();
        assert_eq!(names(&s, &t.visible()), ["room"]);
        assert_eq!(t.pixels(0), 32 * 32);
    }
}

#[test]
fn see_through_surfaces_are_seen_and_hide_nothing() {
    let mut glass = part("glass", |m| wall(m, -10.0, 10.0, -10.0, 10.0, -5.0));
    glass.see_through = true;
    let s = scene(vec![
        glass,
        part("box", |m| cube(m, Vec3::new(0.0, 0.0, -8.0), 0.5)),
    ]);
    let t = Truth::render(&s, &camera(64)).unwrap();
    assert_eq!(names(&s, &t.visible()), ["glass", "box"]);
    // Without the glass in the set, every pixel is wrong; without the box, only its own.
    assert_eq!(t.wrong_pixels(&[1]), 64 * 64);
    assert_eq!(t.wrong_pixels(&[0]), t.pixels(1) as u64);
    assert_eq!(t.wrong_pixels(&[0, 1]), 0);
}

#[test]
fn coplanar_coincident_surfaces_are_ties_not_visible() {
    let s = scene(vec![
        part("a", |m| wall(m, -1.0, 1.0, -1.0, 1.0, -5.0)),
        part("b", |m| wall(m, -1.0, 1.0, -1.0, 1.0, -5.0)),
        part("behind", |m| wall(m, -10.0, 10.0, -10.0, 10.0, -9.0)),
    ]);
    let t = Truth::render(&s, &camera(64)).unwrap();
    assert_eq!(names(&s, &t.visible()), ["behind"]);
    assert_eq!(names(&s, &t.ties()), ["a", "b"]);
}

#[test]
fn sponza_plants_are_seen_but_hide_nothing() {
    let s = shared_scene("Sponza");
    let see_through: Vec<u32> = s
        .objects()
        .iter()
        .filter(|o| !o.see_through.is_empty())
        .map(|o| o.id)
        .collect();
    let cam = Camera {
        eye: DVec3::new(-10.0, 5.0, 0.5),
        forward: DVec3::new(1.0, -0.1, 0.0),
        viewport: [256, 160],
        ..Camera::default()
    };
    let t = Truth::render(&s, &cam).unwrap();
    let visible = t.visible();
    assert!(visible.len() > 20, "{}", visible.len());
    assert!(
        visible.iter().any(|v| see_through.contains(v)),
        "some plant or chain is seen"
    );
    // Every winning opaque pixel belongs to an opaque surface.
    for y in 0..160 {
        for x in 0..256 {
            let w = t.winner_at(x, y);
            if w != pvsd::truth::NO_OBJECT {
                let o = &s.objects()[w as usize];
                assert!(
                    o.see_through.len() <= 1
                        && (o.see_through.is_empty() || o.see_through[0] != o.triangles)
                );
            }
        }
    }
}

#[test]
fn a_translated_scene_has_the_same_truth() {
    let a = city_scene(200, 3, [0.0; 3]);
    let b = city_scene(200, 3, [1e7, 0.0, 1e7]);
    let mut r = common::rng(4);
    for _ in 0..10 {
        let mut cam = common::random_camera(&mut r, &a, 0.1);
        cam.viewport = [160, 100];
        let moved = Camera {
            eye: cam.eye + DVec3::new(1e7, 0.0, 1e7),
            ..cam
        };
        let (ta, tb) = (
            Truth::render(&a, &cam).unwrap(),
            Truth::render(&b, &moved).unwrap(),
        );
        assert_eq!(ta.visible(), tb.visible());
    }
}
