//! `pvsd gen`: deterministic, valid glTF, shaped as DESIGN asks.

mod common;

use common::{city_scene, office_scene};
use pvsd::scene::generate::{CityOptions, OfficeOptions, city, office};

#[test]
fn same_seed_same_bytes_other_seed_other_bytes() {
    let a = city(&CityOptions {
        seed: 7,
        buildings: 200,
        ..CityOptions::default()
    })
    .to_glb();
    let b = city(&CityOptions {
        seed: 7,
        buildings: 200,
        ..CityOptions::default()
    })
    .to_glb();
    let c = city(&CityOptions {
        seed: 8,
        buildings: 200,
        ..CityOptions::default()
    })
    .to_glb();
    assert_eq!(a, b);
    assert_ne!(a, c);
    let a = office(&OfficeOptions {
        seed: 3,
        ..OfficeOptions::default()
    })
    .to_glb();
    let b = office(&OfficeOptions {
        seed: 3,
        ..OfficeOptions::default()
    })
    .to_glb();
    assert_eq!(a, b);
}

#[test]
fn city_is_urbania_shaped() {
    let s = city_scene(1000, 1, [0.0; 3]);
    let objects = s.objects();
    assert_eq!(objects.len(), 1001, "1000 buildings and a ground");
    let ground = objects.last().unwrap();
    assert_eq!(ground.name, "ground");
    assert_eq!(ground.occluder_hint, Some(true));
    let mut tall = 0;
    for (i, b) in objects[..1000].iter().enumerate() {
        assert_eq!(b.name, format!("building_{i:04}"));
        assert_eq!(b.occluder_hint, Some(true));
        assert!(
            (120..=180).contains(&b.triangle_count()),
            "{} has {} triangles",
            b.name,
            b.triangle_count()
        );
        assert!(
            (b.bounds.min.y - ground.bounds.max.y).abs() < 1e-3,
            "{} stands on the ground",
            b.name
        );
        tall += (b.bounds.extent().y >= 50.0) as u32;
    }
    assert!(
        (20..=90).contains(&tall),
        "about 5% tall buildings, got {tall}"
    );
    // Rotated 15° to the axes: the first facade edge of every building.
    for b in &objects[..1000] {
        let t = s.object_triangles(b)[0];
        let edge = t[0] - t[1];
        let angle = edge.z.atan2(edge.x).to_degrees().rem_euclid(90.0);
        assert!(
            (angle - 15.0).abs() < 0.01 || (angle - 75.0).abs() < 0.01,
            "{}: {angle}°",
            b.name
        );
    }
}

#[test]
fn office_has_rooms_walls_and_detail_objects() {
    let s = office_scene(1, [0.0; 3]);
    let plants: Vec<_> = s
        .objects()
        .iter()
        .filter(|o| o.name.starts_with("plant_"))
        .collect();
    let walls = s
        .objects()
        .iter()
        .filter(|o| o.name.starts_with("wall_"))
        .count();
    let floors = s
        .objects()
        .iter()
        .filter(|o| o.name.starts_with("floor_"))
        .count();
    assert_eq!(plants.len(), 100);
    assert_eq!(floors, 3, "two storeys and a roof");
    // Per storey: 5 lines of 6 walls along x, 7 lines of 4 along z.
    assert_eq!(walls, 2 * (5 * 6 + 7 * 4));
    for p in &plants {
        assert_eq!(p.occluder_hint, Some(false));
        assert!(
            (600..=700).contains(&p.triangle_count()),
            "~650 triangles, got {}",
            p.triangle_count()
        );
    }
    for o in s.objects().iter().filter(|o| !o.name.starts_with("plant_")) {
        assert_eq!(o.occluder_hint, Some(true), "{}", o.name);
    }
}

#[test]
fn offset_moves_the_world_not_the_local_geometry() {
    let a = city_scene(100, 5, [0.0; 3]);
    let b = city_scene(100, 5, [1e7, 0.0, -1e7]);
    assert!((b.origin.x - a.origin.x - 1e7).abs() < 1.0);
    for (p, q) in a.objects().iter().zip(b.objects()) {
        let d = (p.bounds.min - q.bounds.min).abs().max_element();
        assert!(d < 1e-3, "{}: {d}", p.name);
    }
}
