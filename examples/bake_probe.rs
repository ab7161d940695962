fn main() {
    for f in [
        "/tmp/sc/city10k.glb",
        "../shared/scenes/Sponza/Sponza.gltf",
        "/tmp/sc/cad.glb",
    ] {
        let t = std::time::Instant::now();
        let scene = std::sync::Arc::new(pvsd::scene::load_path(std::path::Path::new(f)).unwrap());
        let load = t.elapsed();
        let t = std::time::Instant::now();
        let tree = pvsd::spatial::KdTree::build(&scene, Default::default());
        let kd = t.elapsed();
        let t = std::time::Instant::now();
        let occ = pvsd::cull::occluder::Occluders::find(&scene, &tree);
        let oc = t.elapsed();
        let t = std::time::Instant::now();
        let pr = pvsd::cull::horizon::Prisms::find(&scene);
        let pt = t.elapsed();
        let t = std::time::Instant::now();
        let _m = pvsd::cull::SceneMethods::prepare(scene.clone());
        let all = t.elapsed();
        println!(
            "{f}: load {load:?} kd {kd:?} occluders {oc:?} ({}) prisms {pt:?} ({}) prepare-all {all:?}",
            occ.map_or(0, |o| o.all().len()),
            pr.map_or(0, |p| p.len())
        );
    }
}
