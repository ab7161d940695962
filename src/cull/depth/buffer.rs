//! The depth buffer: one value per cell (a cell is a rectangle of
//! viewport pixels), the *inverse* depth `1/z` of the nearest occluder known to
//! cover every pixel centre of the cell, and per tile of 8×8 cells the
//! least of them (the farthest). Zero means nothing covers the cell, and
//! stands for a depth at infinity, so a cleared buffer hides nothing.
//!
//! Inverse depth because it is affine in screen position over a plane, so
//! a polygon's values along a row are `base + k·step`; and because zero is
//! a natural "nothing here". Every value written is a lower bound of the
//! real inverse depth (the occluder is at least that near); a box is
//! hidden when its own upper bound is below every cell it covers.

use super::kernel::{Kernel, Raise, ScalarRaise, Span};

/// Cells per tile side.
pub const TILE: usize = 8;

/// Cells `x0..=x1` × rows `y0..=y1` (inclusive, in cells).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellRect {
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
}

/// A depth buffer of inverse depths; see the module docs.
#[derive(Clone, Debug)]
pub struct DepthBuffer {
    cols: usize,
    rows: usize,
    /// Row length in memory: `cols` rounded up to whole tiles.
    stride: usize,
    /// Tiles per row of tiles: `stride / TILE`, kept so that finding a
    /// tile costs no division (one per raised row, otherwise).
    tiles_across: usize,
    cells: Vec<f32>,
    /// Per row, the columns written since the last clear (`lo..hi`), so a
    /// clear touches only those. (A tile's least value reads its cells
    /// even where unwritten: checking the rows first cost more.)
    written: Vec<(u32, u32)>,
    /// Per tile, the least value of its cells where not stale, and at
    /// most it where stale: cells only rise until a clear zeroes both.
    tiles: Vec<f32>,
    /// Per tile (a bit each, by tile index), whether a cell changed since
    /// its least value was taken: it is taken again when a test needs it,
    /// so drawing and testing can interleave and only tested tiles cost a
    /// pass. Bits, so that a raised span marks its tiles in a word or two.
    stale: Vec<u64>,
    kernel: Kernel,
}

impl DepthBuffer {
    /// An empty buffer; [`DepthBuffer::reset`] sizes it.
    pub fn new(kernel: Kernel) -> DepthBuffer {
        DepthBuffer {
            cols: 0,
            rows: 0,
            stride: 0,
            tiles_across: 0,
            cells: Vec::new(),
            written: Vec::new(),
            tiles: Vec::new(),
            stale: Vec::new(),
            kernel,
        }
    }

    /// The loops it runs.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Runs its loops with `kernel` from now on.
    pub fn set_kernel(&mut self, kernel: Kernel) {
        self.kernel = kernel;
    }

    /// Clears the buffer to `cols × rows` cells of zero.
    pub fn reset(&mut self, cols: usize, rows: usize) {
        if (cols, rows) != (self.cols, self.rows) {
            self.cols = cols;
            self.rows = rows;
            self.stride = cols.div_ceil(TILE) * TILE;
            self.tiles_across = self.stride / TILE;
            self.cells = vec![0.0; self.stride * rows];
            self.written = vec![(u32::MAX, 0); rows];
            self.tiles = vec![0.0; self.tiles_across * rows.div_ceil(TILE)];
            self.stale = vec![0; self.tiles.len().div_ceil(64)];
            return;
        }
        self.tiles.fill(0.0);
        self.stale.fill(0);
        for (y, w) in self.written.iter_mut().enumerate() {
            if w.0 < w.1 {
                self.cells[y * self.stride + w.0 as usize..y * self.stride + w.1 as usize]
                    .fill(0.0);
            }
            *w = (u32::MAX, 0);
        }
    }

    /// Raises cells `x0..=x1` of row `y` to `base + (x − x0)·step` where
    /// that is larger.
    pub fn raise_span(&mut self, y: usize, x0: usize, x1: usize, base: f32, step: f32) {
        self.raise_rows(y, &[(x0 as i32, x1 as i32)], |_, _| base, step);
    }

