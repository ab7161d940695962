//! Loading glTF 2.0 files (`.gltf` with its buffers, or `.glb`) into a [`Scene`].
//!
//! The node hierarchy of the default scene is flattened in a pre-order
//! depth-first walk of its root nodes and their children, in file order; each
//! mesh-bearing node instance met becomes the next object (DESIGN "Scenes"),
//! so ids are the same on every load and for every tool that reads the file.
//! Transforms are composed in `f64` so a file placed at 1e7 units keeps its
//! precision until [`SceneBuilder::finish`] subtracts the scene origin.
//!
//! The `gltf` crate parses and validates the JSON. It does not check that an
//! accessor's bytes lie inside its buffer, and its readers index slices
//! directly, so every accessor is checked here before it is read: a broken
//! file is an error naming the file and the problem, never a panic.

use std::path::{Path, PathBuf};

use base64::Engine as _;
use glam::{DMat4, DVec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;

use super::{Scene, SceneBuilder};

/// Why a scene file could not be loaded.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct LoadError {
    /// The file that failed.
    pub path: PathBuf,
    /// What is wrong with it.
    pub problem: String,
}

/// Loads a `.gltf` or `.glb` file; the scene id is the file stem.
pub fn load_path(path: &Path) -> Result<Scene, LoadError> {
    let fail = |problem: String| LoadError {
        path: path.to_path_buf(),
        problem,
    };
    let bytes = std::fs::read(path).map_err(|e| fail(format!("cannot read file: {e}")))?;
    let id = path
        .file_stem()
        .and_then(|s| s.to_str())
        .ok_or_else(|| fail("file name is not valid UTF-8".into()))?;
    load_slice(id, &bytes, path.parent(), path)
}

/// Loads a scene from the bytes of a `.gltf` or `.glb` file.
///
/// `base_dir` resolves external buffer URIs (none for in-memory data);
/// `path` is only used to name the source in errors.
pub fn load_slice(
    id: &str,
    bytes: &[u8],
    base_dir: Option<&Path>,
    path: &Path,
) -> Result<Scene, LoadError> {
    let fail = |problem: String| LoadError {
        path: path.to_path_buf(),
        problem,
    };
    check_glb_header(bytes).map_err(fail)?;
    let invalid = |e: gltf::Error| fail(format!("not a valid glTF file: {e}"));
    // Validated in two steps: the `gltf` crate's own validation indexes a
    // primitive's POSITION accessor before checking it exists (a panic on a
    // file with none; found by `fuzz/` target `gltf`), so that reference
    // is checked here first.
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(bytes).map_err(invalid)?;
    let root = document.into_json();
    check_accessor_references(&root).map_err(fail)?;
    let document = gltf::Document::from_json(root).map_err(invalid)?;
    let buffers = load_buffers(&document, blob, base_dir).map_err(fail)?;
    let scene = document
        .default_scene()
        .or_else(|| document.scenes().next())
        .ok_or_else(|| fail("the file has no scene".into()))?;
    let mut builder = SceneBuilder::new(id);
    walk(&document, scene, &buffers, &mut builder).map_err(fail)?;
    let mut hash = xxhash_rust::xxh3::Xxh3::new();
    hash.update(bytes);
    for b in &buffers {
        hash.update(b);
    }
    let mut scene = builder.finish();
    scene.source_hash = Some(hash.digest128());
    Ok(scene)
}

/// Every accessor a mesh primitive names (attributes, indices) exists.
fn check_accessor_references(root: &gltf::json::Root) -> Result<(), String> {
    let count = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let named = prim.attributes.values().chain(&prim.indices);
            if let Some(a) = named.map(|a| a.value()).find(|&a| a >= count) {
                return Err(format!(
                    "mesh {m} primitive {p} names accessor {a}, but the file has {count}"
                ));
            }
        }
    }
    Ok(())
}

/// The `gltf` crate subtracts the header size from a GLB's declared length
/// unchecked; a file shorter than a header with one chunk is refused first.
fn check_glb_header(bytes: &[u8]) -> Result<(), String> {
    if !bytes.starts_with(b"glTF") {
        return Ok(());
    }
    let word = |at: usize| {
        bytes
            .get(at..at + 4)
            .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]) as usize)
    };
    let declared = word(8).ok_or("the GLB header is cut short")?;
    if declared < 20 || declared > bytes.len() {
        return Err(format!(
            "the GLB header declares {declared} bytes, but the file has {}",
            bytes.len()
        ));
    }
    Ok(())
}

