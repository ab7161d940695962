//! The occlusion horizon (Downs et al. §3.4, Fig. 3): a piecewise-constant
//! height per screen column, with the lowest height of every block of
//! columns.
//!
//! The paper keeps a balanced binary tree split at the masks' own x values;
//! here the window of the horizontal view is cut into a fixed number of
//! columns, grouped in blocks of [`BLOCK`]. A test of a frame reads the
//! lowest height of each block it covers wholly and the columns of the (at
//! most two) blocks it covers in part; a mask raises a wholly covered block
//! by a floor kept for the block, and the columns of a partly covered one.
//! That is the tree's answer with its logarithmic walk replaced by a few
//! straight loops over contiguous memory (the horizon of a street view
//! takes hundreds of masks and thousands of tests a frame).
//!
//! Rounding to columns is conservative in both directions: a mask raises
//! only the columns it covers *wholly*, and a test looks at every column
//! its frame *touches*.

use crate::geom::{ceil_i64, floor_i64, greater, lesser};

/// Columns per block.
const BLOCK: usize = 16;

/// Heights over `[x0, x1)` of the horizontal view plane, in `columns` columns.
#[derive(Clone, Debug)]
pub struct Horizon {
    x0: f64,
    /// Columns per unit of x.
    scale: f64,
    columns: usize,
    /// Per column, the highest mask raised over it alone; a column's height
    /// is the larger of this and its block's floor.
    heights: Vec<f64>,
    /// Per block, the highest mask raised over the whole block.
    floors: Vec<f64>,
    /// Per block, the lowest height of its columns.
    lowest: Vec<f64>,
}

/// The part of a frame above the horizon: columns `first..=last` (in x,
/// `[x_lo, x_hi]`) and the lowest horizon height among them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Opening {
    /// Left edge of the first open column.
    pub x_lo: f64,
    /// Right edge of the last open column.
    pub x_hi: f64,
    /// The lowest horizon height over the open columns (−∞ where nothing occludes).
    pub floor: f64,
}

/// Relative slack against rounding: masks shrink by it, frames grow by it.
const SLACK: f64 = 1e-12;

fn grow(v: f64) -> f64 {
    v + SLACK * (1.0 + v.abs())
}

fn shrink(v: f64) -> f64 {
    v - SLACK * (1.0 + v.abs())
}

impl Horizon {
    /// Sets the number of columns, keeping the allocation when it is large
    /// enough; the heights are left for [`Horizon::reset`] to empty.
    pub fn set_columns(&mut self, columns: usize) {
        let blocks = columns.div_ceil(BLOCK);
        self.columns = columns;
        self.heights.resize(columns, f64::NEG_INFINITY);
        self.floors.resize(blocks, f64::NEG_INFINITY);
        self.lowest.resize(blocks, f64::NEG_INFINITY);
    }

    /// An empty horizon (−∞ everywhere) over `[x0, x1)` in `columns` columns.
    pub fn new(columns: usize) -> Self {
        let blocks = columns.div_ceil(BLOCK);
        let mut h = Horizon {
            x0: 0.0,
            scale: 1.0,
            columns,
            heights: vec![f64::NEG_INFINITY; columns],
            floors: vec![f64::NEG_INFINITY; blocks],
            lowest: vec![f64::NEG_INFINITY; blocks],
        };
        h.reset(0.0, 1.0);
        h
    }

    /// Empties the horizon and sets its window to `[x0, x1)`, keeping the
    /// allocation.
    pub fn reset(&mut self, x0: f64, x1: f64) {
        self.x0 = x0;
        self.scale = self.columns as f64 / (x1 - x0);
        self.heights.fill(f64::NEG_INFINITY);
        self.floors.fill(f64::NEG_INFINITY);
        self.lowest.fill(f64::NEG_INFINITY);
    }

    fn column_at(&self, x: f64) -> f64 {
        (x - self.x0) * self.scale
    }