    /// Raises row `first_row + k`, for each `spans[k] = (lo, hi)` with
    /// `lo ≤ hi` (whole numbers within the row), from column `lo` to `hi`
    /// to `base(k, lo) + (x − lo)·step` where that is larger: a polygon's
    /// rows in one call, its loop compiled once per kernel with the
    /// kernel's raise inside it rather than called per row. Whether any
    /// cell rose: the rows are first compared, without writing, up to the
    /// first that would raise a cell, and only the rows from there are
    /// raised, so that a polygon behind nearer ones (about half of those
    /// drawn on a dense part, nearest first) costs a look, not its writes.
    pub fn raise_rows(
        &mut self,
        first_row: usize,
        spans: &[Span],
        base: impl Fn(usize, i32) -> f32,
        step: f32,
    ) -> bool {
        match self.kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx2` is only made on a CPU that has AVX2.
            Kernel::Avx2 => unsafe { self.raise_rows_avx2(first_row, spans, base, step) },
            // SAFETY: plain Rust runs anywhere.
            _ => unsafe { self.raise_rows_with::<ScalarRaise>(first_row, spans, base, step) },
        }
    }

    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn raise_rows_avx2(
        &mut self,
        first_row: usize,
        spans: &[Span],
        base: impl Fn(usize, i32) -> f32,
        step: f32,
    ) -> bool {
        // SAFETY: the caller's.
        unsafe { self.raise_rows_with::<super::kernel::Avx2Raise>(first_row, spans, base, step) }
    }

    /// # Safety
    /// The CPU must have `R`'s instructions.
    #[inline(always)]
    unsafe fn raise_rows_with<R: Raise>(
        &mut self,
        first_row: usize,
        spans: &[Span],
        base: impl Fn(usize, i32) -> f32,
        step: f32,
    ) -> bool {
        let rises = spans.iter().enumerate().position(|(k, &(lo, hi))| {
            let at = (first_row + k) * self.stride;
            lo <= hi && {
                let cells = &self.cells[at + lo as usize..=at + hi as usize];
                // SAFETY: the caller's.
                unsafe { R::rises(cells, base(k, lo), step) }
            }
        });
        let Some(from) = rises else {
            return false;
        };
        for (k, &(lo, hi)) in spans.iter().enumerate().skip(from) {
            if lo > hi {
                continue;
            }
            let (y, x0, x1) = (first_row + k, lo as usize, hi as usize);
            debug_assert!(x0 <= x1 && x1 < self.cols && y < self.rows);
            let at = y * self.stride;
            // SAFETY: the caller's.
            unsafe { R::raise(&mut self.cells[at + x0..at + x1 + 1], base(k, lo), step) };
            let w = &mut self.written[y];
            *w = (w.0.min(x0 as u32), w.1.max(x1 as u32 + 1));
            let first = (y / TILE) * self.tiles_across;
            self.mark_stale(first + x0 / TILE, first + x1 / TILE);
        }
        true
    }

    /// Marks tiles `a..=b` (by index) stale.
    #[inline(always)]
    fn mark_stale(&mut self, a: usize, b: usize) {
        let ((wa, from), (wb, upto)) = bit_range(a, b);
        if wa == wb {
            self.stale[wa] |= from & upto;
        } else {
            self.stale[wa] |= from;
            self.stale[wa + 1..wb].fill(!0);
            self.stale[wb] |= upto;
        }
    }

    /// The least value of tile `(tx, ty)`, taken again if stale.
    fn tile(&mut self, tx: usize, ty: usize) -> f32 {
        let t = ty * self.tiles_across + tx;
        let bit = 1u64 << (t % 64);
        if self.stale[t / 64] & bit != 0 {
            self.stale[t / 64] &= !bit;
            self.tiles[t] = self.least(tx, ty);
        }
        self.tiles[t]
    }

    /// The least value of tile `(tx, ty)`'s cells. Out of line: the
    /// hidden-test's loop stays small without it.
    #[inline(never)]
    fn least(&self, tx: usize, ty: usize) -> f32 {
        let (r0, r1) = (ty * TILE, ((ty + 1) * TILE).min(self.rows));
        let (c0, c1) = (tx * TILE, ((tx + 1) * TILE).min(self.cols));
        self.kernel.least(
            &self.cells[r0 * self.stride + c0..],
            self.stride,
            c1 - c0,
            r1 - r0,
        )
    }

    /// Whether every cell of `rect` holds a value above `w` (an occluder
    /// nearer than inverse depth `w` covers all of it).
    pub fn hides(&mut self, rect: CellRect, w: f32) -> bool {
        self.open_tile(rect, w).is_none()
    }

    /// A cell of `rect` (column, row) that does not hold a value above
    /// `w`, if there is one: where an occluder must still be drawn for
    /// `rect` to be hidden at `w`.
    pub fn open_cell(&mut self, rect: CellRect, w: f32) -> Option<(usize, usize)> {
        let (tx, ty) = self.open_tile(rect, w)?;
        let (x0, x1) = (rect.x0.max(tx * TILE), rect.x1.min(tx * TILE + TILE - 1));
        let (y0, y1) = (rect.y0.max(ty * TILE), rect.y1.min(ty * TILE + TILE - 1));
        for y in y0..=y1 {
            for x in x0..=x1 {
                if !self.cell_above((x, y), w) {
                    return Some((x, y));
                }
            }
        }
        Some((x0, y0))
    }

    /// The value of cell `(x, y)`: the least inverse depth known there.
    pub fn cell(&self, (x, y): (usize, usize)) -> f32 {
        self.cells[y * self.stride + x]
    }

    /// Whether cell `(x, y)` holds a value above `w`.
    pub fn cell_above(&self, (x, y): (usize, usize), w: f32) -> bool {
        self.cells[y * self.stride + x] > w
    }

    /// The first tile (column, row) with a cell of `rect` that does not
    /// hold a value above `w`.
    fn open_tile(&mut self, rect: CellRect, w: f32) -> Option<(usize, usize)> {
        // Plain loops: these run for every box and polygon tested, over a
        // few tiles each, where an iterator's set-up costs as much as the
        // tile's test.
        let (tx0, tx1, ty1) = (rect.x0 / TILE, rect.x1 / TILE, rect.y1 / TILE);
        let mut ty = rect.y0 / TILE;
        while ty <= ty1 {
            let at = ty * self.tiles_across;
            // A tile's kept value, stale or not, is at most its least
            // cell (cells only rise until a clear, which zeroes the
            // tiles): a row of tiles all above `w` is hidden as it is,
            // compared at once without a branch per tile (a NaN `w`
            // fails).
            if self.tiles[at + tx0..at + tx1 + 1]
                .iter()
                .fold(true, |all, &t| all & (t > w))
            {
                ty += 1;
                continue;
            }
            let mut tx = tx0;
            while tx <= tx1 {
                // (A NaN `w` is hidden nowhere.)
                let hidden = self.tiles[at + tx] > w
                    || self.tile(tx, ty) > w
                    || self.cells_hide(rect, tx, ty, w);
                if !hidden {
                    return Some((tx, ty));
                }
                tx += 1;
            }
            ty += 1;
        }
        None
    }

    /// Whether the cells `rect` has in tile `(tx, ty)` all hold a value
    /// above `w`, for a tile whose farthest cell does not.
    #[inline(never)]
    fn cells_hide(&self, rect: CellRect, tx: usize, ty: usize, w: f32) -> bool {
        let (left, top) = (tx * TILE, ty * TILE);
        let (right, bottom) = (
            (left + TILE - 1).min(self.cols - 1),
            (top + TILE - 1).min(self.rows - 1),
        );
        let (x0, x1) = (rect.x0.max(left), rect.x1.min(right));
        let (y0, y1) = (rect.y0.max(top), rect.y1.min(bottom));
        if x0 == left && x1 == right && y0 == top && y1 == bottom {
            return false; // all of the tile: its farthest cell is in it
        }
        // Rows start at whole tiles (`stride` is a multiple of TILE), so
        // each of the tile's rows has TILE cells in memory to read.
        let at = y0 * self.stride + left;
        let cells = &self.cells[at..at + (y1 - y0) * self.stride + TILE];
        self.kernel
            .above(cells, self.stride, y1 - y0 + 1, (x0 - left, x1 - left), w)
    }

    /// Bytes held on the heap.
    pub fn heap_bytes(&self) -> usize {
        (self.cells.capacity() + self.tiles.capacity()) * 4
            + (self.stale.capacity() + self.written.capacity()) * 8
    }
}

/// Bits `a..=b` of a bit set in words: `a`'s word and the mask of the
/// bits from `a` on in it, `b`'s word and the mask of the bits up to `b`.
fn bit_range(a: usize, b: usize) -> ((usize, u64), (usize, u64)) {
    (
        (a / 64, !0u64 << (a % 64)),
        (b / 64, !0u64 >> (63 - b % 64)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x0: usize, y0: usize, x1: usize, y1: usize) -> CellRect {
        CellRect { x0, y0, x1, y1 }
    }

    #[test]
    fn a_span_hides_what_lies_behind_it_and_nothing_else() {
        for kernel in [Kernel::Scalar, Kernel::detect()] {
            let mut b = DepthBuffer::new(kernel);
            b.reset(20, 11);
            for y in 2..=9 {
                b.raise_span(y, 3, 17, 0.5, 0.0);
            }
            assert!(b.hides(rect(3, 2, 17, 9), 0.4));
            assert!(!b.hides(rect(3, 2, 17, 9), 0.5), "a tie is not hidden");
            assert!(!b.hides(rect(2, 2, 17, 9), 0.4), "one column uncovered");
            assert!(!b.hides(rect(3, 2, 17, 10), 0.4), "one row uncovered");
            // A clear forgets it.
            b.reset(20, 11);
            assert!(!b.hides(rect(5, 5, 5, 5), 0.0001));
        }
    }

    #[test]
    fn rows_behind_what_is_drawn_are_left_as_they_are() {
        for kernel in [Kernel::Scalar, Kernel::detect()] {
            let mut b = DepthBuffer::new(kernel);
            b.reset(30, 12);
            for y in 0..12 {
                b.raise_span(y, 0, 29, 1.0, 0.0);
            }
            let before = b.cells.clone();
            // Behind everywhere, ties included: nothing rises, no cell is
            // written.
            let spans = [(1, 0), (2, 10), (0, 29), (5, 5)];
            assert!(!b.raise_rows(3, &spans, |_, _| 1.0, -0.01));
            assert_eq!(b.cells, before);
            // In front from column 17 of row 5 on (0.5 + 17·0.03 > 1):
            // only those cells change.
            assert!(b.raise_rows(3, &spans, |_, lo| 0.5 + lo as f32 * 0.03, 0.03));
            let at = |x: usize, y: usize| b.cells[y * b.stride + x];
            for y in 0..12 {
                for x in 0..30 {
                    let rose = y == 5 && x >= 17;
                    assert_eq!(at(x, y) > 1.0, rose, "cell ({x}, {y})");
                }
            }
            assert!(!b.hides(rect(29, 5, 29, 5), at(29, 5)));
            assert!(b.hides(rect(29, 5, 29, 5), 1.0), "its tile was renewed");
        }
    }

    #[test]
    fn a_raised_span_renews_every_tile_it_crosses() {
        // 75 tiles a row: a span over tiles 60..=68 crosses a word of the
        // stale bits; a tile not marked would keep its old least value.
        for kernel in [Kernel::Scalar, Kernel::detect()] {
            let mut b = DepthBuffer::new(kernel);
            b.reset(600, 8);
            for y in 0..8 {
                b.raise_span(y, 0, 599, 1.0, 0.0);
            }
            assert!(b.hides(rect(0, 0, 599, 7), 0.5));
            for y in 0..8 {
                b.raise_span(y, 480, 551, 3.0, 0.0);
            }
            assert!(b.hides(rect(480, 0, 551, 7), 2.0));
            assert!(!b.hides(rect(472, 0, 551, 7), 2.0));
            assert!(!b.hides(rect(480, 0, 559, 7), 2.0));
        }
    }

    #[test]
    fn tiles_hold_their_farthest_cell() {
        let mut b = DepthBuffer::new(Kernel::detect());
        b.reset(16, 8);
        for y in 0..8 {
            b.raise_span(y, 0, 15, 1.0, 0.0);
        }
        b.raise_span(3, 4, 4, 2.0, 0.0);
        assert_eq!((b.tile(0, 0), b.tile(1, 0)), (1.0, 1.0));
        assert!(b.hides(rect(0, 0, 15, 7), 0.99));
        // A ramp: the least of the tile is its first cell.
        b.reset(16, 8);
        for y in 0..8 {
            b.raise_span(y, 0, 15, 1.0, 0.25);
        }
        assert_eq!((b.tile(0, 0), b.tile(1, 0)), (1.0, 3.0));
        assert!(b.hides(rect(8, 0, 15, 7), 2.9));
        assert!(!b.hides(rect(7, 0, 15, 7), 2.9));
    }

    #[test]
    fn an_open_cell_is_one_the_rect_is_not_hidden_at() {
        // Random spans over 3×2 tiles; every rect either hides or names a
        // cell of its own whose value does not lie above `w`.
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = |n: usize| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % n as u64) as usize
        };
        for kernel in [Kernel::Scalar, Kernel::detect()] {
            let mut b = DepthBuffer::new(kernel);
            for _ in 0..200 {
                b.reset(21, 13);
                for _ in 0..next(30) {
                    let (x0, y) = (next(21), next(13));
                    let x1 = (x0 + next(21)).min(20);
                    b.raise_span(y, x0, x1, next(4) as f32, 0.0);
                }
                let (x0, y0) = (next(21), next(13));
                let r = rect(x0, y0, (x0 + next(21)).min(20), (y0 + next(13)).min(12));
                let w = next(4) as f32 - 0.5;
                match b.open_cell(r, w) {
                    None => assert!(b.hides(r, w)),
                    Some((x, y)) => {
                        assert!(!b.hides(r, w));
                        assert!((r.x0..=r.x1).contains(&x) && (r.y0..=r.y1).contains(&y));
                        assert!(
                            !b.cell_above((x, y), w),
                            "{r:?} at {w}: ({x}, {y}) is covered"
                        );
                    }
                }
            }
        }
    }
}