/// Every buffer's bytes. Only buffer 0 may be the GLB binary chunk (glTF
/// §4.4.3.3); it is moved, not copied.
fn load_buffers(
    doc: &gltf::Document,
    mut blob: Option<Vec<u8>>,
    base_dir: Option<&Path>,
) -> Result<Vec<Vec<u8>>, String> {
    let mut out = Vec::new();
    for buffer in doc.buffers() {
        let data = match buffer.source() {
            gltf::buffer::Source::Bin if buffer.index() == 0 => blob.take().ok_or_else(|| {
                "buffer 0 refers to a GLB binary chunk that is missing".to_string()
            })?,
            gltf::buffer::Source::Bin => {
                return Err(format!(
                    "buffer {} refers to the GLB binary chunk, which only buffer 0 may",
                    buffer.index()
                ));
            }
            gltf::buffer::Source::Uri(uri) => read_uri(uri, base_dir)
                .map_err(|e| format!("buffer {} ('{}'): {e}", buffer.index(), short(uri)))?,
        };
        if data.len() < buffer.length() {
            return Err(format!(
                "buffer {} has {} bytes, but the file declares byteLength {}",
                buffer.index(),
                data.len(),
                buffer.length()
            ));
        }
        out.push(data);
    }
    Ok(out)
}

fn short(uri: &str) -> &str {
    if uri.len() > 40 {
        &uri[..uri.char_indices().nth(40).map_or(uri.len(), |(i, _)| i)]
    } else {
        uri
    }
}

fn read_uri(uri: &str, base_dir: Option<&Path>) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, payload) = rest
            .split_once(";base64,")
            .ok_or("only base64 data URIs are supported")?;
        return base64::engine::general_purpose::STANDARD
            .decode(payload)
            .map_err(|e| format!("bad base64: {e}"));
    }
    if uri.contains("://") {
        return Err("only relative file paths and data URIs are supported".into());
    }
    let dir = base_dir.ok_or("an external buffer cannot be resolved for in-memory data")?;
    std::fs::read(dir.join(uri)).map_err(|e| format!("cannot read: {e}"))
}

