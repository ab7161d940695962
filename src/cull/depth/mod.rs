//! A conservative depth buffer on the CPU, at the pixel centres ground
//! truth samples: what `raster` draws visible surfaces into and `ddo`
//! draws its valid octree faces into, both then testing boxes against it
//! (Greene's hierarchical z, on a CPU buffer as in Masked Occlusion
//! Culling, Hasselgren, Andersson & Akenine-Möller 2016).
//!
//! - [`screen`]: a view set up against the buffer: convex polygons into
//!   cells, boxes into the cells they cover and their nearest inverse
//!   depth;
//! - [`buffer`]: the buffer of inverse depths, with 8×8-cell tiles holding
//!   their farthest value, taken again when a test needs a changed tile;
//! - [`kernel`]: its two inner loops, in AVX2 and in plain Rust, bit for
//!   bit the same.
//!
//! **What a cell means.** Ground truth calls an object visible when it is
//! the nearest opaque surface at some pixel centre of the viewport. A cell
//! holds a value `v > 0` only where some drawn polygon covers *every*
//! pixel centre of the cell, lying there no farther than depth `1/v`. A
//! box is hidden only when every pixel centre its screen outline covers
//! holds a cell value above the box's nearest inverse depth (or when it
//! covers no centre at all, and so cannot be drawn). So whenever each
//! polygon drawn is known to have opaque surface at least as near as
//! itself along every ray from the eye through it (`raster`: it *is* a
//! union of one object's opaque triangles; `ddo`: a face the bake proved
//! hidden from the eye by opaque triangles), at a covered centre truth's
//! nearest surface is at least that near, every point of a hidden box is
//! farther, and nothing of the box wins the centre. The roundings all go
//! one way:
//! - coverage: a centre counts as covered only inside all of the
//!   polygon's edge planes (through the eye) by a slack above `f64`
//!   rounding, the occluder merge's 1e-12 collinearity, and 1e-4 of a
//!   pixel, after clipping the polygon to beyond a near plane pushed out
//!   by 1e-9;
//! - depth: the polygon is taken as far from the eye as its thickness
//!   allows (what its triangles may stray from its plane), so its inverse
//!   depth is a lower bound; a cell takes the least over its corner
//!   centres (inverse depth is affine on screen, so that is the least over
//!   all of them); the value is moved down by the error of its `f32`
//!   evaluation `base + k·step` before it is written;
//! - boxes: the outline is widened by the view transform's rounding and
//!   the pixel slack, and the nearest depth moved nearer by it, the
//!   inverse depth rounded up to `f32`; a box reaching the near plane is
//!   never hidden; the comparison is strict, so a tie is visible.
//!
//! Cells of several pixels, square or oblong ([`CellSize`]: `across ×
//! down`), keep the argument: a cell is written only where a polygon
//! covers all of its centres, with the least of their depths (a cell
//! reaching past the view's right or bottom edge may count centres beyond
//! it too, which only writes less). (Coarser cells leave seams where
//! neighbouring polygons meet inside a cell, which neither covers whole:
//! on finely tessellated surfaces they hide far less.)

pub mod buffer;
pub mod kernel;
pub mod screen;

pub use buffer::{CellRect, DepthBuffer};
pub use kernel::Kernel;
pub use screen::{CellSize, Drawn, Footprint, Scratch, Screen};
