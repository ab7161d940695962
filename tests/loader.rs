//! The glTF loader on the real scenes of `../shared/scenes` and on broken files.

mod common;

use std::path::Path;

use common::{shared_scene, shared_scene_path};
use pvsd::scene::{load_path, load_slice};

/// A row of the table in `../shared/scenes/README.md`:
/// (name, instances, triangles, world bounds min, max).
type Documented = (&'static str, usize, usize, [f64; 3], [f64; 3]);

const SHARED: [Documented; 3] = [
    (
        "2CylinderEngine",
        67,
        121_496,
        [-371.69, -180.97, -140.00],
        [371.69, 92.04, 128.00],
    ),
    (
        "ReciprocatingSaw",
        113,
        198_470,
        [-298.26, -42.42, -29.52],
        [76.47, 41.50, 119.23],
    ),
    (
        "Sponza",
        170,
        262_087,
        [-26.84, 2.28, -16.48],
        [24.18, 23.62, 14.90],
    ),
];

#[test]
fn shared_scenes_have_the_documented_counts_and_bounds() {
    for (name, objects, triangles, lo, hi) in SHARED {
        let scene = shared_scene(name);
        assert_eq!(scene.id, name);
        assert_eq!(scene.objects().len(), objects, "{name} objects");
        assert_eq!(scene.triangle_count(), triangles, "{name} triangles");
        let sum: u32 = scene.objects().iter().map(|o| o.triangle_count()).sum();
        assert_eq!(sum as usize, triangles);
        let (wlo, whi) = scene.to_world(&scene.bounds());
        for k in 0..3 {
            assert!(
                (wlo[k] - lo[k]).abs() < 0.01,
                "{name} min[{k}] {} vs {}",
                wlo[k],
                lo[k]
            );
            assert!(
                (whi[k] - hi[k]).abs() < 0.01,
                "{name} max[{k}] {} vs {}",
                whi[k],
                hi[k]
            );
        }
        for (i, o) in scene.objects().iter().enumerate() {
            assert_eq!(o.id as usize, i);
            assert!(!o.bounds.is_empty(), "{name} object {i} has triangles");
        }
    }
}

#[test]
fn ids_are_stable_between_loads() {
    let a = shared_scene("ReciprocatingSaw");
    let b = shared_scene("ReciprocatingSaw");
    let names = |s: &pvsd::scene::Scene| {
        s.objects()
            .iter()
            .map(|o| (o.id, o.name.clone(), o.bounds))
            .collect::<Vec<_>>()
    };
    assert_eq!(names(&a), names(&b));
}

#[test]
fn sponza_mask_materials_are_see_through() {
    // README: 23 instances, 34,778 triangles use alphaMode MASK.
    let s = shared_scene("Sponza");
    let objects = s
        .objects()
        .iter()
        .filter(|o| !o.see_through.is_empty())
        .count();
    let tris: u32 = s
        .objects()
        .iter()
        .flat_map(|o| &o.see_through)
        .map(|r| r.end - r.start)
        .sum();
    assert_eq!(objects, 23);
    assert_eq!(tris, 34_778);
}

#[test]
fn broken_files_are_errors_naming_file_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.glb");
    let e = load_path(&missing).unwrap_err().to_string();
    assert!(e.contains("nope.glb") && e.contains("cannot read"), "{e}");

    let garbage = dir.path().join("garbage.glb");
    std::fs::write(&garbage, b"this is not a glTF file at all").unwrap();
    let e = load_path(&garbage).unwrap_err().to_string();
    assert!(
        e.contains("garbage.glb") && e.contains("not a valid glTF"),
        "{e}"
    );

    // A .gltf whose .bin is shorter than it declares.
    let src = shared_scene_path("Sponza");
    let gltf = dir.path().join("Sponza.gltf");
    std::fs::copy(&src, &gltf).unwrap();
    let bin = std::fs::read(src.with_file_name("Sponza.bin")).unwrap();
    std::fs::write(dir.path().join("Sponza.bin"), &bin[..1000]).unwrap();
    let e = load_path(&gltf).unwrap_err().to_string();
    assert!(e.contains("Sponza.gltf") && e.contains("byteLength"), "{e}");

    // A missing .bin.
    std::fs::remove_file(dir.path().join("Sponza.bin")).unwrap();
    let e = load_path(&gltf).unwrap_err().to_string();
    assert!(e.contains("Sponza.bin") && e.contains("cannot read"), "{e}");
}

/// A one-triangle glTF with an embedded buffer, for hand-made broken files.
fn tiny_gltf(positions: &[[f32; 3]], indices: &[u32], view_len_override: Option<usize>) -> String {
    use base64::Engine;
    let mut bin = Vec::new();
    positions
        .iter()
        .flatten()
        .for_each(|f| bin.extend_from_slice(&f.to_le_bytes()));
    let pos_len = bin.len();
    indices
        .iter()
        .for_each(|i| bin.extend_from_slice(&i.to_le_bytes()));
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "tri"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3",
             "min": [0,0,0], "max": [1,1,1]},
            {"bufferView": 1, "componentType": 5125, "count": indices.len(), "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": view_len_override.unwrap_or(pos_len)},
            {"buffer": 0, "byteOffset": pos_len, "byteLength": bin.len() - pos_len}
        ],
        "buffers": [{"byteLength": bin.len(), "uri": uri}]
    })
    .to_string()
}