/// The pre-order walk of DESIGN "Scenes", with an explicit stack (a long
/// chain of nodes cannot overflow the call stack). glTF nodes have at most one
/// parent and no cycles; a node reached twice is refused, which also bounds
/// the number of instances by the number of nodes.
fn walk(
    doc: &gltf::Document,
    scene: gltf::Scene<'_>,
    buffers: &[Vec<u8>],
    builder: &mut SceneBuilder,
) -> Result<(), String> {
    let mut reached = vec![false; doc.nodes().len()];
    // Roots pushed in reverse so they pop in file order; children likewise.
    let mut stack: Vec<(gltf::Node<'_>, DMat4)> =
        scene.nodes().map(|n| (n, DMat4::IDENTITY)).collect();
    stack.reverse();
    while let Some((node, parent)) = stack.pop() {
        let seen = &mut reached[node.index()];
        if *seen {
            return Err(format!(
                "node {} is reached twice: glTF nodes have at most one parent and no cycles",
                node.index()
            ));
        }
        *seen = true;
        let local = node.transform().matrix().map(|c| c.map(f64::from));
        let world = parent * DMat4::from_cols_array_2d(&local);
        if !world.is_finite() {
            return Err(format!(
                "node {} has a transform that is not finite",
                node.index()
            ));
        }
        if let Some(mesh) = node.mesh() {
            let name = node
                .name()
                .or(mesh.name())
                .map(str::to_owned)
                .unwrap_or_else(|| format!("object_{}", builder.object_count()));
            builder.begin_object(name, extra_flag(&node, "occluder"));
            if extra_flag(&node, "movable") == Some(true) {
                builder.set_movable(world);
            }
            for prim in mesh.primitives() {
                let tris = read_triangles(&prim, buffers, &world).map_err(|e| {
                    format!("mesh {} primitive {}: {e}", mesh.index(), prim.index())
                })?;
                builder.add_triangles(tris, is_see_through(&prim.material()));
            }
        }
        let first_child = stack.len();
        stack.extend(node.children().map(|c| (c, world)));
        stack[first_child..].reverse();
    }
    Ok(())
}

/// A boolean of the node's `extras`, as written by `pvsd gen` (and any
/// tool that follows it): `occluder`, `movable`.
fn extra_flag(node: &gltf::Node<'_>, key: &str) -> Option<bool> {
    let raw = node.extras().as_ref()?;
    let v: serde_json::Value = serde_json::from_str(raw.get()).ok()?;
    v.get(key)?.as_bool()
}

/// DESIGN: `BLEND` or `MASK` alpha, or any transmission, makes a surface see-through.
fn is_see_through(material: &gltf::Material<'_>) -> bool {
    matches!(
        material.alpha_mode(),
        gltf::material::AlphaMode::Blend | gltf::material::AlphaMode::Mask
    ) || material
        .transmission()
        .is_some_and(|t| t.transmission_factor() > 0.0 || t.transmission_texture().is_some())
}

fn read_triangles(
    prim: &gltf::Primitive<'_>,
    buffers: &[Vec<u8>],
    world: &DMat4,
) -> Result<Vec<[DVec3; 3]>, String> {
    let mode = prim.mode();
    if !matches!(
        mode,
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
    ) {
        tracing::warn!(?mode, "skipping a primitive that is not made of triangles");
        return Ok(Vec::new());
    }
    let pos = prim
        .get(&gltf::Semantic::Positions)
        .ok_or("has no POSITION attribute")?;
    if pos.data_type() != DataType::F32 || pos.dimensions() != Dimensions::Vec3 {
        return Err("POSITION must be float VEC3".into());
    }
    check_accessor(&pos, buffers).map_err(|e| format!("POSITION accessor {}: {e}", pos.index()))?;
    if let Some(ix) = prim.indices() {
        if !matches!(ix.data_type(), DataType::U8 | DataType::U16 | DataType::U32)
            || ix.dimensions() != Dimensions::Scalar
        {
            return Err("indices must be unsigned integer scalars".into());
        }
        check_accessor(&ix, buffers).map_err(|e| format!("index accessor {}: {e}", ix.index()))?;
    }
    let reader = prim.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
    let positions: Vec<DVec3> = reader
        .read_positions()
        .ok_or("POSITION cannot be read")?
        .map(|p| world.transform_point3(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)))
        .collect();
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err(format!("vertex {i} is not finite"));
    }
    let indices: Vec<u32> = match reader.read_indices() {
        Some(ix) => ix.into_u32().collect(),
        None => (0..positions.len() as u32).collect(),
    };
    if let Some(&bad) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(format!(
            "index {bad} is out of range for {} vertices",
            positions.len()
        ));
    }
    let corner = |i: u32| positions[i as usize];
    let tris = match mode {
        Mode::Triangles => indices
            .chunks_exact(3)
            .map(|c| [corner(c[0]), corner(c[1]), corner(c[2])])
            .collect(),
        Mode::TriangleStrip => indices
            .windows(3)
            .enumerate()
            .map(|(k, w)| {
                if k % 2 == 0 {
                    [corner(w[0]), corner(w[1]), corner(w[2])]
                } else {
                    [corner(w[1]), corner(w[0]), corner(w[2])]
                }
            })
            .collect(),
        _ => match indices.split_first() {
            Some((&hub, rest)) => rest
                .windows(2)
                .map(|w| [corner(hub), corner(w[0]), corner(w[1])])
                .collect(),
            None => Vec::new(),
        },
    };
    Ok(tris)
}

/// Checks that every element of the accessor lies inside its view and buffer.
fn check_accessor(a: &gltf::Accessor<'_>, buffers: &[Vec<u8>]) -> Result<(), String> {
    if a.sparse().is_some() {
        return Err("sparse accessors are not supported".into());
    }
    let view = a.view().ok_or("has no buffer view")?;
    let buffer = buffers
        .get(view.buffer().index())
        .ok_or("refers to a missing buffer")?;
    let elem = a.size();
    let stride = view.stride().unwrap_or(elem);
    if stride < elem {
        return Err(format!(
            "byteStride {stride} is smaller than an element ({elem} bytes)"
        ));
    }
    let view_end = view
        .offset()
        .checked_add(view.length())
        .filter(|&e| e <= buffer.len())
        .ok_or_else(|| {
            format!(
                "buffer view {} runs past the end of its buffer",
                view.index()
            )
        })?;
    if a.count() == 0 {
        // glTF requires count >= 1, and the gltf crate's reader computes count - 1.
        return Err("has count 0".into());
    }
    let last = (a.count() - 1)
        .checked_mul(stride)
        .and_then(|n| n.checked_add(view.offset()))
        .and_then(|n| n.checked_add(a.offset()))
        .and_then(|n| n.checked_add(elem))
        .ok_or("size overflows")?;
    if last > view_end {
        return Err(format!(
            "{} elements run past the end of buffer view {} ({} bytes)",
            a.count(),
            view.index(),
            view.length()
        ));
    }
    Ok(())
}
