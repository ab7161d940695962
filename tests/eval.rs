//! `pvsd eval`: metrics as DESIGN defines them, checked by hand on a tiny
//! scene; the JSON schema; walkthroughs that are deterministic and stay in
//! free space; the command end to end.

mod common;

use std::sync::Arc;

use common::{city_scene, office_scene, shared_scene};
use glam::{DVec3, Vec3};
use pvsd::cull::{
    CullCounters, CullError, CullMethod, MethodError, MethodOptions, MethodSpec, Occludees, View,
    VisibleSet,
};
use pvsd::eval::{Contender, EvalParams, WalkKind, WalkParams, evaluate, run, walk};
use pvsd::geom::Camera;
use pvsd::scene::generate::MeshBuilder;
use pvsd::scene::{Scene, SceneBuilder};
use pvsd::truth::Truth;

/// Answers the same ids whatever the view.
struct Fixed(Vec<u32>);

impl CullMethod for Fixed {
    type State = ();
    fn name(&self) -> &'static str {
        "fixed"
    }
    fn new_state(&self, _: &MethodOptions) -> Result<(), MethodError> {
        Ok(())
    }
    fn is_conservative(&self, _: &()) -> bool {
        false
    }
    fn cull(
        &self,
        _: &View,
        _: &mut (),
        out: &mut VisibleSet,
        _: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        out.extend_from_slice(&self.0);
        Ok(CullCounters {
            nodes_tested: 0,
            in_frustum: pvsd::cull::InFrustum::Counted(4),
        })
    }
}

/// wall (0) at z = −5 filling the view; box 1 behind it; box 2 in front of
/// it; box 3 behind the camera.
fn tiny() -> Arc<Scene> {
    let mut b = SceneBuilder::new("tiny");
    let mut add = |name: &str, f: &dyn Fn(&mut MeshBuilder)| {
        let mut m = MeshBuilder::new();
        f(&mut m);
        let m = m.build(false);
        b.begin_object(name, None);
        b.add_triangles(m.triangles().map(|t| t.map(|v| v.as_dvec3())), false);
    };
    add("wall", &|m| {
        m.quad(
            Vec3::new(-20.0, -20.0, -5.0),
            Vec3::new(20.0, -20.0, -5.0),
            Vec3::new(20.0, 20.0, -5.0),
            Vec3::new(-20.0, 20.0, -5.0),
        )
    });
    add("hidden", &|m| {
        m.cuboid(Vec3::new(-0.5, -0.5, -9.0), Vec3::new(0.5, 0.5, -8.0), true)
    });
    add("front", &|m| {
        m.cuboid(Vec3::new(-0.5, -0.5, -3.0), Vec3::new(0.5, 0.5, -2.0), true)
    });
    add("behind_camera", &|m| {
        m.cuboid(Vec3::new(-0.5, -0.5, 2.0), Vec3::new(0.5, 0.5, 3.0), true)
    });
    Arc::new(b.finish())
}

