//! The occlusion map (Bernardini et al. §4.2): the union of the occluder
//! rectangles seen so far, on a coordinate plane, queried with a node's
//! bounding rectangle. Two forms, as the paper measured:
//!
//! - [`RectUnion`] (the default, `map=exact`): the union kept exactly, as
//!   16 × 16 buckets of the window, each a binary partition cut only at
//!   rectangle edges, each part empty or full. Faces of neighbouring nodes in one plane share their
//!   edges' coordinates bit for bit, so their union has no seam.
//! - [`CellGrid`] (`map=grid`): a uniform grid, a row of cells a few machine
//!   words, so a rectangle costs one mask per row; a cell is marked only
//!   when it lies wholly inside one rectangle, so seams between
//!   neighbouring faces stay open and faces smaller than a cell add
//!   nothing (cheaper, and looser).
//!
//! A rectangle is hidden only when it lies inside the window and inside
//! the union. Queries are grown by [`SLACK`] of their coordinates (the
//! grid also shrinks what it marks by as much, and moves cell indices by a
//! millionth of a cell), far above the rounding of the projections, so
//! rounding can only make the map hide less, with one allowance: two
//! occluder rectangles whose edges round to the same value are taken to
//! meet, so a crack between them narrower than the slack (10⁻⁹ of the
//! coordinates, a millionth of a pixel) counts as closed.

use glam::DVec2;

/// Relative slack applied to rectangles before they meet the grid.
pub const SLACK: f64 = 1e-9;

/// An axis-aligned rectangle on the map's plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    /// Lowest corner.
    pub lo: DVec2,
    /// Highest corner.
    pub hi: DVec2,
}

impl Rect {
    /// The smallest rectangle holding `points`.
    pub fn around(points: impl IntoIterator<Item = DVec2>) -> Rect {
        points.into_iter().fold(
            Rect {
                lo: DVec2::splat(f64::INFINITY),
                hi: DVec2::splat(f64::NEG_INFINITY),
            },
            |r, p| Rect {
                lo: r.lo.min(p),
                hi: r.hi.max(p),
            },
        )
    }

    /// Grown (`by > 0`) or shrunk (`by < 0`) by `by` of its coordinates' size.
    fn slackened(&self, by: f64) -> Rect {
        let d = (self.lo.abs() + self.hi.abs() + DVec2::ONE) * by;
        Rect {
            lo: self.lo - d,
            hi: self.hi + d,
        }
    }
}

/// The occlusion map of one view.
#[derive(Clone, Debug)]
pub enum OcclusionMap {
    /// The exact union.
    Exact(RectUnion),
    /// A uniform grid.
    Grid(CellGrid),
}

impl OcclusionMap {
    /// Clears the map and sets its window.
    pub fn reset(&mut self, window: Rect) {
        match self {
            OcclusionMap::Exact(m) => m.reset(window),
            OcclusionMap::Grid(m) => m.reset(window),
        }
    }

    /// Whether nothing was added since the reset.
    pub fn is_empty(&self) -> bool {
        match self {
            OcclusionMap::Exact(m) => m.is_empty(),
            OcclusionMap::Grid(m) => m.is_empty(),
        }
    }

    /// Adds an occluder rectangle.
    pub fn add(&mut self, r: Rect) {
        match self {
            OcclusionMap::Exact(m) => m.add(r),
            OcclusionMap::Grid(m) => m.add(r),
        }
    }

    /// Whether every point of `r` lies inside the rectangles added.
    pub fn hides(&mut self, r: Rect) -> bool {
        match self {
            OcclusionMap::Exact(m) => m.hides(r),
            OcclusionMap::Grid(m) => m.hides(r),
        }
    }

    /// Bytes it holds on the heap.
    pub fn heap_bytes(&self) -> usize {
        match self {
            OcclusionMap::Exact(m) => m.parts.capacity() * std::mem::size_of::<Part>(),
            OcclusionMap::Grid(m) => m.heap_bytes(),
        }
    }
}

/// A part of the window's partition.
#[derive(Clone, Copy, Debug)]
enum Part {
    Empty,
    Full,
    /// Cut at `at` along `axis`; `lo` is the part below the cut.
    Split {
        axis: usize,
        at: f64,
        lo: u32,
        hi: u32,
    },
}

/// The exact union of rectangles: a partition of the window, cut at their
/// edges, into empty and full parts.
#[derive(Clone, Debug)]
pub struct RectUnion {
    parts: Vec<Part>,
    window: Option<Rect>,
    stack: Vec<(u32, Rect)>,
    /// The window's boundaries between buckets, per axis: bucket `(i, j)`
    /// is the root of its own partition (part `j × BUCKETS + i`), so a
    /// path down is as deep as the cuts inside one bucket, not the window.
    edges: Box<[[f64; BUCKETS + 1]; 2]>,
    added: bool,
}

