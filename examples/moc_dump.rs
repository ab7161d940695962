//! Writes what a side-by-side run of Intel's Masked Occlusion Culling (MOC)
//! needs to cull exactly the views `pvsd eval --walk views` culls
//! (issue 16): the cameras, every opaque triangle, every object's box, and
//! each view's ground truth. `benches/moc/harness.cpp` reads the file, so MOC
//! runs on the same machine, the same views and the same occluders as
//! pvsd's methods, and its PVS is held to the same truth.
//!
//! `cargo run --release --example moc_dump -- SCENE OUT [FRAMES] [WIDTH HEIGHT] [SEED]`
//! (defaults: 60 frames, 512×320, seed 1: the views of
//! `pvsd eval --walk views --frames 60 --width 512 --height 320`).
//!
//! What is written is what pvsd itself uses:
//! - the cameras of [`walk`] with [`WalkKind::Views`], as their frame
//!   (eye, right, up, forward from [`Camera::basis`]), the half-field
//!   tangents of [`Camera::half_tangents`], near and far; ground truth maps
//!   view space to pixels by `x / (z tx)` and `y / (z ty)` onto
//!   `[-1, 1]` (row 0 at the top), which is MOC's clip space with
//!   `w = z`;
//! - the triangles every occlusion method may draw: each static object's
//!   [`Object::opaque_ranges`] (see-through triangles, `alphaMode` `BLEND`
//!   or `MASK` or transmission, never hide; movable objects are no
//!   occluders either);
//! - each object's box as the frustum test and ground truth see it;
//! - per view, [`Truth::visible`] (the objects `pvsd eval` counts misses
//!   against) and [`Truth::ties`], and the objects
//!   [`FrustumCulling::reference`] keeps (`pvsd eval`'s in-frustum count),
//!   so the harness can check its own frustum test.
//!
//! Everything is scene-local (world = `scene.origin` + local), as pvsd
//! keeps it: triangles and boxes are the scene's own `f32`, eyes are
//! subtracted from the origin in `f64`.
//!
//! The file, little-endian: the magic `PVSDMOC1`; `u32` width, height,
//! views, objects, triangles; per view `f64` eye\[3\], right\[3\], up\[3\],
//! forward\[3\], tx, ty, near, far, then `u32` counts of truth, ties and
//! in-frustum objects, each followed by its ids; per object `f32` min\[3\],
//! max\[3\], `u32` flags (1: no box, 2: movable), first triangle and
//! triangle count (its opaque triangles in the triangle array); per
//! triangle `f32` × 9 (three corners).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::time::Instant;

use pvsd::cull::View;
use pvsd::cull::frustum::FrustumCulling;
use pvsd::eval::{WalkKind, WalkParams, walk};
use pvsd::geom::Camera;
use pvsd::scene::{Object, Scene};
use pvsd::truth::Truth;

/// Object flag: the object has no triangles, hence no box.
const NO_BOX: u32 = 1;
/// Object flag: the object may move (no occluder, as in pvsd's methods).
const MOVABLE: u32 = 2;

