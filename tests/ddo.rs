//! `ddo` at DESIGN's numerical extremes (its walks over generated and real
//! scenes are in the conservativeness table, tests/conservative.rs).

mod common;

use glam::DVec3;
use pvsd::cull::ddo::OctreeParams;
use pvsd::cull::{MethodContext, Registry, SceneMethods};
use pvsd::eval::{Contender, WalkKind};
use pvsd::geom::Camera;

/// Objects from 1e-4 to 1e5 units, points and zero-area triangles, from
/// random cameras and at near 1e-6, far 1e9, fov 0.01° and 179°: `ddo`
/// (with every other method) drops nothing truth sees.
#[test]
fn tiny_huge_and_degenerate_objects_at_extreme_cameras() {
    let methods = common::prepare(common::scales_scene());
    assert!(methods.names().contains(&"ddo"), "{:?}", methods.names());
    common::check_extreme_cameras(&methods, 9, 40);
}

/// A CAD body 1e7 units from the world origin, seen from close by, through
/// its windows, grazing its skin and from inside it.
#[test]
fn a_cad_body_far_from_the_origin_up_close() {
    let methods = common::prepare(common::cad_scene(4, [1e7, -1e7, 1e7]));
    assert!(methods.names().contains(&"ddo"), "{:?}", methods.names());
    let registry = Registry::standard();
    let s = methods.scene().clone();
    let (lo, hi) = s.to_world(&s.bounds());
    let mid = (lo + hi) * 0.5;
    let size = hi - lo;
    let mut seen = Vec::new();
    let eyes = [
        mid + DVec3::new(0.0, size.y * 0.2, size.z * 0.8),
        mid + DVec3::new(size.x * 0.55, size.y * 0.1, 0.0),
        mid + DVec3::new(-size.x * 0.3, size.y * 0.51, size.z * 0.2),
        mid + DVec3::new(0.1, 0.05, 0.0),
        mid + DVec3::new(size.x * 0.2, -size.y * 0.2, size.z * 0.501),
    ];
    for (i, eye) in eyes.into_iter().enumerate() {
        for target in [mid, mid + DVec3::new(size.x * 0.3, 0.0, 0.0)] {
            let cam = Camera {
                eye,
                forward: target - eye + DVec3::new(0.0, -0.01 * i as f64, 0.0),
                near: 1e-3,
                ..Camera::default()
            };
            seen.push(common::check_camera(&methods, &registry, cam));
        }
    }
    common::assert_seen(&seen, 0.5);
}

/// A finer octree (`ddo_leaf_triangles`, here 32 triangles a leaf: more
/// nodes, more faces near the skin) through the shared check on an orbit
/// of the CAD body, with every checked option set: zero
/// misses, as with the default cut.
#[test]
fn a_finer_octree_drops_nothing_either() {
    let registry = Registry::standard();
    let context = MethodContext {
        ddo_octree: OctreeParams::with_leaf_triangles(32).unwrap(),
        disabled: registry
            .entries()
            .iter()
            .map(|e| e.name.to_string())
            .filter(|m| m != "frustum" && m != "ddo")
            .collect(),
        ..common::test_context()
    };
    let scene = common::cad_scene(3, [0.0; 3]);
    let methods = SceneMethods::prepare_with(scene, &registry, &context);
    assert!(methods.names().contains(&"ddo"), "{:?}", methods.names());
    common::check_conservative(&methods, &[WalkKind::Orbit], 24, |m| {
        common::checked_methods(m, &registry)
            .into_iter()
            .filter(|(label, ..)| label.starts_with("ddo"))
            .map(|(label, method, options)| Contender::new(label, method, options).unwrap())
            .collect()
    })
    .unwrap();
}