/// Buckets along each axis of the window.
const BUCKETS: usize = 16;

/// Parts beyond this many are not made: later rectangles are dropped
/// (hiding less), which bounds a view's work whatever it adds.
const MAX_PARTS: usize = 1 << 18;

impl Default for RectUnion {
    fn default() -> Self {
        RectUnion {
            parts: Vec::new(),
            window: None,
            stack: Vec::new(),
            edges: Box::new([[0.0; BUCKETS + 1]; 2]),
            added: false,
        }
    }
}

impl RectUnion {
    /// Clears the union and sets its window.
    pub fn reset(&mut self, window: Rect) {
        self.parts.clear();
        self.parts.resize(BUCKETS * BUCKETS, Part::Empty);
        for (axis, edges) in self.edges.iter_mut().enumerate() {
            let (lo, hi) = (window.lo[axis], window.hi[axis]);
            for (k, e) in edges.iter_mut().enumerate() {
                *e = lo + (hi - lo) * k as f64 / BUCKETS as f64;
            }
            edges[BUCKETS] = hi;
        }
        self.window = Some(window);
        self.added = false;
    }

    /// Whether nothing was added since the reset.
    pub fn is_empty(&self) -> bool {
        !self.added
    }

    /// The buckets `[first, end)` along `axis` that `r` overlaps with
    /// positive length.
    fn buckets(&self, r: Rect, axis: usize) -> (usize, usize) {
        let e = &self.edges[axis];
        let first = e[1..].partition_point(|&x| x <= r.lo[axis]);
        let end = e[..BUCKETS].partition_point(|&x| x < r.hi[axis]);
        (first, end)
    }

    /// The scratch stack, holding the root and region of every bucket `r`
    /// overlaps: where a walk over the union for `r` starts.
    fn bucket_stack(&mut self, r: Rect) -> Vec<(u32, Rect)> {
        let ((x0, x1), (y0, y1)) = (self.buckets(r, 0), self.buckets(r, 1));
        let mut stack = std::mem::take(&mut self.stack);
        stack.clear();
        for j in y0..y1 {
            for i in x0..x1 {
                stack.push(self.bucket(i, j));
            }
        }
        stack
    }

    /// Bucket `(i, j)`'s root part and region.
    fn bucket(&self, i: usize, j: usize) -> (u32, Rect) {
        let [x, y] = &*self.edges;
        (
            (j * BUCKETS + i) as u32,
            Rect {
                lo: DVec2::new(x[i], y[j]),
                hi: DVec2::new(x[i + 1], y[j + 1]),
            },
        )
    }

    /// Adds `r` (its part inside the window).
    pub fn add(&mut self, r: Rect) {
        let Some(window) = self.window else { return };
        let r = Rect {
            lo: r.lo.max(window.lo),
            hi: r.hi.min(window.hi),
        };
        if !(r.lo.x < r.hi.x && r.lo.y < r.hi.y) {
            return;
        }
        self.added = true;
        let mut stack = self.bucket_stack(r);
        while let Some((i, region)) = stack.pop() {
            match self.parts[i as usize] {
                Part::Full => {}
                Part::Split { axis, at, lo, hi } => {
                    if r.lo[axis] < at {
                        let mut below = region;
                        below.hi[axis] = at;
                        stack.push((lo, below));
                    }
                    if r.hi[axis] > at {
                        let mut above = region;
                        above.lo[axis] = at;
                        stack.push((hi, above));
                    }
                }
                Part::Empty => {
                    if r.lo.cmple(region.lo).all() && r.hi.cmpge(region.hi).all() {
                        self.parts[i as usize] = Part::Full;
                        continue;
                    }
                    if self.parts.len() + 2 > MAX_PARTS {
                        continue;
                    }
                    // An edge of `r` inside the region: cut there.
                    let (axis, at) = (0..2)
                        .find_map(|a| {
                            if r.lo[a] > region.lo[a] {
                                Some((a, r.lo[a]))
                            } else if r.hi[a] < region.hi[a] {
                                Some((a, r.hi[a]))
                            } else {
                                None
                            }
                        })
                        .expect("a rectangle that does not hold the region has an edge inside it");
                    let lo = self.parts.len() as u32;
                    self.parts.push(Part::Empty);
                    self.parts.push(Part::Empty);
                    self.parts[i as usize] = Part::Split {
                        axis,
                        at,
                        lo,
                        hi: lo + 1,
                    };
                    // Visit it again, now split.
                    stack.push((i, region));
                }
            }
        }
        self.stack = stack;
    }