#[test]
fn metrics_by_hand_on_a_tiny_scene() {
    let scene = tiny();
    let methods = common::prepare(scene.clone());
    let cam = Camera {
        eye: DVec3::ZERO,
        forward: DVec3::NEG_Z,
        aspect: 1.0,
        viewport: [64, 64],
        ..Camera::default()
    };
    let cameras = vec![cam; 3];
    let params = EvalParams {
        walk: WalkParams {
            frames: 3,
            viewport: [64, 64],
            ..WalkParams::default()
        },
        cost_per_triangle_ns: 1000.0,
        ..EvalParams::default()
    };
    let frustum = Contender::from_spec(&methods, &MethodSpec::named("frustum").unwrap()).unwrap();
    let fixed = Contender::new("fixed", Arc::new(Fixed(vec![0, 3])), MethodOptions::new()).unwrap();
    let report = run(&scene, vec![frustum, fixed], &cameras, &params, |_| {}).unwrap();
    let truth = Truth::render(&scene, &cam).unwrap();
    assert_eq!(
        truth.visible(),
        [0, 2],
        "the wall and the box in front of it"
    );

    let (f, x) = (&report.methods[0], &report.methods[1]);
    assert_eq!(report.frames, 3);
    // frustum: {wall, hidden, front} every frame.
    assert_eq!(
        (f.mean_pvs, f.mean_truth, f.mean_in_frustum),
        (3.0, 2.0, 3.0)
    );
    assert_eq!((f.misses, f.ties), (0, 0));
    assert!(f.conservative);
    assert_eq!(f.overestimation, 1.5);
    assert_eq!(f.culled_in_frustum_share, 0.0);
    assert_eq!(f.wrong_pixel_share, 0.0);
    assert_eq!(f.mean_pvs_triangles, 2.0 + 12.0 + 12.0);
    assert!(
        (f.mean_frame_cost_us - (26.0 + f.median_cull_us)).abs() < f.p99_cull_us + 1e-9,
        "cost ≈ 26 triangles × 1 µs + cull"
    );
    assert_eq!(f.speedup, Some(1.0));
    // fixed {wall, behind_camera}: misses `front` in each of 3 frames.
    // In-frustum is counted by eval for everyone (3), not taken from the
    // method's own claim (4).
    assert_eq!((x.mean_pvs, x.misses, x.mean_in_frustum), (2.0, 3, 3.0));
    assert!(!x.conservative);
    assert_eq!(x.overestimation, 1.0);
    assert_eq!(x.culled_in_frustum_share, 1.0 - 2.0 / 3.0);
    assert_eq!(x.mean_pvs_triangles, 14.0);
    let front_pixels = truth.pixels(2) as f64;
    assert!(front_pixels > 0.0);
    assert!((x.wrong_pixel_share - front_pixels / (64.0 * 64.0)).abs() < 1e-12);
    assert_eq!(x.miss_examples, [(0, 2), (1, 2), (2, 2)]);
    let speedup = f.mean_frame_cost_us / x.mean_frame_cost_us;
    assert!((x.speedup.unwrap() - speedup).abs() < 1e-12);
    // Truth counts ties apart: none here.
    assert_eq!(report.mean_tie_objects, 0.0);
}

#[test]
fn json_has_every_field_design_names() {
    let methods = common::prepare(city_scene(200, 1, [0.0; 3]));
    let params = EvalParams {
        walk: WalkParams {
            kind: WalkKind::Street,
            frames: 5,
            viewport: [128, 80],
            ..WalkParams::default()
        },
        ..EvalParams::default()
    };
    let report = evaluate(
        &methods,
        &[MethodSpec::named("frustum").unwrap()],
        &params,
        |_| {},
    )
    .unwrap();
    let v = serde_json::to_value(&report).unwrap();
    for k in ["scene", "walk", "frames", "resolution", "methods"] {
        assert!(v.get(k).is_some(), "{k}");
    }
    assert_eq!(v["resolution"], serde_json::json!([128, 80]));
    assert_eq!(v["walk"], "street");
    let m = &v["methods"][0];
    for k in [
        "method",
        "options",
        "conservative",
        "median_cull_us",
        "p99_cull_us",
        "mean_pvs",
        "mean_truth",
        "mean_in_frustum",
        "misses",
        "ties",
        "overestimation",
        "culled_in_frustum_share",
        "wrong_pixel_share",
    ] {
        assert!(m.get(k).is_some(), "methods[0].{k}");
    }
    assert!(m["median_cull_us"].as_f64().unwrap() <= m["p99_cull_us"].as_f64().unwrap());
}

