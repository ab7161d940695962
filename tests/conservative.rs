//! The conservativeness table: every method the registry knows, through the
//! one shared check, on the same scenes and walks, with the option sets its
//! registry entry names (DESIGN "Accuracy": zero misses). A method added to
//! the registry is in the table without anyone touching this file. And
//! proof that the table catches a method that drops a visible object.

mod common;

use std::sync::Arc;

use common::{check_conservative, checked_methods, city_scene, office_scene, shared_scene};
use pvsd::cull::frustum::FrustumCulling;
use pvsd::cull::{
    CullCounters, CullError, CullMethod, MethodContext, MethodEntry, MethodError, MethodOptions,
    Occludees, Registry, SceneMethods, View, VisibleSet,
};
use pvsd::eval::{Contender, WalkKind};
use pvsd::scene::Scene;

/// Frames per walk: enough to cross a scene, few enough for CI.
const FRAMES: usize = 16;

/// Runs every method `registry` has for `scene` (with each checked option
/// set) over `walks`; returns how many method variants were checked.
fn check_table(
    registry: &Registry,
    scene: &Arc<Scene>,
    walks: &[WalkKind],
) -> Result<usize, String> {
    let methods = SceneMethods::prepare_with(scene.clone(), registry, &MethodContext::default());
    let contenders = |m: &SceneMethods| -> Vec<Contender> {
        checked_methods(m, registry)
            .into_iter()
            .map(|(label, method, options)| Contender::new(label, method, options).unwrap())
            .collect()
    };
    let checked = contenders(&methods).len();
    check_conservative(&methods, walks, FRAMES, contenders)?;
    Ok(checked)
}

/// The table's row for one scene: every standard method it supports.
fn row(scene: &Arc<Scene>, walks: &[WalkKind]) {
    let checked =
        check_table(&Registry::standard(), scene, walks).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{}: {checked} method variants, 0 misses", scene.id);
    assert!(checked >= 1, "{}: no method checked", scene.id);
}

#[test]
fn city_1k() {
    row(
        &city_scene(1000, 1, [0.0; 3]),
        &[WalkKind::Street, WalkKind::Orbit, WalkKind::Random],
    );
}

#[test]
fn city_1k_at_1e7() {
    row(&city_scene(1000, 1, [1e7, 0.0, -1e7]), &[WalkKind::Street]);
}

#[test]
fn office() {
    row(
        &office_scene(1, [0.0; 3]),
        &[WalkKind::Random, WalkKind::Orbit],
    );
}

#[test]
fn office_at_1e7() {
    row(&office_scene(2, [1e7, -1e6, 1e7]), &[WalkKind::Random]);
}

#[test]
fn sponza() {
    row(
        &shared_scene("Sponza"),
        &[WalkKind::Random, WalkKind::Orbit],
    );
}

#[test]
fn two_cylinder_engine() {
    row(&shared_scene("2CylinderEngine"), &[WalkKind::Orbit]);
}

#[test]
fn reciprocating_saw() {
    row(&shared_scene("ReciprocatingSaw"), &[WalkKind::Orbit]);
}

/// Every standard method that is built is supported by some scene of the
/// table, so none escapes it; those that are not built say so.
#[test]
fn every_built_method_has_a_row() {
    let registry = Registry::standard();
    let scenes = [
        city_scene(300, 1, [0.0; 3]),
        office_scene(1, [0.0; 3]),
        shared_scene("Sponza"),
        shared_scene("2CylinderEngine"),
    ];
    let prepared: Vec<SceneMethods> = scenes
        .iter()
        .map(|s| SceneMethods::prepare(s.clone()))
        .collect();
    for entry in registry.entries() {
        let supported = prepared.iter().any(|m| m.names().contains(&entry.name));
        let not_built = prepared[0]
            .unsupported()
            .iter()
            .any(|u| u.method == entry.name && u.reason == pvsd::cull::NOT_BUILT);
        assert!(
            supported || not_built,
            "{} is supported by no scene of the table",
            entry.name
        );
    }
}

/// Frustum culling that claims to be conservative but drops the object
/// nearest the eye (almost always a visible one: the ground under a walker).
struct DropsNearest {
    inner: FrustumCulling,
    scene: Arc<Scene>,
}

impl CullMethod for DropsNearest {
    type State = ();
    fn name(&self) -> &'static str {
        "drops_nearest"
    }
    fn new_state(&self, _: &MethodOptions) -> Result<(), MethodError> {
        Ok(())
    }
    fn is_conservative(&self, _: &()) -> bool {
        true
    }
    fn cull(
        &self,
        view: &View,
        state: &mut (),
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        let counters = self.inner.cull(view, state, out, occludees)?;
        let objects = self.scene.objects();
        let nearest = out.ids().iter().copied().min_by(|&a, &b| {
            let d = |id: u32| objects[id as usize].bounds.distance_to(view.eye());
            d(a).total_cmp(&d(b))
        });
        if let Some(nearest) = nearest {
            out.retain(|&id| id != nearest);
        }
        Ok(counters)
    }
}

#[test]
fn the_table_catches_a_method_that_drops_the_nearest_object() {
    let registry = Registry::standard().with(MethodEntry {
        name: "drops_nearest",
        purpose: "a deliberately wrong method",
        checked_with: &[],
        build: |p| {
            Ok(Arc::new(DropsNearest {
                inner: FrustumCulling::new(p.scene().clone(), p.kd_tree()),
                scene: p.scene().clone(),
            }))
        },
    });
    let scene = city_scene(300, 1, [0.0; 3]);
    let err = check_table(&registry, &scene, &[WalkKind::Street])
        .expect_err("a method that drops the nearest object is not conservative");
    assert!(err.contains("by drops_nearest"), "{err}");
    // Only the wrong method is blamed.
    for line in err.lines() {
        assert!(line.contains("by drops_nearest"), "{line}");
    }
}
