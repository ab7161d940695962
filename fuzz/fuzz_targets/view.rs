//! A view body through the parsing and validation the routes use (its
//! one view or its `views`, each with its region).
//! Invariant: a view that validates builds a frustum of finite unit planes
//! around a finite eye, whatever its `radius` and `angle`.
#![no_main]

use std::sync::{Arc, OnceLock};

use libfuzzer_sys::fuzz_target;
use pvsd::geom::Region;
use pvsd::scene::Scene;
use pvsd::server::JsonLimits;
use pvsd::server::wire::ViewRequestExt;
use pvsd_proto::json::ViewRequest;

fuzz_target!(|data: &[u8]| {
    static SCENE: OnceLock<Arc<Scene>> = OnceLock::new();
    let scene = SCENE.get_or_init(pvsd_fuzz::scene);
    let Ok(req) = pvsd::server::parse::<ViewRequest>(data, JsonLimits::default()) else {
        return;
    };
    let _ = req.method_spec();
    let (_, _) = (req.check_stateless(), req.check_frame());
    let Ok(views) = req.views(scene, Region::POINT) else {
        return;
    };
    for view in &views.views {
        check(view);
    }
});

fn check(view: &pvsd::cull::View) {
    assert!(view.eye().is_finite(), "eye {:?}", view.eye());
    for p in view.frustum().planes() {
        assert!(p.normal.is_finite() && p.d.is_finite(), "plane {p:?}");
        assert!(
            (p.normal.length() - 1.0).abs() < 1e-6,
            "plane normal {:?} is not unit",
            p.normal
        );
    }
    for c in view.frustum().corners() {
        assert!(c.is_finite(), "corner {c:?}");
    }
}
