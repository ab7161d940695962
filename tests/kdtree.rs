//! The kd-tree of Bittner et al. §2.2 is valid on every scene we have.

mod common;

use common::{city_scene, office_scene, shared_scene};
use glam::Vec3;
use proptest::prelude::*;
use pvsd::scene::{Scene, SceneBuilder};
use pvsd::spatial::{KdTree, KdTreeParams, NodeKind};

fn check(scene: &Scene, params: KdTreeParams) -> KdTree {
    let tree = KdTree::build(scene, params);
    tree.validate(scene)
        .unwrap_or_else(|e| panic!("{}: {e}", scene.id));
    tree
}

#[test]
fn valid_on_generated_and_real_scenes() {
    for scene in [
        city_scene(1000, 1, [0.0; 3]),
        office_scene(1, [0.0; 3]),
        shared_scene("Sponza"),
        shared_scene("2CylinderEngine"),
        shared_scene("ReciprocatingSaw"),
    ] {
        let tree = check(&scene, KdTreeParams::default());
        let root = tree.root().unwrap();
        assert_eq!(
            root.cost as usize,
            scene.triangle_count(),
            "{}: root cost is every triangle",
            scene.id
        );
        let leaves = tree
            .nodes()
            .iter()
            .filter(|n| n.kind == NodeKind::Leaf)
            .count();
        assert!(leaves > 1, "{} was split", scene.id);
    }
}

#[test]
fn splits_few_objects_on_a_city() {
    let scene = city_scene(1000, 2, [0.0; 3]);
    let tree = check(&scene, KdTreeParams::default());
    // Buildings have space between them: few are duplicated. (The ground
    // spans every leaf, so it is left out of the count.)
    let ground = scene.objects().last().unwrap().id;
    let refs = tree.refs().iter().filter(|&&r| r != ground).count();
    let dup = refs as f64 / (scene.objects().len() - 1) as f64;
    assert!(dup < 1.6, "references per building {dup}");
}

fn scene_of_boxes(boxes: &[(Vec3, Vec3)]) -> Scene {
    let mut b = SceneBuilder::new("boxes");
    for (i, (lo, size)) in boxes.iter().enumerate() {
        b.begin_object(format!("b{i}"), None);
        let (lo, hi) = (lo.as_dvec3(), (*lo + *size).as_dvec3());
        b.add_triangles([[lo, glam::DVec3::new(hi.x, lo.y, lo.z), hi]], false);
    }
    b.finish()
}

fn arb_box() -> impl Strategy<Value = (Vec3, Vec3)> {
    let c = -100.0f32..100.0;
    let s = prop_oneof![Just(0.0f32), 0.0f32..0.01, 0.0f32..50.0];
    ((c.clone(), c.clone(), c), (s.clone(), s.clone(), s))
        .prop_map(|((x, y, z), (a, b, c))| (Vec3::new(x, y, z), Vec3::new(a, b, c)))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn valid_on_random_boxes(boxes in proptest::collection::vec(arb_box(), 0..300), leaf in 1usize..6) {
        let scene = scene_of_boxes(&boxes);
        check(&scene, KdTreeParams { max_leaf_objects: leaf, ..KdTreeParams::default() });
    }
}

#[test]
fn identical_boxes_stop_splitting() {
    let boxes = vec![(Vec3::ZERO, Vec3::ONE); 50];
    let tree = check(&scene_of_boxes(&boxes), KdTreeParams::default());
    assert!(
        tree.nodes().len() <= 3,
        "no split separates identical boxes: {} nodes",
        tree.nodes().len()
    );
}

#[test]
fn empty_scene_has_no_root() {
    let tree = check(&scene_of_boxes(&[]), KdTreeParams::default());
    assert!(tree.root().is_none());
}
