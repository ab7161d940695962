//! Baking a scene's DDOs (Bernardini et al. §3, Fig. 5): the octree over
//! its static triangles and, for each face of each node, its masks for
//! both partitions of the viewspace (the 64 regions proved, the 32 derived
//! from them: [`coarse_mask`]), on all cores, with
//! a progress bar on a terminal; read from and written to the bake cache.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use glam::DVec3;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use super::octree::{Octree, OctreeParams, Skeleton, face_index};
use super::regions::{Regions, coarse_mask};
use super::validity::{Face, Scratch, Surfaces, Validator};
use crate::scene::{BakeCache, Scene};

/// What names a bake: a change to any of it (or to the validity test)
/// must change this text, so old files are rebuilt, never misread.
fn params_text(params: OctreeParams) -> String {
    format!(
        "ddo v7 leaf={} depth={} regions=64>32 angle={} clip={}",
        params.leaf_triangles,
        params.max_depth,
        super::regions::MAX_ANGLE_DEG,
        super::validity::CLIP
    )
}

/// The octree in which the validity test looks for the triangles along a
/// segment.
const SEARCH_PARAMS: OctreeParams = OctreeParams {
    leaf_triangles: 24,
    max_depth: 12,
};

/// The octree and masks of `scene`, or why it has none (no static geometry,
/// or no face valid from anywhere: DDOs would not pay).
pub fn bake(scene: &Scene, params: OctreeParams) -> Result<Octree, String> {
    let started = Instant::now();
    // Opaque triangles first (the validity test's surfaces are exactly
    // those), then see-through ones, which are seen but hide nothing.
    let mut opaque = Vec::new();
    let mut see_through = Vec::new();
    for o in scene.objects().iter().filter(|o| o.is_static()) {
        let ranges = o.opaque_ranges();
        for r in &ranges {
            opaque.extend((r.start..r.end).map(|t| (o.id, t)));
        }
        see_through.extend(
            o.triangles
                .clone()
                .filter(|t| !ranges.iter().any(|r| r.contains(t)))
                .map(|t| (o.id, t)),
        );
    }
    let all: Vec<(u32, u32)> = opaque.iter().chain(&see_through).copied().collect();
    let corners = |t: u32| scene.triangles()[t as usize].map(|p| p.as_dvec3());
    let boxes: Vec<(DVec3, DVec3)> = all
        .iter()
        .map(|&(_, t)| {
            let c = corners(t);
            (c[0].min(c[1]).min(c[2]), c[0].max(c[1]).max(c[2]))
        })
        .collect();
    let owner: Vec<u32> = all.iter().map(|&(o, _)| o).collect();
    let skeleton = Skeleton::build(&boxes, &owner, params)
        .ok_or_else(|| "the scene has no static geometry".to_string())?;
    let surfaces = Surfaces::new(opaque.iter().map(|&(_, t)| corners(t)).collect());
    // The segments' triangles are found in a finer octree than the DDOs':
    // a leaf of the DDO octree holds up to 256 triangles, most of them far
    // from any one segment.
    let index = Skeleton::build(&boxes, &owner, SEARCH_PARAMS).expect("static geometry, as above");
    let validator = Validator {
        surfaces: &surfaces,
        index: &index,
        extent: scene.bounds().extent().max_element() as f64,
    };
    let bar = ProgressBar::new(skeleton.nodes.len() as u64).with_style(
        ProgressStyle::with_template("{msg} {bar:40} {pos}/{len} nodes, {eta} left")
            .expect("a valid template"),
    );
    bar.set_message(format!("baking ddo for {}", scene.id));
    let done = AtomicU64::new(0);
    let masks: Vec<([u32; 6], [u64; 6])> = skeleton
        .nodes
        .par_iter()
        .map_init(
            || Scratch::new(&surfaces),
            |scratch, node| {
                let mut m32 = [0u32; 6];
                let mut m64 = [0u64; 6];
                for axis in 0..3 {
                    for side in 0..2 {
                        let face = Face::of_cube(node.min, node.size, axis, side);
                        let f = face_index(axis, side);
                        for r in 0..Regions::R64.count() {
                            if validator.is_valid(&face, Regions::R64, r, scratch) {
                                m64[f] |= 1 << r;
                            }
                        }
                        m32[f] = coarse_mask(m64[f]);
                    }
                }
                let n = done.fetch_add(1, Ordering::Relaxed);
                if n % 64 == 0 {
                    bar.set_position(n);
                }
                (m32, m64)
            },
        )
        .collect();
    bar.finish_and_clear();
    let solids_started = Instant::now();
    let solids = super::solid::find(&surfaces, &owner[..opaque.len()], validator.extent);
    let solids_ms = solids_started.elapsed().as_millis() as u64;
    let tree = skeleton.finish(masks, solids);
    tracing::info!(
        scene = %scene.id,
        nodes = tree.nodes().len(),
        valid_faces_32 = tree.valid_faces(Regions::R32),
        valid_faces_64 = tree.valid_faces(Regions::R64),
        solids = tree.solids().len(),
        solid_rects = tree.solids().iter().map(|s| s.rects.len()).sum::<usize>(),
        solids_ms,
        ms = started.elapsed().as_millis() as u64,
        "baked directional discretized occluders"
    );
    if tree.valid_faces(Regions::R32) + tree.valid_faces(Regions::R64) == 0 {
        return Err(
            "no octree face is a valid occluder from any viewspace region: DDOs would not pay here"
                .into(),
        );
    }
    Ok(tree)
}

/// [`bake`], read from `cache` when an earlier run baked this scene file
/// with these parameters, and written there when not.
pub fn bake_cached(scene: &Scene, params: OctreeParams, cache: &BakeCache) -> Result<Octree, String> {
    cache
        .load_or_build(
            scene,
            "ddo",
            &params_text(params),
            || bake(scene, params),
            encode,
            |bytes| decode(bytes, scene),
        )
        .0
}

/// A bake's payload: a status byte, then the octree or the reason.
fn encode(found: &Result<Octree, String>) -> Vec<u8> {
    match found {
        Ok(tree) => {
            let mut out = vec![1u8];
            out.extend(tree.encode());
            out
        }
        Err(reason) => {
            let mut out = vec![0u8];
            out.extend_from_slice(reason.as_bytes());
            out
        }
    }
}

fn decode(bytes: &[u8], scene: &Scene) -> Result<Result<Octree, String>, String> {
    match bytes.split_first() {
        Some((1, rest)) => Octree::decode(rest, scene).map(Ok),
        Some((0, rest)) => Ok(Err(String::from_utf8(rest.to_vec())
            .map_err(|_| "the ddo payload's reason is not UTF-8")?)),
        _ => Err("the ddo payload has no status byte".into()),
    }
}
