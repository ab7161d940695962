//! Scenes: the in-memory model, the glTF loader and writer, and generators.
//!
//! A scene is a flat list of objects (one per mesh-bearing node instance)
//! with stable ids, boxes and triangles; see [`Scene`].

pub mod bake;
pub mod generate;
pub mod glb;
mod loader;
pub mod mesh;
mod model;
pub mod motion;

pub use bake::{BakeCache, Baked};
pub use loader::{LoadError, load_path, load_slice};
pub use mesh::IndexedMesh;
pub use model::{Object, Scene, SceneBuilder};
pub use motion::{Motion, MoveError};
