//! Spatial hierarchies over a scene's objects.
//!
//! For now the kd-tree of Bittner et al. §2.2, which frustum culling
//! traverses and the occlusion methods will order front to back.

mod kdtree;

pub use kdtree::{KdNode, KdTree, KdTreeParams, NodeKind};
