//! Writing scenes as glTF 2.0 binary (`.glb`) files.
//!
//! Generators describe a scene as a [`Document`] of nodes and meshes; this
//! module lays the geometry out in one binary chunk (all positions in one
//! buffer view, all indices in another) and writes the JSON chunk with
//! `serde_json`. What it writes is read back by [`crate::scene::load_slice`]
//! in the tests, which validate it through the `gltf` crate.

use serde_json::{Value, json};

/// A triangle mesh, indexed, in the node's local coordinates.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangle list, three indices a triangle.
    pub indices: Vec<u32>,
    /// Whether the mesh is drawn with a blended material (seen, never hiding).
    pub see_through: bool,
}

impl Mesh {
    /// The triangles, as corner positions.
    pub fn triangles(&self) -> impl Iterator<Item = [glam::Vec3; 3]> + '_ {
        let corner = |i: u32| glam::Vec3::from(self.positions[i as usize]);
        self.indices
            .chunks_exact(3)
            .map(move |c| [corner(c[0]), corner(c[1]), corner(c[2])])
    }
}

/// A node of the hierarchy.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Node {
    /// Readable name (`building_0042`, `wall_3_17`).
    pub name: String,
    /// Local translation.
    pub translation: [f32; 3],
    /// Local rotation as a unit quaternion `[x, y, z, w]`.
    pub rotation: [f32; 4],
    /// Index into [`Document::meshes`], if the node draws one.
    pub mesh: Option<usize>,
    /// Indices into [`Document::nodes`].
    pub children: Vec<usize>,
    /// The node's `extras` (e.g. `{"occluder": true}`).
    pub extras: Option<Value>,
}

impl Node {
    /// A node with the given name and no transform.
    pub fn named(name: impl Into<String>) -> Self {
        Node {
            name: name.into(),
            rotation: [0.0, 0.0, 0.0, 1.0],
            ..Node::default()
        }
    }
}

/// A whole glTF document: one scene whose roots are `roots`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Document {
    /// Every node; children refer to them by index.
    pub nodes: Vec<Node>,
    /// Every mesh; nodes refer to them by index.
    pub meshes: Vec<Mesh>,
    /// The root nodes of the default scene, in order.
    pub roots: Vec<usize>,
}

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

impl Document {
    /// Adds a mesh and returns its index.
    pub fn add_mesh(&mut self, mesh: Mesh) -> usize {
        self.meshes.push(mesh);
        self.meshes.len() - 1
    }

    /// Adds a node and returns its index.
    pub fn add_node(&mut self, node: Node) -> usize {
        self.nodes.push(node);
        self.nodes.len() - 1
    }

    /// The document as `.glb` bytes.
    ///
    /// # Panics
    /// When a mesh has no triangles: glTF forbids the empty buffer views
    /// and accessors that would make (generators never build one).
    pub fn to_glb(&self) -> Vec<u8> {
        assert!(
            self.meshes
                .iter()
                .all(|m| !m.indices.is_empty() && !m.positions.is_empty()),
            "glTF cannot hold an empty mesh"
        );
        let positions_len: usize = self.meshes.iter().map(|m| m.positions.len() * 12).sum();
        let mut bin = Vec::with_capacity(
            positions_len
                + self
                    .meshes
                    .iter()
                    .map(|m| m.indices.len() * 4)
                    .sum::<usize>(),
        );
        let mut accessors = Vec::new();
        let mut meshes = Vec::new();
        for m in &self.meshes {
            let offset = bin.len();
            let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for p in &m.positions {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                    bin.extend_from_slice(&p[k].to_le_bytes());
                }
            }
            accessors.push(json!({
                "bufferView": 0, "byteOffset": offset, "componentType": FLOAT,
                "count": m.positions.len(), "type": "VEC3", "min": lo, "max": hi,
            }));
            let material = if m.see_through { 1 } else { 0 };
            meshes.push(json!({ "primitives": [{
                "attributes": { "POSITION": accessors.len() - 1 },
                "indices": Value::Null, // patched once index accessors are laid out
                "material": material, "mode": 4,
            }]}));
        }
        // Index accessors follow all position accessors; patch the primitives.
        let index_base = bin.len();
        for (i, m) in self.meshes.iter().enumerate() {
            let offset = bin.len() - index_base;
            for &ix in &m.indices {
                bin.extend_from_slice(&ix.to_le_bytes());
            }
            accessors.push(json!({
                "bufferView": 1, "byteOffset": offset, "componentType": UNSIGNED_INT,
                "count": m.indices.len(), "type": "SCALAR",
            }));
            meshes[i]["primitives"][0]["indices"] = json!(accessors.len() - 1);
        }
        let nodes: Vec<Value> = self.nodes.iter().map(node_json).collect();
        let mut views = vec![json!({
            "buffer": 0, "byteOffset": 0, "byteLength": index_base, "target": ARRAY_BUFFER,
        })];
        views.push(json!({
            "buffer": 0, "byteOffset": index_base, "byteLength": bin.len() - index_base,
            "target": ELEMENT_ARRAY_BUFFER,
        }));
        let doc = json!({
            "asset": { "version": "2.0", "generator": concat!("pvsd ", env!("CARGO_PKG_VERSION")) },
            "scene": 0,
            "scenes": [{ "nodes": self.roots }],
            "nodes": nodes,
            "meshes": meshes,
            "materials": [
                { "name": "opaque" },
                { "name": "see_through", "alphaMode": "BLEND" },
            ],
            "accessors": accessors,
            "bufferViews": views,
            "buffers": [{ "byteLength": bin.len() }],
        });
        glb_container(
            &serde_json::to_vec(&doc).expect("JSON of plain values"),
            &bin,
        )
    }
}

fn node_json(n: &Node) -> Value {
    let mut v = json!({ "name": n.name });
    if n.translation != [0.0; 3] {
        v["translation"] = json!(n.translation);
    }
    if n.rotation != [0.0, 0.0, 0.0, 1.0] {
        v["rotation"] = json!(n.rotation);
    }
    if let Some(m) = n.mesh {
        v["mesh"] = json!(m);
    }
    if !n.children.is_empty() {
        v["children"] = json!(n.children);
    }
    if let Some(e) = &n.extras {
        v["extras"] = e.clone();
    }
    v
}

/// The GLB container: header, JSON chunk (space-padded), BIN chunk (zero-padded).
fn glb_container(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let json_len = json.len() + pad(json.len());
    let bin_len = bin.len() + pad(bin.len());
    let has_bin = !bin.is_empty();
    let total = 12 + 8 + json_len + if has_bin { 8 + bin_len } else { 0 };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json_len as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()), b' ');
    if has_bin {
        out.extend_from_slice(&(bin_len as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin);
        out.resize(out.len() + pad(bin.len()), 0);
    }
    out
}