    /// Whether the part holding `p` (a point of the window) is empty.
    fn empty_at(&self, p: DVec2) -> bool {
        let bucket = |axis: usize| {
            self.edges[axis][1..]
                .partition_point(|&x| x <= p[axis])
                .min(BUCKETS - 1)
        };
        let mut i = self.bucket(bucket(0), bucket(1)).0;
        loop {
            match self.parts[i as usize] {
                Part::Full => return false,
                Part::Empty => return true,
                Part::Split { axis, at, lo, hi } => i = if p[axis] < at { lo } else { hi },
            }
        }
    }

    /// Whether every point of `r`, grown by the slack, lies inside the window and the union.
    pub fn hides(&mut self, r: Rect) -> bool {
        let Some(window) = self.window else {
            return false;
        };
        if self.is_empty() {
            return false;
        }
        let r = r.slackened(SLACK);
        if !(r.lo.cmpge(window.lo).all() && r.hi.cmple(window.hi).all()) {
            return false;
        }
        // Most queries are of visible nodes: the rectangle's centre in an
        // empty part says so after one path down, before the whole search
        // (probing its corners too was measured slower).
        let centre = (r.lo + r.hi) * 0.5;
        if self.empty_at(centre) {
            return false;
        }
        let mut stack = self.bucket_stack(r);
        let mut hidden = true;
        while let Some((i, region)) = stack.pop() {
            match self.parts[i as usize] {
                Part::Full => {}
                Part::Empty => {
                    hidden = false;
                    break;
                }
                Part::Split { axis, at, lo, hi } => {
                    if r.lo[axis] < at {
                        stack.push((lo, region));
                    }
                    if r.hi[axis] > at {
                        stack.push((hi, region));
                    }
                }
            }
        }
        self.stack = stack;
        hidden
    }
}

/// A grid of `resolution × resolution` cells over a window.
#[derive(Clone, Debug)]
pub struct CellGrid {
    resolution: usize,
    words: usize,
    cells: Vec<u64>,
    window: Rect,
    /// Cells per unit, per axis.
    scale: DVec2,
    empty: bool,
}

impl CellGrid {
    /// An empty map of `resolution²` cells over the unit window.
    pub fn new(resolution: usize) -> CellGrid {
        let words = resolution.div_ceil(64);
        CellGrid {
            resolution,
            words,
            cells: vec![0; words * resolution],
            window: Rect {
                lo: DVec2::ZERO,
                hi: DVec2::ONE,
            },
            scale: DVec2::splat(resolution as f64),
            empty: true,
        }
    }

    /// Clears the map and sets its window.
    pub fn reset(&mut self, window: Rect) {
        self.cells.fill(0);
        self.window = window;
        self.scale = DVec2::splat(self.resolution as f64) / (window.hi - window.lo);
        self.empty = true;
    }

    /// Whether nothing was added since the reset.
    pub fn is_empty(&self) -> bool {
        self.empty
    }

    /// The cell coordinates (fractional) of `p`.
    fn cell(&self, p: DVec2) -> DVec2 {
        (p - self.window.lo) * self.scale
    }

    /// Marks every cell that lies wholly inside `r`.
    pub fn add(&mut self, r: Rect) {
        let r = r.slackened(-SLACK);
        let (lo, hi) = (self.cell(r.lo), self.cell(r.hi));
        let n = self.resolution as f64;
        let first = |x: f64| (x + 1e-6).ceil().clamp(0.0, n) as usize;
        let end = |x: f64| (x - 1e-6).floor().clamp(0.0, n) as usize;
        let (x0, x1, y0, y1) = (first(lo.x), end(hi.x), first(lo.y), end(hi.y));
        if x0 >= x1 || y0 >= y1 || !(lo.is_finite() && hi.is_finite()) {
            return;
        }
        self.empty = false;
        for y in y0..y1 {
            let row = &mut self.cells[y * self.words..(y + 1) * self.words];
            for (w, word) in row.iter_mut().enumerate() {
                *word |= span_mask(w, x0, x1);
            }
        }
    }

    /// Whether every point of `r` lies inside the rectangles added.
    pub fn hides(&mut self, r: Rect) -> bool {
        if self.empty {
            return false;
        }
        let r = r.slackened(SLACK);
        let (lo, hi) = (self.cell(r.lo), self.cell(r.hi));
        let n = self.resolution as f64;
        let (x0, x1) = ((lo.x - 1e-6).floor(), (hi.x + 1e-6).ceil());
        let (y0, y1) = ((lo.y - 1e-6).floor(), (hi.y + 1e-6).ceil());
        // Outside the window (or not a number): nothing there was mapped.
        if !(x0 >= 0.0 && y0 >= 0.0 && x1 <= n && y1 <= n) {
            return false;
        }
        let (x0, x1, y0, y1) = (x0 as usize, x1 as usize, y0 as usize, y1 as usize);
        (y0..y1).all(|y| {
            let row = &self.cells[y * self.words..(y + 1) * self.words];
            row.iter().enumerate().all(|(w, word)| {
                let m = span_mask(w, x0, x1);
                word & m == m
            })
        })
    }

