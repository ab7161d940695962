//! Ground truth: which objects a view really shows (DESIGN "Accuracy").
//!
//! Every triangle of the scene is rendered at the camera's viewport with its
//! object's id, depth-tested, sampled at pixel centres; an object is
//! *truth-visible* when it is seen at one pixel at least. See-through
//! triangles are drawn depth-tested without writing depth, so what stands
//! behind them stays visible, and they are seen wherever they are in front of
//! the nearest opaque surface.
//!
//! **Ties.** Where the nearest surface of a pixel and the nearest surface of
//! *another* object lie within [`Truth::depth_tolerance`] of each other (two
//! coplanar walls, a poster on a wall), which one wins is decided by rounding,
//! not by geometry. Such pixels are ties: objects seen only at ties are
//! reported apart ([`Truth::ties`]) and are not misses when a method drops
//! them. The tolerance is 8 `f32` ulps of the scene's largest local
//! coordinate (vertices are stored in `f32`, so two surfaces meant to
//! coincide differ by about that) plus 1e-6 of the depth (the `f64`
//! interpolation error is ~1e-15 of it). It is safe: a surface in front of
//! another by more than a millimetre in a kilometre-wide city is a clean
//! winner, so no real visibility is filed as a tie.
//!
//! The rasterizer is this module's own code, independent of `geom::Frustum`
//! and `cull`, which it exists to check. It runs on all cores (rayon, one
//! band of rows per task).

mod raster;

use crate::geom::{Camera, CameraError};
use crate::scene::Scene;

/// No object covers the pixel.
pub const NO_OBJECT: u32 = u32::MAX;

/// The ground truth of one view.
#[derive(Clone, Debug)]
pub struct Truth {
    width: u32,
    height: u32,
    /// Per pixel (row-major, top row first): the nearest opaque object.
    winner: Vec<u32>,
    /// Per object: pixels where it is seen clearly (not a tie).
    clean: Vec<u32>,
    /// Per object: pixels where it is seen only within the depth tolerance of another object.
    tied: Vec<u32>,
    /// Per object: pixels where its see-through surfaces are seen (clean or tied).
    see_through: Vec<u32>,
}

impl Truth {
    /// Renders `scene` from `camera` at `camera.viewport`.
    pub fn render(scene: &Scene, camera: &Camera) -> Result<Truth, CameraError> {
        camera.validate()?;
        Ok(raster::render(scene, camera))
    }

    /// The depth tolerance of a scene at depth `z` (see the module docs).
    pub fn depth_tolerance(scene: &Scene, z: f64) -> f64 {
        let b = scene.bounds();
        let magnitude = if b.is_empty() {
            0.0
        } else {
            b.min.abs().max(b.max.abs()).max_element() as f64
        };
        8.0 * f32::EPSILON as f64 * magnitude + 1e-6 * z
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Truth-visible objects (seen clearly at one pixel at least), ascending.
    pub fn visible(&self) -> Vec<u32> {
        (0..self.clean.len() as u32)
            .filter(|&i| self.clean[i as usize] > 0)
            .collect()
    }

    /// Objects seen only at ties, ascending; not truth-visible, not misses.
    pub fn ties(&self) -> Vec<u32> {
        (0..self.clean.len() as u32)
            .filter(|&i| self.clean[i as usize] == 0 && self.tied[i as usize] > 0)
            .collect()
    }

    /// Pixels at which object `id` is seen, clearly or at a tie.
    pub fn pixels(&self, id: u32) -> u32 {
        self.clean[id as usize] + self.tied[id as usize]
    }

    /// The nearest opaque object at pixel `(x, y)` (row 0 at the top), or [`NO_OBJECT`].
    pub fn winner_at(&self, x: u32, y: u32) -> u32 {
        self.winner[(y * self.width + x) as usize]
    }

    /// Pixels an image drawn from only `pvs` (ascending ids) gets wrong:
    /// those whose nearest opaque surface belongs to a dropped object, plus
    /// the pixels where a dropped see-through object is seen (once per
    /// object, so a pixel behind two dropped see-through layers counts twice).
    pub fn wrong_pixels(&self, pvs: &[u32]) -> u64 {
        let dropped = |id: u32| pvs.binary_search(&id).is_err();
        let opaque = self
            .winner
            .iter()
            .filter(|&&w| w != NO_OBJECT && dropped(w))
            .count() as u64;
        let see_through: u64 = (0..self.see_through.len() as u32)
            .filter(|&i| self.see_through[i as usize] > 0 && dropped(i))
            .map(|i| self.see_through[i as usize] as u64)
            .sum();
        opaque + see_through
    }

    /// Width × height.
    pub fn pixel_count(&self) -> u64 {
        self.width as u64 * self.height as u64
    }
}
