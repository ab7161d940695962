//! The conservativeness table: every method the registry knows, through the
//! one shared check, on the same scenes and walks, with the option sets its
//! registry entry names (DESIGN "Accuracy": zero misses). A method added to
//! the registry is in the table without anyone touching this file. And
//! proof that the table catches a method that drops a visible object.

mod common;

use std::sync::Arc;

use common::{
    cad_scene, check_conservative, check_conservative_in, checked_methods, city_scene, crowd_scene,
    office_scene, shared_scene,
};
use pvsd::cull::frustum::FrustumCulling;
use pvsd::cull::{
    CullCounters, CullError, CullMethod, MethodEntry, MethodError, MethodOptions, Occludees,
    Registry, SceneMethods, View, VisibleSet,
};
use pvsd::eval::{Contender, WalkKind};
use pvsd::geom::Region;
use pvsd::scene::Scene;

/// Frames per walk: enough to cross a scene, few enough for CI.
const FRAMES: usize = 24;

/// One row of the table: a scene and the walks it allows.
struct Row {
    name: &'static str,
    scene: fn() -> Arc<Scene>,
    walks: &'static [WalkKind],
}

/// The table's rows: the generated city and office (at the origin and at a
/// 1e7 offset), a crowd whose movable half every method culls as dynamic
/// occludees, and the real scenes.
const ROWS: [Row; 10] = [
    Row {
        name: "city_1k",
        scene: || city_scene(1000, 1, [0.0; 3]),
        walks: &[WalkKind::Street, WalkKind::Orbit, WalkKind::Random],
    },
    Row {
        name: "city_1k_at_1e7",
        scene: || city_scene(1000, 1, [1e7, 0.0, -1e7]),
        walks: &[WalkKind::Street],
    },
    Row {
        name: "office",
        scene: || office_scene(1, [0.0; 3]),
        walks: &[WalkKind::Random, WalkKind::Orbit],
    },
    Row {
        name: "office_at_1e7",
        scene: || office_scene(2, [1e7, -1e6, 1e7]),
        walks: &[WalkKind::Random],
    },
    Row {
        name: "crowd",
        scene: || crowd_scene(1000, 3),
        walks: &[WalkKind::Street, WalkKind::Random],
    },
    Row {
        name: "cad",
        scene: || cad_scene(1, [0.0; 3]),
        walks: &[WalkKind::Orbit],
    },
    Row {
        name: "cad_at_1e7",
        scene: || cad_scene(2, [1e7, 1e7, -1e7]),
        walks: &[WalkKind::Orbit],
    },
    Row {
        name: "sponza",
        scene: || shared_scene("Sponza"),
        walks: &[WalkKind::Random, WalkKind::Orbit],
    },
    Row {
        name: "two_cylinder_engine",
        scene: || shared_scene("2CylinderEngine"),
        walks: &[WalkKind::Orbit],
    },
    Row {
        name: "reciprocating_saw",
        scene: || shared_scene("ReciprocatingSaw"),
        walks: &[WalkKind::Orbit],
    },
];

/// Runs every method `registry` has for `scene` (with each checked option
/// set) over `walks`; returns how many method variants were checked. Every
/// variant must be conservative: one that says it is not would be exempt
/// from the check.
fn check_table(
    registry: &Registry,
    scene: &Arc<Scene>,
    walks: &[WalkKind],
) -> Result<usize, String> {
    let methods = SceneMethods::prepare_with(scene.clone(), registry, &common::test_context());
    let variants = checked_methods(&methods, registry);
    for (label, method, options) in &variants {
        let cache = method.new_cache(options).unwrap();
        assert!(
            cache.is_conservative(),
            "{label} is checked but says it is not conservative"
        );
    }
    let contenders = |m: &SceneMethods| -> Vec<Contender> {
        checked_methods(m, registry)
            .into_iter()
            .map(|(label, method, options)| Contender::new(label, method, options).unwrap())
            .collect()
    };
    check_conservative(&methods, walks, FRAMES, contenders)?;
    Ok(variants.len())
}