    /// Bytes its cells hold.
    pub fn heap_bytes(&self) -> usize {
        self.cells.capacity() * 8
    }
}

/// The bits of word `w` (cells `64w .. 64w + 64`) among cells `[x0, x1)`.
fn span_mask(w: usize, x0: usize, x1: usize) -> u64 {
    let (lo, hi) = (x0.max(w * 64), x1.min(w * 64 + 64));
    if lo >= hi {
        return 0;
    }
    let bits = hi - lo;
    let ones = if bits == 64 { u64::MAX } else { (1u64 << bits) - 1 };
    ones << (lo - w * 64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Rect {
        Rect {
            lo: DVec2::new(x0, y0),
            hi: DVec2::new(x1, y1),
        }
    }

    #[test]
    fn a_rectangle_is_hidden_only_inside_the_union_of_those_added() {
        let mut m = CellGrid::new(100);
        m.reset(rect(-1.0, -1.0, 1.0, 1.0));
        assert!(!m.hides(rect(-0.1, -0.1, 0.1, 0.1)), "empty map");
        m.add(rect(-0.5, -0.5, 0.0, 0.5));
        m.add(rect(0.0, -0.5, 0.5, 0.5));
        assert!(m.hides(rect(-0.4, -0.4, -0.1, 0.4)), "inside one");
        assert!(!m.hides(rect(-0.4, -0.4, 0.4, 0.4)), "the seam on a cell edge stays open");
        m.add(rect(-0.5, -0.5, 0.5, 0.5));
        assert!(m.hides(rect(-0.4, -0.4, 0.4, 0.4)));
        assert!(!m.hides(rect(-0.4, -0.4, 0.6, 0.4)), "past the union");
        assert!(!m.hides(rect(-0.5, -0.5, 0.5, 0.5)), "the union's own edge is a cell boundary: too close");
        assert!(!m.hides(rect(0.9, 0.9, 1.1, 1.1)), "leaves the window");
        assert!(!m.hides(rect(f64::NAN, 0.0, 0.1, 0.1)));
    }

    #[test]
    fn the_exact_union_has_no_seams_and_nothing_more() {
        let mut m = RectUnion::default();
        m.reset(rect(-1.0, -1.0, 1.0, 1.0));
        assert!(!m.hides(rect(-0.1, -0.1, 0.1, 0.1)), "empty");
        // A 10 × 10 tiling of small squares sharing their edges exactly.
        for i in 0..10 {
            for j in 0..10 {
                let (x, y) = (-0.5 + i as f64 * 0.1, -0.5 + j as f64 * 0.1);
                m.add(rect(x, y, -0.5 + (i + 1) as f64 * 0.1, -0.5 + (j + 1) as f64 * 0.1));
            }
        }
        assert!(m.hides(rect(-0.45, -0.45, 0.45, 0.45)));
        assert!(!m.hides(rect(-0.45, -0.45, 0.55, 0.45)), "past the union");
        assert!(!m.hides(rect(-0.5, -0.5, 0.5, 0.5)), "the slack reaches past its edge");
        assert!(!m.hides(rect(0.95, 0.0, 1.05, 0.1)), "leaves the window");
        assert!(!m.hides(rect(f64::NAN, 0.0, 0.1, 0.1)));
        // An L shape does not hide its bounding box.
        let mut l = RectUnion::default();
        l.reset(rect(0.0, 0.0, 4.0, 4.0));
        l.add(rect(1.0, 1.0, 3.0, 2.0));
        l.add(rect(1.0, 1.0, 2.0, 3.0));
        assert!(l.hides(rect(1.2, 1.2, 2.8, 1.8)));
        assert!(!l.hides(rect(1.2, 1.2, 2.8, 2.8)));
    }

    #[test]
    fn a_rectangle_smaller_than_a_cell_marks_nothing() {
        let mut m = CellGrid::new(16);
        m.reset(rect(0.0, 0.0, 1.0, 1.0));
        m.add(rect(0.01, 0.01, 0.05, 0.05));
        assert!(m.is_empty());
    }

    #[test]
    fn masks_span_word_boundaries() {
        assert_eq!(span_mask(0, 0, 64), u64::MAX);
        assert_eq!(span_mask(1, 60, 70), 0b11_1111);
        assert_eq!(span_mask(0, 60, 70), 0xF << 60);
        assert_eq!(span_mask(2, 60, 70), 0);
    }
}
