//! Spatial hierarchies over a scene's objects: the kd-tree of Bittner et
//! al. §2.2, which frustum culling and the occlusion trees traverse, and the
//! ground-plane quadtree of Downs et al. §3.3, which the horizon sweeps.

mod kdtree;
mod quadtree;

pub use kdtree::{KdNode, KdTree, KdTreeParams, NodeKind};
pub use quadtree::{QuadCell, QuadTree};
