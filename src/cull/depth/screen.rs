//! A view set up for the depth buffer: occluder polygons drawn into cells
//! and boxes turned into the cells they cover and their nearest inverse
//! depth, both rounded so that the buffer can only under-state what an
//! occluder hides (the module doc of [`super`] gives the argument).
//!
//! Screen positions are the viewport's pixels (x right, y down); pixel
//! `(i, j)` has its centre at `(i + ½, j + ½)`, as ground truth's. The ray
//! through screen position `(x, y)` is `r = (X·tx, Y·ty, 1)` in view space
//! with `X = 2x/W − 1`, `Y = 1 − 2y/H`, so that anything linear in `r` is
//! affine in `(x, y)`: the side of a plane through the eye (an occluder's
//! edge seen from the eye) and the inverse depth `1/z` of a plane.

use std::cmp::Ordering;
use std::fmt;
use std::str::FromStr;

use glam::DVec3;

use super::buffer::{CellRect, DepthBuffer};
use super::kernel::{Bound, Kernel, Outline, Span};
use crate::cull::View;
use crate::geom::{Aabb, Plane, ceil_i64, floor_i64, greater, lesser};

/// An occluder's corners must lie inside a pixel centre's edge planes by
/// this share of their squared distance from the eye (times the ray's
/// length), beyond rounding: the merged polygons may stand out of their
/// triangles by 1e-12 of an edge (`occluder::extract`'s `COLLINEAR`), and
/// `f64` rounding is ~1e-16; 1e-9 covers both a thousand times over and is
/// 1e-6 of a pixel on any viewport.
const EDGE_SLACK: f64 = 1e-9;

/// Also a pixel centre must lie this far (in pixels) inside an occluder's
/// outline, and a box's outline is widened by as much: ground truth's own
/// rasterizer rounds too, and a centre this close to an edge is not worth
/// deciding.
const PIXEL_SLACK: f64 = 1e-4;

/// Rounding of a scene-local position moved to view space, as a share of
/// the magnitudes involved (the eye's and the point's distance from the
/// scene origin): a few `f64` ulps, taken a thousand times over.
const TRANSFORM_SLACK: f64 = 1e-12;

/// Near-plane clipping keeps the part of a polygon beyond `near` grown by
/// this share, so that rounding of the cut never leaves a corner in front
/// of the plane, where ground truth draws nothing.
const NEAR_SLACK: f64 = 1e-9;

/// Buffers one draw reuses from the last, so drawing allocates nothing.
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    poly: Vec<DVec3>,
    edges: Vec<(f64, f64, f64, f64)>,
    left: Vec<Bound>,
    right: Vec<Bound>,
    level: Vec<(f64, f64)>,
    spans: Vec<Span>,
}

/// What a box covers on screen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Footprint {
    /// It reaches the near plane (or behind the eye): not decidable here.
    Near,
    /// It covers no pixel centre: nothing of it can be drawn.
    Nothing,
    /// It covers at most these cells, no nearer than inverse depth `w`.
    Cells(CellRect, f32),
}

/// What drawing a polygon did to the buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Drawn {
    /// Some cell rose.
    Raised,
    /// It lies in view, but behind what the buffer holds wherever it
    /// would write.
    Behind,
    /// It had nothing to draw: off the view (or off the cells it may
    /// write), seen edge-on or from within its thickness, clipped away by
    /// the near plane, or degenerate.
    Missed,
}

/// Pixels per cell, across and down: written `2` for a square, `2x3`
/// for one two pixels wide and three tall. A draw's cost follows the rows
/// it writes more than their length, so a taller cell is the cheaper way
/// to coarsen (docs/ddo.md measures it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellSize {
    pub across: usize,
    pub down: usize,
}

impl CellSize {
    /// `n × n` pixels.
    pub const fn square(n: usize) -> CellSize {
        CellSize { across: n, down: n }
    }
}

impl fmt::Display for CellSize {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.across == self.down {
            write!(f, "{}", self.across)
        } else {
            write!(f, "{}x{}", self.across, self.down)
        }
    }
}

impl FromStr for CellSize {
    type Err = std::num::ParseIntError;

    fn from_str(text: &str) -> Result<CellSize, Self::Err> {
        match text.split_once('x') {
            Some((across, down)) => Ok(CellSize {
                across: across.parse()?,
                down: down.parse()?,
            }),
            None => text.parse().map(CellSize::square),
        }
    }
}