    /// Adds a rectangular mask (§3.4, Fig. 4c): every column lying wholly
    /// inside `[x_lo, x_hi]` is raised to at least `height`.
    pub fn insert(&mut self, x_lo: f64, x_hi: f64, height: f64) {
        let (lo, hi) = (self.column_at(grow(x_lo)), self.column_at(shrink(x_hi)));
        if lo.is_nan() || hi.is_nan() {
            return;
        }
        let (lo, hi) = (ceil_i64(lo), floor_i64(hi).saturating_sub(1));
        if lo > hi || hi < 0 || lo >= self.columns as i64 {
            return;
        }
        let (lo, hi) = (lo.max(0) as usize, hi.min(self.columns as i64 - 1) as usize);
        let height = shrink(height);
        for b in lo / BLOCK..=hi / BLOCK {
            if height <= self.lowest[b] {
                continue; // every column of the block is already higher
            }
            let (first, last) = (b * BLOCK, ((b + 1) * BLOCK).min(self.columns) - 1);
            if lo <= first && last <= hi {
                self.floors[b] = height;
                self.lowest[b] = height;
                continue;
            }
            let floor = self.floors[b];
            let mut lowest = f64::INFINITY;
            for c in first..=last {
                if (lo..=hi).contains(&c) {
                    self.heights[c] = greater(self.heights[c], height);
                }
                lowest = lesser(lowest, greater(self.heights[c], floor));
            }
            self.lowest[b] = lowest;
        }
    }

    /// The columns a frame `[x_lo, x_hi]` touches, clamped to the window.
    fn touched(&self, x_lo: f64, x_hi: f64) -> Option<(usize, usize)> {
        let (lo, hi) = (self.column_at(shrink(x_lo)), self.column_at(grow(x_hi)));
        if lo.is_nan() || hi.is_nan() {
            return None;
        }
        let (lo, hi) = (floor_i64(lo), floor_i64(hi));
        if lo > hi || hi < 0 || lo >= self.columns as i64 {
            return None;
        }
        Some((lo.max(0) as usize, hi.min(self.columns as i64 - 1) as usize))
    }

    /// The height of column `c`.
    fn height(&self, c: usize) -> f64 {
        self.heights[c].max(self.floors[c / BLOCK])
    }

    /// Whether a frame `[x_lo, x_hi]` whose top is `top` lies wholly below
    /// the horizon (§3.5): every column it touches is higher than its top.
    /// A frame outside the window is not hidden.
    pub fn hides(&self, x_lo: f64, x_hi: f64, top: f64) -> bool {
        let Some((lo, hi)) = self.touched(x_lo, x_hi) else {
            return false;
        };
        let top = grow(top);
        for b in lo / BLOCK..=hi / BLOCK {
            if self.lowest[b] > top {
                continue;
            }
            // The block's lowest column is not above the top: a block
            // covered wholly is open; one covered in part, only if that
            // column is among those covered.
            let (first, last) = (b * BLOCK, ((b + 1) * BLOCK).min(self.columns) - 1);
            if lo <= first && last <= hi {
                return false;
            }
            let floor = self.floors[b];
            if self.heights[first.max(lo)..=last.min(hi)]
                .iter()
                .any(|&h| greater(h, floor) <= top)
            {
                return false;
            }
        }
        true
    }