#[test]
fn walks_are_deterministic_and_stay_in_free_space() {
    let city = city_scene(500, 2, [0.0; 3]);
    let p = WalkParams {
        kind: WalkKind::Street,
        frames: 200,
        viewport: [64, 48],
        ..WalkParams::default()
    };
    let a = walk(&city, &p).unwrap();
    assert_eq!(a, walk(&city, &p).unwrap());
    assert_ne!(a, walk(&city, &WalkParams { seed: 2, ..p }).unwrap());
    let ground = city.objects().iter().find(|o| o.name == "ground").unwrap();
    let moved: f64 = a.windows(2).map(|w| (w[1].eye - w[0].eye).length()).sum();
    assert!(moved > 100.0, "it walks: {moved} m");
    for c in &a {
        let eye = (c.eye - city.origin).as_vec3();
        assert!(
            (eye.y - ground.bounds.max.y - 1.7).abs() < 1e-3,
            "eye height above the ground"
        );
        // Not inside a building: looking four ways, the view is not one
        // building's walls from edge to edge.
        let enclosed = [DVec3::X, DVec3::Z, DVec3::NEG_X, DVec3::NEG_Z]
            .into_iter()
            .all(|forward| {
                let t = Truth::render(
                    &city,
                    &Camera {
                        forward,
                        viewport: [8, 8],
                        ..*c
                    },
                )
                .unwrap();
                let w = t.winner_at(0, 0);
                w != pvsd::truth::NO_OBJECT
                    && (0..8).all(|y| (0..8).all(|x| t.winner_at(x, y) == w))
            });
        assert!(!enclosed, "the walk entered a building at {}", c.eye);
        assert!(c.validate().is_ok());
    }
    // Random walks wander; orbits stay outside, looking at the centre.
    let r = walk(
        &city,
        &WalkParams {
            kind: WalkKind::Random,
            ..p
        },
    )
    .unwrap();
    assert_ne!(r, a);
    let o = walk(
        &city,
        &WalkParams {
            kind: WalkKind::Orbit,
            frames: 16,
            ..p
        },
    )
    .unwrap();
    let center = city.origin + city.bounds().center().as_dvec3();
    for c in &o {
        let local = (c.eye - city.origin).as_vec3();
        assert!(!city.bounds().contains_point(local), "orbit from outside");
        assert!(c.forward.normalize().dot((center - c.eye).normalize()) > 0.999);
    }
}

#[test]
fn interior_walks_see_something_every_frame() {
    for scene in [office_scene(1, [0.0; 3]), shared_scene("Sponza")] {
        let p = WalkParams {
            kind: WalkKind::Random,
            frames: 30,
            viewport: [96, 64],
            ..WalkParams::default()
        };
        for c in walk(&scene, &p).unwrap() {
            let t = Truth::render(&scene, &c).unwrap();
            assert!(
                !t.visible().is_empty(),
                "{}: a frame that sees nothing at {}",
                scene.id,
                c.eye
            );
        }
    }
}

#[test]
fn eval_command_writes_json_and_svg() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("town.glb");
    let (json, svg) = (dir.path().join("out.json"), dir.path().join("out.svg"));
    let made = std::process::Command::new(env!("CARGO_BIN_EXE_pvsd"))
        .args([
            "gen",
            "city",
            "--buildings",
            "150",
            "-o",
            scene.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(made.status.success());
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_pvsd"))
        .args([
            "eval",
            "--scene",
            scene.to_str().unwrap(),
            "--methods",
            "frustum,auto",
            "--walk",
            "street",
        ])
        .args(["--frames", "6", "--width", "160", "--height", "100"])
        .args([
            "--json",
            json.to_str().unwrap(),
            "--svg",
            svg.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("town: street walk, 6 frames at 160x100"),
        "{stdout}"
    );
    assert!(
        stdout.lines().any(|l| l.starts_with("frustum ")),
        "{stdout}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["methods"].as_array().unwrap().len(), 2);
    // `auto` says what it answered with.
    let auto = report["methods"][1]["method"].as_str().unwrap();
    assert!(auto.starts_with("auto→"), "{auto}");
    let svg = std::fs::read_to_string(&svg).unwrap();
    assert!(
        svg.starts_with("<svg") && svg.contains("frustum") && svg.contains("truth-visible"),
        "{}",
        &svg[..200.min(svg.len())]
    );
    // Bad input: an unknown walk, an unsupported method.
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_pvsd"))
        .args([
            "eval",
            "--scene",
            scene.to_str().unwrap(),
            "--methods",
            "ddo",
        ])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not supported by scene 'town'"));
}
