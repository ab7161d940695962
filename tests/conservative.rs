//! Every conservative method, through the shared check, on generated and
//! real scenes: zero misses against ground truth. And proof that the check
//! fails for a method that drops one visible object.

mod common;

use std::sync::Arc;

use common::{assert_conservative, check_conservative, city_scene, office_scene, shared_scene};
use pvsd::cull::frustum::FrustumCulling;
use pvsd::cull::{CullCounters, CullMethod, MethodError, MethodOptions, View, VisibleSet};
use pvsd::eval::{Contender, WalkKind};
use pvsd::spatial::{KdTree, KdTreeParams};

#[test]
fn frustum_on_a_city() {
    assert_conservative(
        &city_scene(1000, 1, [0.0; 3]),
        "frustum",
        &[WalkKind::Street, WalkKind::Orbit],
        24,
    );
}

#[test]
fn frustum_on_an_office() {
    assert_conservative(
        &office_scene(1, [0.0; 3]),
        "frustum",
        &[WalkKind::Random, WalkKind::Orbit],
        24,
    );
}

#[test]
fn frustum_on_real_scenes() {
    assert_conservative(
        &shared_scene("Sponza"),
        "frustum",
        &[WalkKind::Random, WalkKind::Orbit],
        24,
    );
    assert_conservative(
        &shared_scene("2CylinderEngine"),
        "frustum",
        &[WalkKind::Orbit],
        16,
    );
    assert_conservative(
        &shared_scene("ReciprocatingSaw"),
        "frustum",
        &[WalkKind::Orbit],
        16,
    );
}

#[test]
fn frustum_far_from_the_origin() {
    assert_conservative(
        &city_scene(300, 2, [1e7, 0.0, -1e7]),
        "frustum",
        &[WalkKind::Street],
        16,
    );
}

/// Frustum culling that claims to be conservative but drops one object.
struct DropsOne {
    inner: FrustumCulling,
    victim: u32,
}

impl CullMethod for DropsOne {
    type State = ();
    fn name(&self) -> &'static str {
        "drops_one"
    }
    fn new_state(&self, _: &MethodOptions) -> Result<(), MethodError> {
        Ok(())
    }
    fn is_conservative(&self, _: &()) -> bool {
        true
    }
    fn cull(&self, view: &View, state: &mut (), out: &mut VisibleSet) -> CullCounters {
        let counters = self.inner.cull(view, state, out);
        out.retain(|&id| id != self.victim);
        counters
    }
}

#[test]
fn the_check_fails_for_a_method_that_drops_one_visible_object() {
    let scene = city_scene(300, 1, [0.0; 3]);
    let ground = scene
        .objects()
        .iter()
        .find(|o| o.name == "ground")
        .unwrap()
        .id;
    let tree = Arc::new(KdTree::build(&scene, KdTreeParams::default()));
    let dropper = Arc::new(DropsOne {
        inner: FrustumCulling::new(scene.clone(), tree),
        victim: ground,
    });
    let err = check_conservative(&scene, &[WalkKind::Street], 8, |_| {
        Contender::new("drops_one", dropper.clone(), MethodOptions::new()).unwrap()
    })
    .expect_err("a method that drops the ground is not conservative");
    assert!(err.contains("drops_one") && err.contains("ground"), "{err}");
}