    /// The part of a frame `[x_lo, x_hi]` (top `top`) above the horizon
    /// (§3.6), or `None` when it is hidden or outside the window.
    pub fn opening(&self, x_lo: f64, x_hi: f64, top: f64) -> Option<Opening> {
        let (lo, hi) = self.touched(x_lo, x_hi)?;
        let top = grow(top);
        let open = |c: &usize| self.height(*c) <= top;
        let first = (lo..=hi).find(open)?;
        let last = (lo..=hi).rev().find(open)?;
        let floor = (lo..=hi).map(|c| self.height(c)).fold(f64::INFINITY, f64::min);
        Some(Opening {
            x_lo: self.x0 + first as f64 / self.scale,
            x_hi: self.x0 + (last + 1) as f64 / self.scale,
            floor,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force over columns, to check the tree against.
    fn columns(h: &Horizon) -> Vec<f64> {
        (0..h.columns)
            .map(|c| {
                let x = h.x0 + (c as f64 + 0.5) / h.scale;
                // The height of a column is what a one-column frame sees.
                let (mut lo, mut hi) = (-1e9, 1e9);
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    if h.hides(x, x, mid) {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                lo
            })
            .collect()
    }

    #[test]
    fn a_mask_raises_only_the_columns_it_covers_wholly() {
        let mut h = Horizon::new(10);
        h.reset(0.0, 10.0);
        h.insert(2.5, 6.001, 3.0);
        let c = columns(&h);
        // Columns 3, 4, 5 lie inside [2.5, 6.001]; 2 and 6 only partly.
        // (A mask ending exactly on a column edge loses that column to the
        // rounding slack: the safe side.)
        for (i, v) in c.iter().enumerate() {
            if (3..=5).contains(&i) {
                assert!((v - 3.0).abs() < 1e-6, "column {i}: {v}");
            } else {
                assert!(*v < -1e8, "column {i}: {v}");
            }
        }
    }

    #[test]
    fn a_frame_is_hidden_only_when_every_touched_column_is_higher() {
        let mut h = Horizon::new(8);
        h.reset(-4.0, 4.0);
        h.insert(-4.01, 0.01, 1.0);
        h.insert(-0.01, 4.01, 2.0);
        assert!(h.hides(-3.5, 3.5, 0.5));
        assert!(!h.hides(-3.5, 3.5, 1.5));
        assert!(h.hides(0.5, 3.5, 1.5));
        // Touching the column left of 0 (height 1) is enough to be seen.
        assert!(!h.hides(-0.01, 3.5, 1.5));
        // Exactly at the height is not hidden: the mask must be higher.
        assert!(!h.hides(0.5, 3.5, 2.0));
    }

    #[test]
    fn frames_outside_the_window_are_not_hidden() {
        let mut h = Horizon::new(4);
        h.reset(0.0, 4.0);
        h.insert(-0.1, 4.1, 10.0);
        assert!(!h.hides(5.0, 6.0, 0.0));
        assert!(!h.hides(-2.0, -1.0, 0.0));
        // Partly inside: only the inside part is looked at (the caller
        // decides whether the outside part matters).
        assert!(h.hides(3.0, 6.0, 0.0));
    }

    #[test]
    fn lower_masks_do_not_lower_and_reset_empties() {
        let mut h = Horizon::new(16);
        h.reset(0.0, 16.0);
        h.insert(-1.0, 17.0, 5.0);
        h.insert(4.0, 8.0, 1.0);
        assert!(h.hides(0.0, 16.0, 4.9));
        h.reset(0.0, 16.0);
        assert!(!h.hides(0.0, 16.0, -1e300));
    }

    #[test]
    fn the_opening_spans_the_open_columns_and_their_floor() {
        let mut h = Horizon::new(10);
        h.reset(0.0, 10.0);
        h.insert(-0.01, 4.01, 5.0);
        h.insert(3.99, 7.01, 2.0);
        h.insert(6.99, 10.01, 5.0);
        let o = h.opening(1.0, 9.0, 3.0).expect("columns 4..7 are open");
        assert_eq!((o.x_lo, o.x_hi), (4.0, 7.0));
        assert!((o.floor - 2.0).abs() < 1e-9);
        assert_eq!(h.opening(1.0, 3.5, 3.0), None);
    }

    #[test]
    fn random_masks_match_brute_force() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let n = 37;
        let mut h = Horizon::new(n);
        h.reset(-1.0, 1.0);
        let mut brute = vec![f64::NEG_INFINITY; n];
        for _ in 0..300 {
            let a: f64 = rng.random_range(-1.2..1.2);
            let b: f64 = rng.random_range(-1.2..1.2);
            let (lo, hi) = (a.min(b), a.max(b));
            let y: f64 = rng.random_range(-5.0..5.0);
            h.insert(lo, hi, y);
            for (c, v) in brute.iter_mut().enumerate() {
                let (cl, cr) = (
                    -1.0 + c as f64 * 2.0 / n as f64,
                    -1.0 + (c + 1) as f64 * 2.0 / n as f64,
                );
                if cl >= lo + 1e-9 && cr <= hi - 1e-9 {
                    *v = v.max(y);
                }
            }
            let a: f64 = rng.random_range(-1.0..1.0);
            let b: f64 = rng.random_range(-1.0..1.0);
            let (lo, hi) = (a.min(b), a.max(b));
            let top: f64 = rng.random_range(-5.0..5.0);
            let touched = brute.iter().enumerate().filter(|(c, _)| {
                let (cl, cr) = (
                    -1.0 + *c as f64 * 2.0 / n as f64,
                    -1.0 + (*c + 1) as f64 * 2.0 / n as f64,
                );
                cr > lo - 1e-9 && cl <= hi + 1e-9
            });
            let expect = touched.clone().all(|(_, v)| *v > top + 1e-9);
            let strict = touched.clone().all(|(_, v)| *v > top - 1e-9);
            let got = h.hides(lo, hi, top);
            // Away from rounding ties the tree and brute force agree.
            if expect == strict {
                assert_eq!(got, expect, "[{lo}, {hi}] top {top}");
            }
        }
    }
}