/// Ordered side by side: one size is within another when it is in both
/// directions, so a range `1..=8` bounds each side.
impl PartialOrd for CellSize {
    fn partial_cmp(&self, other: &CellSize) -> Option<Ordering> {
        match (self.across.cmp(&other.across), self.down.cmp(&other.down)) {
            (a, d) if a == d => Some(a),
            (Ordering::Equal, d) => Some(d),
            (a, Ordering::Equal) => Some(a),
            _ => None,
        }
    }
}

/// A view set up against the buffer's cells.
#[derive(Clone, Copy, Debug)]
pub struct Screen {
    eye: DVec3,
    right: DVec3,
    up: DVec3,
    forward: DVec3,
    tx: f64,
    ty: f64,
    near: f64,
    /// Viewport, pixels.
    width: f64,
    height: f64,
    /// Pixels per cell across and down.
    across: usize,
    down: usize,
    cols: usize,
    rows: usize,
    /// The longest ray `r` (at a corner of the screen).
    ray: f64,
    /// Absolute rounding of a view-space position (scene units).
    slack: f64,
    /// The loops [`Screen::footprint`] runs.
    kernel: Kernel,
}

impl Screen {
    /// `view` with cells of `cell` pixels; `scene_radius` bounds the
    /// scene-local coordinates of everything drawn or tested; `kernel`
    /// runs its loops (the buffer's, where it has one).
    pub fn new(view: &View, cell: CellSize, scene_radius: f64, kernel: Kernel) -> Screen {
        let CellSize { across, down } = cell;
        debug_assert!(across > 0 && down > 0, "cells of {cell} pixels");
        let camera = view.camera();
        let (tx, ty) = camera.half_tangents();
        let [w, h] = camera.viewport;
        let b = view.basis();
        Screen {
            eye: view.eye(),
            right: b.right,
            up: b.up,
            forward: b.forward,
            tx,
            ty,
            near: camera.near,
            width: w as f64,
            height: h as f64,
            across,
            down,
            cols: (w as usize).div_ceil(across),
            rows: (h as usize).div_ceil(down),
            ray: (tx * tx + ty * ty + 1.0).sqrt(),
            slack: TRANSFORM_SLACK * (view.eye().length() + scene_radius),
            kernel,
        }
    }

    /// Cells across, cells down.
    pub fn cells(&self) -> (usize, usize) {
        (self.cols, self.rows)
    }

    /// All the cells.
    pub fn everywhere(&self) -> CellRect {
        CellRect {
            x0: 0,
            y0: 0,
            x1: self.cols - 1,
            y1: self.rows - 1,
        }
    }

    fn view_of(&self, p: DVec3) -> DVec3 {
        let d = p - self.eye;
        DVec3::new(d.dot(self.right), d.dot(self.up), d.dot(self.forward))
    }

    /// Where view-space `v` (beyond the near plane) shows, to a few ulps:
    /// one division, since only the rows a polygon may cover and a box
    /// around them rest on it, and a pixel centre covered lies a pixel
    /// slack (1e-4) inside both.
    fn screen_of(&self, v: DVec3) -> (f64, f64) {
        let inv = 1.0 / v.z;
        let (hw, hh) = (0.5 * self.width, 0.5 * self.height);
        (
            v.x * inv * (hw / self.tx) + hw,
            hh - v.y * inv * (hh / self.ty),
        )
    }

    /// About how many pixels across a sphere of `radius` around `centre`
    /// (scene-local) shows; infinite when it reaches the near plane.
    pub fn pixels_across(&self, centre: DVec3, radius: f64) -> f64 {
        let z = (centre - self.eye).dot(self.forward) - radius;
        if z <= self.near {
            return f64::INFINITY;
        }
        2.0 * radius / z * (0.5 * self.height / self.ty)
    }

    /// Pixels per scene unit at the nearest depth of box `b` (infinite
    /// when it reaches the near plane).
    pub fn pixels_per_unit(&self, b: &Aabb) -> f64 {
        let (c, h) = (b.center().as_dvec3(), b.extent().as_dvec3() * 0.5);
        let z = (c - self.eye).dot(self.forward) - h.dot(self.forward.abs());
        if z <= self.near {
            return f64::INFINITY;
        }
        0.5 * self.height / self.ty / z
    }

    /// Draws the convex polygon `corners` (scene-local) of plane `plane`
    /// into `buffer`: every cell all of whose pixel centres it covers
    /// (beyond the near plane) is raised to a lower bound of `1/z` at its
    /// farthest point among those centres, with the polygon taken
    /// `thickness` farther from the eye than its plane (what its triangles
    /// may stray from it). What it did: [`Drawn`].
    pub fn draw<C: Copy + Into<DVec3>>(
        &self,
        corners: &[C],
        plane: &Plane,
        thickness: f64,
        buffer: &mut DepthBuffer,
        scratch: &mut Scratch,
    ) -> Drawn {
        self.draw_within(
            corners,
            plane,
            thickness,
            self.everywhere(),
            buffer,
            scratch,
        )
    }