fn main() {
    if let Err(e) = run() {
        eprintln!("moc_dump: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: moc_dump SCENE OUT [FRAMES] [WIDTH HEIGHT] [SEED]".into());
    }
    let number = |i: usize, default: u64| -> Result<u64, String> {
        args.get(i).map_or(Ok(default), |s| {
            s.parse()
                .map_err(|_| format!("argument {i} ({s}) is not a number"))
        })
    };
    let frames = number(3, 60)? as usize;
    let viewport = [number(4, 512)? as u32, number(5, 320)? as u32];
    let seed = number(6, 1)?;

    let scene = pvsd::scene::load_path(Path::new(&args[1]))?;
    let params = WalkParams {
        kind: WalkKind::Views,
        frames,
        seed,
        viewport,
        ..WalkParams::default()
    };
    let cameras = walk(&scene, &params)?;

    let mut out = BufWriter::new(File::create(&args[2])?);
    let (triangles, ranges) = occluders(&scene);
    out.write_all(b"PVSDMOC1")?;
    for n in [
        viewport[0],
        viewport[1],
        cameras.len() as u32,
        scene.objects().len() as u32,
        triangles.len() as u32,
    ] {
        out.write_all(&n.to_le_bytes())?;
    }

    let started = Instant::now();
    let (mut truth_total, mut frustum_total) = (0usize, 0usize);
    for camera in &cameras {
        write_camera(&mut out, &scene, camera)?;
        let truth = Truth::render(&scene, camera)?;
        let in_frustum = FrustumCulling::reference(&scene, View::new(*camera, &scene)?.frustum());
        let visible = truth.visible();
        truth_total += visible.len();
        frustum_total += in_frustum.len();
        for ids in [&visible, &truth.ties(), &in_frustum] {
            out.write_all(&(ids.len() as u32).to_le_bytes())?;
            for id in ids {
                out.write_all(&id.to_le_bytes())?;
            }
        }
    }
    let truth_s = started.elapsed().as_secs_f64();

    for (o, range) in scene.objects().iter().zip(&ranges) {
        let b = o.bounds;
        for v in [b.min, b.max] {
            for c in v.to_array() {
                out.write_all(&c.to_le_bytes())?;
            }
        }
        let flags = u32::from(b.is_empty()) * NO_BOX + u32::from(o.movable) * MOVABLE;
        for n in [flags, range.0, range.1] {
            out.write_all(&n.to_le_bytes())?;
        }
    }
    for t in &triangles {
        for v in t {
            for c in v.to_array() {
                out.write_all(&c.to_le_bytes())?;
            }
        }
    }
    out.flush()?;

    let n = cameras.len().max(1) as f64;
    let see_through: u32 = scene
        .objects()
        .iter()
        .flat_map(|o| &o.see_through)
        .map(|r| r.end - r.start)
        .sum();
    eprintln!(
        "moc_dump: {} ({} objects, {} movable; {} triangles, {} see-through, {} written as occluders); \
         {} views at {}×{} (seed {seed}): mean truth {:.2}, mean in frustum {:.2} (truth rendered in {truth_s:.1} s)",
        scene.id,
        scene.objects().len(),
        scene.objects().iter().filter(|o| o.movable).count(),
        scene.triangle_count(),
        see_through,
        triangles.len(),
        cameras.len(),
        viewport[0],
        viewport[1],
        truth_total as f64 / n,
        frustum_total as f64 / n,
    );
    Ok(())
}

/// Every static object's opaque triangles, and per object (static or not)
/// where its own lie among them: `(first, count)`.
fn occluders(scene: &Scene) -> (Vec<[glam::Vec3; 3]>, Vec<(u32, u32)>) {
    let mut triangles = Vec::new();
    let ranges = scene
        .objects()
        .iter()
        .map(|o: &Object| {
            let first = triangles.len() as u32;
            if !o.movable {
                for r in o.opaque_ranges() {
                    triangles
                        .extend_from_slice(&scene.triangles()[r.start as usize..r.end as usize]);
                }
            }
            (first, triangles.len() as u32 - first)
        })
        .collect();
    (triangles, ranges)
}

/// The camera as the harness builds its clip space from it: eye
/// (scene-local), frame, half-field tangents, near and far.
fn write_camera(out: &mut impl Write, scene: &Scene, camera: &Camera) -> std::io::Result<()> {
    let basis = camera.basis().expect("a walk's cameras are valid");
    let (tx, ty) = camera.half_tangents();
    let eye = camera.eye - scene.origin;
    for v in [eye, basis.right, basis.up, basis.forward] {
        for c in v.to_array() {
            out.write_all(&c.to_le_bytes())?;
        }
    }
    for c in [tx, ty, camera.near, camera.far] {
        out.write_all(&c.to_le_bytes())?;
    }
    Ok(())
}