#[test]
fn hand_made_files_load_or_fail_precisely() {
    let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let ok = tiny_gltf(&p, &[0, 1, 2], None);
    let s = load_slice("tiny", ok.as_bytes(), None, Path::new("tiny.gltf")).unwrap();
    assert_eq!((s.objects().len(), s.triangle_count()), (1, 1));
    assert_eq!(s.objects()[0].name, "tri");

    let bad_index = tiny_gltf(&p, &[0, 1, 7], None);
    let e = load_slice("t", bad_index.as_bytes(), None, Path::new("t.gltf"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("index 7 is out of range"), "{e}");

    // The POSITION accessor claims 3 vertices but its view holds 2.
    let short_view = tiny_gltf(&p, &[0, 1, 2], Some(24));
    let e = load_slice("t", short_view.as_bytes(), None, Path::new("t.gltf"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("POSITION accessor 0") && e.contains("past the end"),
        "{e}"
    );

    let nan = tiny_gltf(
        &[[0.0, f32::NAN, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        &[0, 1, 2],
        None,
    );
    let e = load_slice("t", nan.as_bytes(), None, Path::new("t.gltf"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("not finite"), "{e}");

    let truncated = &ok.as_bytes()[..ok.len() / 2];
    let e = load_slice("t", truncated, None, Path::new("cut.gltf"))
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("cut.gltf: not a valid glTF file"), "{e}");
}

#[test]
fn primitives_that_are_not_triangles_are_skipped() {
    let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let mut doc: serde_json::Value =
        serde_json::from_str(&tiny_gltf(&p, &[0, 1, 2], None)).unwrap();
    let tri = doc["meshes"][0]["primitives"][0].clone();
    let mut lines = tri.clone();
    lines["mode"] = serde_json::json!(1);
    let mut strip = tri.clone();
    strip["mode"] = serde_json::json!(5);
    doc["meshes"][0]["primitives"] = serde_json::json!([lines, tri, strip]);
    let s = load_slice(
        "mixed",
        doc.to_string().as_bytes(),
        None,
        Path::new("mixed.gltf"),
    )
    .unwrap();
    assert_eq!(s.objects().len(), 1);
    assert_eq!(
        s.triangle_count(),
        2,
        "the triangle list and the one-triangle strip; the lines are skipped"
    );
}

fn hierarchy(nodes: serde_json::Value) -> String {
    serde_json::json!({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": nodes}).to_string()
}

#[test]
fn node_cycles_are_refused() {
    let doc = hierarchy(serde_json::json!([{"children": [1]}, {"children": [0]}]));
    let e = load_slice("c", doc.as_bytes(), None, Path::new("c.gltf"))
        .expect_err("a cyclic hierarchy loaded");
    assert!(
        e.to_string().starts_with("c.gltf: node 0 is reached twice"),
        "{e}"
    );
}

#[test]
fn shared_children_are_refused_instead_of_exploding() {
    // 40 levels of two references to the same child would be 2^40 instances.
    let nodes: Vec<_> = (0..40)
        .map(|i| serde_json::json!({"children": [i + 1, i + 1]}))
        .chain([serde_json::json!({})])
        .collect();
    let e = load_slice(
        "d",
        hierarchy(nodes.into()).as_bytes(),
        None,
        Path::new("d.gltf"),
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("reached twice"), "{e}");
}

#[test]
fn a_long_chain_of_nodes_does_not_overflow_the_stack() {
    let n = 20_000;
    let nodes: Vec<_> = (0..n)
        .map(|i| {
            if i + 1 < n {
                serde_json::json!({"children": [i + 1]})
            } else {
                serde_json::json!({})
            }
        })
        .collect();
    let s = load_slice(
        "chain",
        hierarchy(nodes.into()).as_bytes(),
        None,
        Path::new("chain.gltf"),
    )
    .unwrap();
    assert_eq!(s.objects().len(), 0);
}

#[test]
fn accessor_edge_cases_are_errors_not_panics() {
    let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let base: serde_json::Value = serde_json::from_str(&tiny_gltf(&p, &[0, 1, 2], None)).unwrap();
    let mut zero = base.clone();
    zero["accessors"][1]["count"] = serde_json::json!(0);
    let mut far = base.clone();
    far["accessors"][0]["byteOffset"] = serde_json::json!(u64::MAX - 7);
    let mut second_bin = base.clone();
    second_bin["buffers"] = serde_json::json!([base["buffers"][0].clone(), {"byteLength": 4}]);
    for (doc, want) in [(zero, "count 0"), (far, ""), (second_bin, "buffer 1")] {
        match load_slice("t", doc.to_string().as_bytes(), None, Path::new("t.gltf")) {
            Err(e) => assert!(e.to_string().contains(want), "{e}"),
            Ok(_) => panic!("loaded: {doc}"),
        }
    }
}

#[test]
fn short_glb_headers_are_errors_not_panics() {
    for bytes in [
        &b"glTF\x02\0\0\0\x0c\0\0\0"[..],
        b"glTF\x02\0\0\0",
        b"glTF\x02\0\0\0\xff\xff\0\0",
    ] {
        let e = load_slice("g", bytes, None, Path::new("g.glb"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.starts_with("g.glb: "), "{e}");
    }
}

/// Found by the `gltf` fuzz target: a primitive naming a POSITION accessor
/// the file does not have made the `gltf` crate's own validation index out
/// of bounds and panic; it is a precise error now.
#[test]
fn a_primitive_naming_a_missing_accessor_is_an_error_not_a_panic() {
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}]
    })
    .to_string();
    let e = pvsd::scene::load_slice("x", json.as_bytes(), None, Path::new("x.gltf"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("x.gltf")
            && e.contains("mesh 0 primitive 0 names accessor 0, but the file has 0"),
        "{e}"
    );
    // And through the indices.
    let json = json.replace(
        r#""attributes":{"POSITION":0}"#,
        r#""attributes":{},"indices":3"#,
    );
    let e = pvsd::scene::load_slice("x", json.as_bytes(), None, Path::new("x.gltf"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("names accessor 3"), "{e}");
}
