//! The glTF/GLB loader, from bytes. Invariants: a file either loads or is
//! refused with an error (never a panic); a loaded scene's objects are the
//! mesh-bearing node instances of the default scene in a pre-order walk
//! (DESIGN "Scenes"), found here by a walk of our own over the `gltf`
//! crate's document, with finite bounds.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;

/// The names objects get, in id order, by DESIGN's rule.
fn expected_names(bytes: &[u8]) -> Option<Vec<String>> {
    let doc = gltf::Gltf::from_slice(bytes).ok()?.document;
    let scene = doc.default_scene().or_else(|| doc.scenes().next())?;
    let mut names = Vec::new();
    let mut stack: Vec<gltf::Node<'_>> = scene.nodes().collect();
    stack.reverse();
    while let Some(node) = stack.pop() {
        if let Some(mesh) = node.mesh() {
            let name = node.name().or(mesh.name()).map(str::to_owned);
            names.push(name.unwrap_or_else(|| format!("object_{}", names.len())));
        }
        let mut children: Vec<_> = node.children().collect();
        children.reverse();
        stack.extend(children);
    }
    Some(names)
}

fuzz_target!(|data: &[u8]| {
    let Ok(scene) = pvsd::scene::load_slice("fuzz", data, None, Path::new("fuzz.glb")) else {
        return;
    };
    let names: Vec<&str> = scene.objects().iter().map(|o| o.name.as_str()).collect();
    let expected = expected_names(data).expect("a file that loads parses");
    assert_eq!(names, expected);
    for (i, o) in scene.objects().iter().enumerate() {
        assert_eq!(o.id as usize, i);
        if !o.bounds.is_empty() {
            assert!(o.bounds.min.is_finite() && o.bounds.max.is_finite());
        }
    }
});