    /// [`Screen::draw`] writing only cells of `within` (taken within the
    /// screen; where the caller knows a later test may look): writing
    /// fewer cells only leaves more visible, and a cell written gets the
    /// same bound as from a whole draw (its `f32` rounding, which the
    /// margin covers, may differ by an ulp: each row starts its values
    /// at its first cell written).
    pub fn draw_within<C: Copy + Into<DVec3>>(
        &self,
        corners: &[C],
        plane: &Plane,
        thickness: f64,
        within: CellRect,
        buffer: &mut DepthBuffer,
        scratch: &mut Scratch,
    ) -> Drawn {
        // The plane seen from the eye: n·v = dist for its points v (view space).
        let mut n = DVec3::new(
            plane.normal.dot(self.right),
            plane.normal.dot(self.up),
            plane.normal.dot(self.forward),
        );
        if corners.len() < 3 {
            return Drawn::Missed;
        }
        let mut dist = -plane.signed_distance(self.eye);
        if dist < 0.0 {
            (n, dist) = (-n, -dist);
        }
        let far_side = dist + thickness + self.slack;
        if dist <= 2.0 * (thickness + self.slack) {
            return Drawn::Missed; // seen edge-on, or from within its thickness: hides nothing sure
        }
        self.clip_near(corners, &mut scratch.poly);
        let poly = &scratch.poly[..];
        let len = poly.len();
        if len < 3 {
            return Drawn::Missed;
        }

        // Screen bounds of the clipped polygon: the rows to visit.
        let (mut y_lo, mut y_hi, mut x_lo, mut x_hi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for &v in poly {
            let (x, y) = self.screen_of(v);
            (x_lo, x_hi) = (lesser(x_lo, x), greater(x_hi, x));
            (y_lo, y_hi) = (lesser(y_lo, y), greater(y_hi, y));
        }
        if !(x_hi >= 0.0 && x_lo <= self.width && y_hi >= 0.0 && y_lo <= self.height) {
            return Drawn::Missed;
        }
        // Hidden already where it would write (each cell above its nearest
        // inverse depth): drawing it would change nothing.
        let z_min = poly.iter().map(|v| v.z).fold(f64::INFINITY, lesser);
        let (cx, cy) = (self.across as f64, self.down as f64);
        let cells = CellRect {
            x0: floor_i64(x_lo / cx).max(within.x0 as i64) as usize,
            y0: floor_i64(y_lo / cy).max(within.y0 as i64) as usize,
            x1: floor_i64(x_hi / cx).min(within.x1.min(self.cols - 1) as i64) as usize,
            y1: floor_i64(y_hi / cy).min(within.y1.min(self.rows - 1) as i64) as usize,
        };
        if cells.x0 > cells.x1 || cells.y0 > cells.y1 {
            return Drawn::Missed;
        }
        if buffer.hides(cells, (1.0 / z_min) as f32) {
            return Drawn::Behind;
        }
        // Edge functions A·x + B·y + C ≥ tol inside, one per edge from
        // corner k to k + 1, signed once the winding is known (below).
        let centroid: DVec3 = poly.iter().sum::<DVec3>() / len as f64;
        let edges = &mut scratch.edges;
        edges.clear();
        let mut orientation = 0.0;
        // Each corner's squared length taken once, for both its edges.
        let (mut a, mut a2) = (poly[0], poly[0].length_squared());
        for k in 1..=len {
            let b = if k < len { poly[k] } else { poly[0] };
            let b2 = b.length_squared();
            let e = a.cross(b);
            orientation += e.dot(centroid);
            let size = a2.max(b2).sqrt();
            let tol = (EDGE_SLACK * size + self.slack * 4.0) * size * self.ray;
            let (ea, eb) = (
                2.0 * e.x * self.tx / self.width,
                -2.0 * e.y * self.ty / self.height,
            );
            edges.push((ea, eb, -e.x * self.tx + e.y * self.ty + e.z, tol));
            (a, a2) = (b, b2);
        }
        if !(orientation != 0.0 && orientation.is_finite()) {
            return Drawn::Missed;
        }
        let s = orientation.signum();
        let edges = &edges[..];

        // Inverse depth: w(x, y) = n·r / far_side, affine in (x, y).
        let wa = 2.0 * n.x * self.tx / (self.width * far_side);
        let wb = -2.0 * n.y * self.ty / (self.height * far_side);
        let wc = (-n.x * self.tx + n.y * self.ty + n.z) / far_side;
        let w_round = TRANSFORM_SLACK * (wa.abs() * self.width + wb.abs() * self.height + wc.abs());
        if !(wa.is_finite() && wb.is_finite() && wc.is_finite()) {
            return Drawn::Missed;
        }

        // Per edge, the bound on a row's cells as an affine function of
        // the row's centre y, in cell columns: `first ≥ p + q·y` for edges
        // facing right, `last ≤ p + q·y` for edges facing left, and rows
        // wholly on one side for level edges. Solving `A·x + B·y + C ≥ tol`
        // once instead of per row rounds differently by ~1e-16 of the
        // terms, under 1e-9 of the pixel slack in `tol` on any viewport.
        // Each bound binds at the cell row's top or bottom pixel row,
        // known from its slope: kept as that row's offset from the top
        // one, so a row costs no branch per edge.
        let (left, right, level) = (&mut scratch.left, &mut scratch.right, &mut scratch.level);
        left.clear();
        right.clear();
        level.clear();
        let bottom = cy - 1.0;
        for &(ea, eb, ec, tol) in edges {
            let (ea, eb, ec) = (ea * s, eb * s, ec * s);
            // |A| + |B| ≥ the edge function's growth per pixel of distance.
            let tol = tol + PIXEL_SLACK * (ea.abs() + eb.abs());
            if ea == 0.0 {
                level.push((eb, ec - tol));
                continue;
            }
            let p = (tol - ec) / ea - 0.5;
            let q = -eb / ea / cx;
            if !(p.is_finite() && q.is_finite()) {
                return Drawn::Missed;
            }
            if ea > 0.0 {
                left.push((p / cx, q, if q > 0.0 { bottom } else { 0.0 }));
            } else {
                right.push(((p - (cx - 1.0)) / cx, q, if q < 0.0 { bottom } else { 0.0 }));
            }
        }
        // In f32, `base + k·step` rounds twice, each within half an ulp of
        // the larger magnitude (at most the polygon's largest inverse
        // depth, `1/z_min`, or a row's worth of steps), and `base` and
        // `step` round once each on the way to f32: three ulps of both
        // bound it, and `base` is lowered by that before conversion.
        let step = wa * cx;
        let step32 = step as f32;
        let f32_margin =
            3.0 * f32::EPSILON as f64 * (1.0 / z_min + 2.0 * self.cols as f64 * step.abs())
                + f32::MIN_POSITIVE as f64;
        let (row_first, row_last) = (cells.y0, cells.y1);
        // Pixel rows and columns are whole numbers, exact in f64 (and
        // counted as i64: converting an unsigned one costs several steps).
        let last_centre = self.height - 0.5;
        let y_first = (row_first * self.down) as i64 as f64 + 0.5;
        // Each bound is affine in y, taken at its binding row (⌈max⌉ =
        // max⌈⌉). In the screen's last cell row that row may lie below the
        // last pixel row: the bound there is only tighter, and the cell is
        // written only if the polygon covers more than it has.
        // Grown only: the kernel writes every span it is given.
        let count = row_last + 1 - row_first;
        if scratch.spans.len() < count {
            scratch.spans.resize(count, (0, 0));
        }
        let spans = &mut scratch.spans[..count];
        let last_col = cells.x1 as i64 as f64;
        buffer
            .kernel()
            .spans(left, right, (y_first, cy), last_col, spans);
        if cells.x0 > 0 {
            for span in spans.iter_mut() {
                span.0 = span.0.max(cells.x0 as i32);
            }
        }
        // Rows wholly outside a level edge: none.
        if !level.is_empty() {
            for (k, span) in spans.iter_mut().enumerate() {
                let y_top = y_first + (k as i64 as f64) * cy;
                let y_bot = lesser(y_top + bottom, last_centre);
                if level
                    .iter()
                    .any(|&(b, c)| b * y_top + c < 0.0 || b * y_bot + c < 0.0)
                {
                    *span = (1, 0);
                }
            }
        }
        // The farthest of a cell's corner centres (the least w): its last
        // pixel row where w falls downwards (that row clamped to the
        // screen's last), else its first (never below the last).
        let x_far = 0.5 + if wa < 0.0 { cx - 1.0 } else { 0.0 };
        let y_far = y_first + if wb < 0.0 { bottom } else { 0.0 };
        // The margins taken once (their sum rounds by ~1e-16 of it, far
        // below `w_round`), not per row.
        let offset = wc - w_round - f32_margin;
        let base = move |k: usize, lo: i32| {
            let y = lesser(y_far + (k as i64 as f64) * cy, last_centre);
            (wa * (lo as f64 * cx + x_far) + wb * y + offset) as f32
        };
        if buffer.raise_rows(row_first, spans, base, step32) {
            Drawn::Raised
        } else {
            Drawn::Behind
        }
    }

    /// `corners` moved to view space and clipped to beyond the near plane,
    /// into `out` (fewer than three corners: nothing left). Corners that
    /// round together are merged.
    fn clip_near<C: Copy + Into<DVec3>>(&self, corners: &[C], out: &mut Vec<DVec3>) {
        let near = self.near * (1.0 + NEAR_SLACK) + self.slack;
        out.clear();
        let push = |p: DVec3, out: &mut Vec<DVec3>| {
            if out
                .last()
                .is_none_or(|q| (*q - p).length_squared() > 1e-24 * p.length_squared())
            {
                out.push(p);
            }
        };
        let n = corners.len();
        let mut a = self.view_of(corners[n - 1].into());
        for &c in corners {
            let b = self.view_of(c.into());
            let (ina, inb) = (a.z >= near, b.z >= near);
            if ina != inb {
                let t = (near - a.z) / (b.z - a.z);
                let mut p = a + (b - a) * t;
                p.z = near;
                push(p, out);
            }
            if inb {
                push(b, out);
            }
            a = b;
        }
        while out.len() > 1
            && (out[0] - out[out.len() - 1]).length_squared() <= 1e-24 * out[0].length_squared()
        {
            out.pop();
        }
        if out.len() < 3 {
            out.clear();
        }
    }

    /// The cells `b` (scene-local) may cover and its nearest inverse depth.
    pub fn footprint(&self, b: &Aabb) -> Footprint {
        // Corners as the near corner plus the box's edges in view space.
        // The edges are taken in f64: in f32 their rounding (half an ulp
        // of the box's size) could move a corner farther from the eye, or
        // inward on screen, by more than the slack allows for.
        let e = b.max.as_dvec3() - b.min.as_dvec3();
        let base = self.view_of(b.min.as_dvec3());
        let axis =
            |len: f64, a: usize| DVec3::new(self.right[a], self.up[a], self.forward[a]) * len;
        let (ex, ey, ez) = (axis(e.x, 0), axis(e.y, 1), axis(e.z, 2));
        let Some(Outline {
            z_min,
            x: (x_lo, x_hi),
            y: (y_lo, y_hi),
        }) = self
            .kernel
            .outline(base, [ex, ey, ez], self.near + self.slack)
        else {
            // Also a NaN depth: not decidable.
            return Footprint::Near;
        };
        // The corners' rounding, moved to the screen: the slack over the
        // nearest depth in tangent units, more for corners off to the
        // side; then into pixels, with 1e-9 of them for the division.
        let (sx, sy) = (0.5 * self.width / self.tx, 0.5 * self.height / self.ty);
        let tan_x = x_lo.abs().max(x_hi.abs());
        let tan_y = y_lo.abs().max(y_hi.abs());
        let err_x = self.slack * (1.0 + tan_x) / z_min * sx + 1e-9 * (tan_x * sx + self.width);
        let err_y = self.slack * (1.0 + tan_y) / z_min * sy + 1e-9 * (tan_y * sy + self.height);
        let to_x = |t: f64| (t / self.tx + 1.0) * 0.5 * self.width;
        let to_y = |t: f64| (1.0 - t / self.ty) * 0.5 * self.height;
        // Pixel centres i + ½ within the outline, widened by the slacks.
        let i0 = ceil_i64(to_x(x_lo) - err_x - PIXEL_SLACK - 0.5).max(0);
        let i1 = floor_i64(to_x(x_hi) + err_x + PIXEL_SLACK - 0.5).min(self.width as i64 - 1);
        let j0 = ceil_i64(to_y(y_hi) - err_y - PIXEL_SLACK - 0.5).max(0);
        let j1 = floor_i64(to_y(y_lo) + err_y + PIXEL_SLACK - 0.5).min(self.height as i64 - 1);
        if !(i0 <= i1 && j0 <= j1) {
            return Footprint::Nothing;
        }
        let w = 1.0 / (z_min - self.slack);
        let mut w32 = w as f32;
        if (w32 as f64) < w {
            // w > 0: the next float up is one more in its bits.
            w32 = f32::from_bits(w32.to_bits() + 1);
        }
        Footprint::Cells(
            CellRect {
                x0: i0 as usize / self.across,
                y0: j0 as usize / self.down,
                x1: i1 as usize / self.across,
                y1: j1 as usize / self.down,
            },
            w32,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cull::depth::Kernel;
    use crate::geom::Camera;
    use crate::scene::SceneBuilder;

    /// A 64 × 48 view down −z from 10 units above the plane `z = 0`.
    fn screen() -> Screen {
        screen_of_cells(CellSize::square(1))
    }

    /// [`screen`] with cells of `across × down` pixels.
    fn screen_of_cells(cells: CellSize) -> Screen {
        let scene = SceneBuilder::new("empty").finish();
        let camera = Camera {
            eye: DVec3::new(0.0, 0.0, 10.0),
            forward: DVec3::NEG_Z,
            up: DVec3::Y,
            aspect: 64.0 / 48.0,
            viewport: [64, 48],
            ..Camera::default()
        };
        Screen::new(
            &View::new(camera, &scene).expect("a view"),
            cells,
            100.0,
            Kernel::detect(),
        )
    }

    /// The square `[−h, h]²` of the plane `z = 0`.
    fn square(h: f64) -> [DVec3; 4] {
        [(-h, -h), (h, -h), (h, h), (-h, h)].map(|(x, y)| DVec3::new(x, y, 0.0))
    }

    fn rect(x0: usize, y0: usize, x1: usize, y1: usize) -> CellRect {
        CellRect { x0, y0, x1, y1 }
    }

    fn written(buffer: &DepthBuffer, screen: &Screen) -> Vec<(usize, usize)> {
        let (cols, rows) = screen.cells();
        (0..rows)
            .flat_map(|y| (0..cols).map(move |x| (x, y)))
            .filter(|&c| buffer.cell_above(c, 0.0))
            .collect()
    }

    #[test]
    fn a_polygon_drawn_within_cells_writes_those_it_covers_and_no_other() {
        let screen = screen();
        let plane = Plane {
            normal: DVec3::Z,
            d: 0.0,
        };
        let mut scratch = Scratch::default();
        let (cols, rows) = screen.cells();
        let mut buffer = DepthBuffer::new(Kernel::detect());

        // A wall filling the view, drawn everywhere, writes every cell.
        buffer.reset(cols, rows);
        let wall = square(50.0);
        assert_eq!(
            screen.draw(&wall, &plane, 0.0, &mut buffer, &mut scratch),
            Drawn::Raised
        );
        assert_eq!(written(&buffer, &screen).len(), cols * rows);

        // Within a rectangle, it writes exactly that rectangle.
        buffer.reset(cols, rows);
        let within = rect(10, 5, 20, 15);
        let drawn = screen.draw_within(&wall, &plane, 0.0, within, &mut buffer, &mut scratch);
        assert_eq!(drawn, Drawn::Raised);
        let cells = written(&buffer, &screen);
        assert_eq!(cells.len(), 11 * 11);
        assert!(
            cells
                .iter()
                .all(|&(x, y)| (10..=20).contains(&x) && (5..=15).contains(&y))
        );

        // A wall farther away lies behind it.
        let far = wall.map(|p| p - DVec3::new(0.0, 0.0, 5.0));
        let farther = Plane {
            normal: DVec3::Z,
            d: 5.0,
        };
        let drawn = screen.draw_within(&far, &farther, 0.0, within, &mut buffer, &mut scratch);
        assert_eq!(drawn, Drawn::Behind);

        // A small square in the middle writes nothing within a corner
        // it does not reach, and says so.
        buffer.reset(cols, rows);
        let corner = rect(0, 0, 5, 5);
        let drawn =
            screen.draw_within(&square(0.5), &plane, 0.0, corner, &mut buffer, &mut scratch);
        assert_eq!(drawn, Drawn::Missed);
        assert!(written(&buffer, &screen).is_empty());

        // Within a rectangle it crosses, it writes only the overlap.
        let right = rect(32, 0, 63, 47);
        let drawn = screen.draw_within(&square(0.5), &plane, 0.0, right, &mut buffer, &mut scratch);
        assert_eq!(drawn, Drawn::Raised);
        let cells = written(&buffer, &screen);
        assert!(!cells.is_empty() && cells.iter().all(|&(x, _)| x >= 32));
        buffer.reset(cols, rows);
        screen.draw(&square(0.5), &plane, 0.0, &mut buffer, &mut scratch);
        assert!(written(&buffer, &screen).iter().any(|&(x, _)| x < 32));
    }

    #[test]
    fn a_tilted_polygon_drawn_within_cells_gives_them_what_a_whole_draw_does() {
        let screen = screen();
        // The plane z = 0.3 x: depth changes along every row. From the
        // eye (0, 0, 10) the ray through column centre X (in −1..1) meets
        // it at inverse depth (1 + 0.3 X tx) / 10.
        let normal = DVec3::new(-0.3, 0.0, 1.0).normalize();
        let plane = Plane { normal, d: 0.0 };
        let wall = square(50.0).map(|p| DVec3::new(p.x, p.y, 0.3 * p.x));
        let exact =
            |x: usize| (1.0 + 0.3 * (2.0 * (x as f64 + 0.5) / 64.0 - 1.0) * screen.tx) / 10.0;
        let (cols, rows) = screen.cells();
        let mut scratch = Scratch::default();
        let mut whole = DepthBuffer::new(Kernel::detect());
        whole.reset(cols, rows);
        screen.draw(&wall, &plane, 0.0, &mut whole, &mut scratch);
        let mut part = DepthBuffer::new(Kernel::detect());
        part.reset(cols, rows);
        screen.draw_within(
            &wall,
            &plane,
            0.0,
            rect(13, 7, 41, 30),
            &mut part,
            &mut scratch,
        );
        for y in 0..rows {
            for x in 0..cols {
                let (w, w_whole) = (part.cell((x, y)), whole.cell((x, y)));
                if (13..=41).contains(&x) && (7..=30).contains(&y) {
                    // Written, never nearer than the plane, and what the
                    // whole draw wrote but for rounding.
                    assert!(w > 0.0 && (w as f64) <= exact(x), "cell ({x}, {y}): {w}");
                    assert!(
                        (w - w_whole).abs() <= 4.0 * f32::EPSILON * w_whole,
                        "cell ({x}, {y})"
                    );
                } else {
                    assert_eq!(w, 0.0, "cell ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn a_cell_size_reads_as_one_side_or_across_x_down_and_ranges_side_by_side() {
        let size = |across, down| CellSize { across, down };
        assert_eq!("2".parse(), Ok(size(2, 2)));
        assert_eq!("2x3".parse(), Ok(size(2, 3)));
        for text in ["", "x", "2x", "x3", "2x3x4", "2.5", "-1"] {
            assert!(text.parse::<CellSize>().is_err(), "{text:?}");
        }
        for s in [size(2, 2), size(2, 3), size(8, 1)] {
            assert_eq!(s.to_string().parse(), Ok(s));
        }
        assert_eq!(size(3, 3).to_string(), "3");
        // Within 1..=8 only where both sides are.
        let (min, max) = (CellSize::square(1), CellSize::square(8));
        for (s, within) in [
            (size(2, 3), true),
            (size(8, 8), true),
            (size(2, 9), false),
            (size(0, 2), false),
        ] {
            assert_eq!(min <= s && s <= max, within, "{s}");
        }
        assert_eq!(size(2, 3).partial_cmp(&size(3, 2)), None);
    }

    #[test]
    fn cells_of_any_shape_get_only_what_every_pixel_centre_in_them_sees() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
        let mut scratch = Scratch::default();
        let mut buffer = DepthBuffer::new(Kernel::detect());
        // Square and oblong cells, some not dividing the 64 × 48 view
        // across (5), down (5, 7) or both.
        for (across, down) in [(1, 1), (2, 2), (2, 3), (3, 2), (1, 5), (5, 7)] {
            let cells = CellSize { across, down };
            let screen = screen_of_cells(cells);
            let (cols, rows) = screen.cells();
            for _ in 0..40 {
                // A quadrilateral on a tilted plane below the eye, convex
                // (corners at increasing angles on an ellipse).
                let normal = DVec3::new(
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.6..0.6),
                    1.0,
                )
                .normalize();
                let centre = DVec3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-4.0..2.0),
                );
                let plane = Plane::from_point_normal(centre, normal).expect("a plane");
                let (u, v) = (
                    normal.any_orthonormal_vector(),
                    normal.cross(normal.any_orthonormal_vector()),
                );
                let start = rng.random_range(0.0..std::f64::consts::TAU);
                let (ru, rv) = (rng.random_range(1.0..5.0), rng.random_range(1.0..5.0));
                let quad: [DVec3; 4] = std::array::from_fn(|k| {
                    let a = start
                        + k as f64 * std::f64::consts::FRAC_PI_2
                        + rng.random_range(-0.5..0.5);
                    centre + u * (ru * a.cos()) + v * (rv * a.sin())
                });
                buffer.reset(cols, rows);
                screen.draw(&quad, &plane, 0.0, &mut buffer, &mut scratch);
                // Per pixel centre: the inverse depth of the polygon there,
                // and whether it lies inside by `margin` (scene units).
                let seen = |x: usize, y: usize, margin: f64| {
                    let (sx, sy) = (
                        2.0 * (x as f64 + 0.5) / 64.0 - 1.0,
                        1.0 - 2.0 * (y as f64 + 0.5) / 48.0,
                    );
                    let dir = DVec3::new(sx * screen.tx, sy * screen.ty, -1.0);
                    let z = -plane.signed_distance(screen.eye) / plane.normal.dot(dir);
                    let p = screen.eye + dir * z;
                    let inside = (0..4).all(|k| {
                        let (a, b) = (quad[k], quad[(k + 1) % 4]);
                        (b - a).cross(p - a).dot(normal) / (b - a).length() > margin
                    });
                    (1.0 / z, inside)
                };
                for cy in 0..rows {
                    for cx in 0..cols {
                        let w = buffer.cell((cx, cy)) as f64;
                        let centres: Vec<(usize, usize)> = (cy * cells.down
                            ..((cy + 1) * cells.down).min(48))
                            .flat_map(|y| {
                                (cx * cells.across..((cx + 1) * cells.across).min(64))
                                    .map(move |x| (x, y))
                            })
                            .collect();
                        // A cell reaching past the view's edge is only
                        // checked for what it must not hold: it counts
                        // centres beyond the edge, and may hold less.
                        let whole = centres.len() == cells.across * cells.down;
                        if w > 0.0 {
                            // Every centre covered, none nearer than what
                            // the cell holds, and the farthest of them
                            // held but for the margins.
                            let mut farthest = f64::INFINITY;
                            for &(x, y) in &centres {
                                let (exact, inside) = seen(x, y, 0.0);
                                assert!(
                                    inside,
                                    "{cells:?}: cell ({cx}, {cy}) written, pixel ({x}, {y}) uncovered"
                                );
                                assert!(
                                    w <= exact,
                                    "{cells:?}: cell ({cx}, {cy}) holds {w} > {exact} at ({x}, {y})"
                                );
                                farthest = farthest.min(exact);
                            }
                            assert!(
                                !whole || w >= farthest * (1.0 - 1e-5),
                                "{cells:?}: cell ({cx}, {cy}) holds {w}, its farthest centre {farthest}"
                            );
                        } else if whole {
                            // Covered well inside at every centre: written.
                            assert!(
                                !centres.iter().all(|&(x, y)| seen(x, y, 0.05).1),
                                "{cells:?}: cell ({cx}, {cy}) covered but not written"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_box_footprint_holds_every_cell_whose_pixel_centres_see_it() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(29);
        for (across, down) in [(1, 1), (2, 2), (2, 3), (3, 2), (1, 5), (5, 7)] {
            let cells = CellSize { across, down };
            let screen = screen_of_cells(cells);
            for _ in 0..60 {
                let c = DVec3::new(
                    rng.random_range(-4.0..4.0),
                    rng.random_range(-4.0..4.0),
                    rng.random_range(-6.0..8.0),
                );
                let h = DVec3::new(
                    rng.random_range(0.01..2.0),
                    rng.random_range(0.01..2.0),
                    rng.random_range(0.01..2.0),
                );
                let b = Aabb::new((c - h).as_vec3(), (c + h).as_vec3());
                let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
                let footprint = screen.footprint(&b);
                for y in 0..48 {
                    for x in 0..64 {
                        let (sx, sy) = (
                            2.0 * (x as f64 + 0.5) / 64.0 - 1.0,
                            1.0 - 2.0 * (y as f64 + 0.5) / 48.0,
                        );
                        let dir = DVec3::new(sx * screen.tx, sy * screen.ty, -1.0);
                        // Where the ray from the eye enters the box (slabs).
                        let (mut enter, mut leave) = (0.0f64, f64::INFINITY);
                        for a in 0..3 {
                            let (t0, t1) = (
                                (lo[a] - screen.eye[a]) / dir[a],
                                (hi[a] - screen.eye[a]) / dir[a],
                            );
                            enter = enter.max(t0.min(t1));
                            leave = leave.min(t0.max(t1));
                        }
                        if enter > leave || enter < screen.near {
                            continue; // missed, or met only nearer than the near plane
                        }
                        let cell = (x / cells.across, y / cells.down);
                        match footprint {
                            Footprint::Near => {}
                            Footprint::Nothing => panic!("{cells:?}: pixel ({x}, {y}) sees {b:?}"),
                            Footprint::Cells(r, w) => {
                                assert!(
                                    (r.x0..=r.x1).contains(&cell.0)
                                        && (r.y0..=r.y1).contains(&cell.1),
                                    "{cells:?}: pixel ({x}, {y}) sees {b:?} from cell {cell:?}, outside {r:?}"
                                );
                                assert!(
                                    w as f64 >= 1.0 / enter,
                                    "{cells:?}: {b:?} is nearer than {w} at pixel ({x}, {y})"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