/// The table's row `name`, with every standard method its scene supports.
fn row(name: &str) {
    let row = ROWS
        .iter()
        .find(|r| r.name == name)
        .expect("a row of the table");
    let scene = (row.scene)();
    let checked =
        check_table(&Registry::standard(), &scene, row.walks).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{name}: {checked} method variants, 0 misses");
}

#[test]
fn city_1k() {
    row("city_1k");
}

#[test]
fn city_1k_at_1e7() {
    row("city_1k_at_1e7");
}

#[test]
fn office() {
    row("office");
}

#[test]
fn office_at_1e7() {
    row("office_at_1e7");
}

#[test]
fn crowd() {
    row("crowd");
}

#[test]
fn cad() {
    row("cad");
}

#[test]
fn cad_at_1e7() {
    row("cad_at_1e7");
}

#[test]
fn sponza() {
    row("sponza");
}

#[test]
fn two_cylinder_engine() {
    row("two_cylinder_engine");
}

#[test]
fn reciprocating_saw() {
    row("reciprocating_saw");
}

/// Frames per walk for region answers: each is held to 17–31 truths.
const REGION_FRAMES: usize = 6;

/// The table's row `name` for region answers: every method (and checked
/// option set) that answers for regions, on the row's first walk, with a
/// ball of 1% of the scene's diagonal and a cone of 5°, then a ball alone
/// of 3% (frames held to the truths of cameras sampled in the region).
fn region_row(name: &str) {
    let row = ROWS
        .iter()
        .find(|r| r.name == name)
        .expect("a row of the table");
    let scene = (row.scene)();
    let registry = Registry::standard();
    let methods = SceneMethods::prepare_with(scene.clone(), &registry, &common::test_context());
    let diagonal = f64::from(scene.bounds().extent().length());
    let mut checked = 0;
    for region in [
        Region::new(0.01 * diagonal, 5.0).unwrap(),
        Region::new(0.03 * diagonal, 0.0).unwrap(),
    ] {
        let contenders = |m: &SceneMethods| -> Vec<Contender> {
            checked_methods(m, &registry)
                .into_iter()
                .filter(|(_, method, _)| m.answers_regions(method.name()))
                .map(|(label, method, options)| Contender::new(label, method, options).unwrap())
                .collect()
        };
        checked = contenders(&methods).len();
        check_conservative_in(&methods, &row.walks[..1], REGION_FRAMES, region, contenders)
            .unwrap_or_else(|e| panic!("{region:?}: {e}"));
    }
    eprintln!("{name}: {checked} method variants answer regions, 0 misses");
}

#[test]
fn regions_city_1k() {
    region_row("city_1k");
}

#[test]
fn regions_city_1k_at_1e7() {
    region_row("city_1k_at_1e7");
}

#[test]
fn regions_office() {
    region_row("office");
}

#[test]
fn regions_office_at_1e7() {
    region_row("office_at_1e7");
}

#[test]
fn regions_crowd() {
    region_row("crowd");
}

#[test]
fn regions_cad() {
    region_row("cad");
}

#[test]
fn regions_sponza() {
    region_row("sponza");
}

#[test]
fn regions_two_cylinder_engine() {
    region_row("two_cylinder_engine");
}

#[test]
fn regions_reciprocating_saw() {
    region_row("reciprocating_saw");
}

/// Every standard method that is built is supported by some row of the
/// table, so none escapes it; those that are not built say so.
#[test]
fn every_built_method_has_a_row() {
    let registry = Registry::standard();
    let prepared: Vec<SceneMethods> = ROWS.iter().map(|r| common::prepare((r.scene)())).collect();
    for entry in registry.entries() {
        let rows: Vec<&str> = ROWS
            .iter()
            .zip(&prepared)
            .filter(|(_, m)| m.names().contains(&entry.name))
            .map(|(r, _)| r.name)
            .collect();
        // Without a Vulkan device gpu is nowhere; gpu_or_skip says so, or
        // fails where a device is required.
        let no_device = entry.name == "gpu" && common::gpu_or_skip("table").is_none();
        assert!(
            !rows.is_empty() || no_device,
            "{} is supported by no row of the table",
            entry.name
        );
        eprintln!("{}: rows {rows:?}", entry.name);
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
        options: &[],
        regions: None,
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
