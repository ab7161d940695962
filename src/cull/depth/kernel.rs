//! The loops a depth buffer spends its time in, written twice: with AVX2
//! through `std::arch` where the CPU has it, and in plain Rust. Both do the
//! same floating-point operations in the same order on every cell or row
//! (a product then a sum, never fused; a maximum; a minimum; a rounding to
//! a whole number), so they give the same bits, and a test holds them to
//! it.

use glam::DVec3;

use crate::geom::{ceil_i64, floor_i64, greater, lesser};

/// One edge of a polygon as a bound on a cell row's columns: `p + q·(y +
/// at)` for the row whose top pixel centre is at `y` (see
/// [`Kernel::spans`]).
pub type Bound = (f64, f64, f64);

/// A row's first and last cell inside a polygon (the first above the last
/// where none is).
pub type Span = (i32, i32);

/// Where a box's eight corners lie seen from the eye (view space, the
/// eye at the origin looking along +z): their least depth, and the least
/// and greatest of their `x/z` and `y/z` (tangents of the angle off the
/// view direction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outline {
    pub z_min: f64,
    pub x: (f64, f64),
    pub y: (f64, f64),
}

/// Which implementation of the loops to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Plain Rust, one cell at a time.
    Scalar,
    /// AVX2, eight cells at a time (x86-64 CPUs that have it).
    Avx2,
}

impl Kernel {
    /// The fastest kernel this CPU runs.
    pub fn detect() -> Kernel {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Kernel::Avx2;
        }
        Kernel::Scalar
    }

    /// Raises each `cells[k]` to `base + k·step` where that is larger: one
    /// occluder's depth along a span of a row.
    pub fn raise(self, cells: &mut [f32], base: f32, step: f32) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx2` is only made by `detect` on a CPU that has AVX2
            // (or by a test that checked the same).
            Kernel::Avx2 => unsafe { avx2::raise(cells, base, step) },
            _ => raise_scalar(cells, base, step),
        }
    }

    /// Whether `raise` would change some cell: some `base + k·step` above
    /// `cells[k]`, computed as `raise` computes it.
    pub fn rises(self, cells: &[f32], base: f32, step: f32) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `raise`.
            Kernel::Avx2 => unsafe { avx2::rises(cells, base, step) },
            _ => rises_scalar(cells, base, step),
        }
    }

    /// The cells of consecutive cell rows inside a convex polygon: for row
    /// `k` of `rows`, whose top pixel centre is at `y = y_top + k·down`
    /// (`down` pixel rows a cell row),
    /// `(⌈max(0, maxₗ pₗ + qₗ·(y + atₗ))⌉, ⌊min(last_col, minᵣ pᵣ +
    /// qᵣ·(y + atᵣ))⌋)` over the `left` and `right` bounds (the first
    /// above the last where no cell is inside; either may then be clamped
    /// to one past the row's ends). The bounds must be finite, `y_top` and
    /// `down` whole numbers and a half, `last_col` a whole number below
    /// 2³¹ − 1.
    pub fn spans(
        self,
        left: &[Bound],
        right: &[Bound],
        (y_top, down): (f64, f64),
        last_col: f64,
        rows: &mut [Span],
    ) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `raise`.
            Kernel::Avx2 => unsafe { avx2::spans(left, right, (y_top, down), last_col, rows) },
            _ => spans_scalar(left, right, (y_top, down), last_col, rows),
        }
    }

    /// Whether cells `x0..=x1` (below 8) of `rows` runs of 8 cells,
    /// `stride` apart from `cells[0]`, all hold a value above `w` (none
    /// does for a NaN `w`): a tile's part of a box.
    pub fn above(
        self,
        cells: &[f32],
        stride: usize,
        rows: usize,
        (x0, x1): (usize, usize),
        w: f32,
    ) -> bool {
        assert!(x0 <= x1 && x1 < 8 && rows >= 1 && cells.len() >= (rows - 1) * stride + 8);
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `raise`; the assertion bounds the reads.
            Kernel::Avx2 => unsafe { avx2::above(cells, stride, rows, (x0, x1), w) },
            _ => (0..rows).all(|r| {
                cells[r * stride + x0..r * stride + x1 + 1]
                    .iter()
                    .all(|&c| c > w)
            }),
        }
    }

    /// The least of `rows` runs of `width` cells, `stride` apart, starting
    /// at `cells[0]`: a tile's farthest depth.
    pub fn least(self, cells: &[f32], stride: usize, width: usize, rows: usize) -> f32 {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `raise`.
            Kernel::Avx2 if width == 8 => unsafe { avx2::least8(cells, stride, rows) },
            _ => least_scalar(cells, stride, width, rows),
        }
    }

    /// The [`Outline`] of the corners `base + {0, ex} + {0, ey} + {0, ez}`
    /// (each summed in that order), or `None` when one of them does not
    /// lie beyond depth `z_floor` (a NaN depth among them). A NaN tangent
    /// (a corner at the eye itself, 0/0, past a floor below zero) is left
    /// out of the bounds; beyond a floor above zero none arises.
    pub fn outline(self, base: DVec3, edges: [DVec3; 3], z_floor: f64) -> Option<Outline> {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `raise`.
            Kernel::Avx2 => unsafe { avx2::outline(base, edges, z_floor) },
            _ => outline_scalar(base, edges, z_floor),
        }
    }
}

/// A kernel's `raise` as a type, so that a loop around it can be compiled
/// once per kernel with the raise inlined (see `DepthBuffer::raise_rows`).
pub(super) trait Raise {
    /// `Kernel::raise`.
    ///
    /// # Safety
    /// Only run on a CPU that has the kernel's instructions.
    unsafe fn raise(cells: &mut [f32], base: f32, step: f32);

    /// `Kernel::rises`.
    ///
    /// # Safety
    /// Only run on a CPU that has the kernel's instructions.
    unsafe fn rises(cells: &[f32], base: f32, step: f32) -> bool;
}

/// [`Raise`] in plain Rust.
pub(super) struct ScalarRaise;

impl Raise for ScalarRaise {
    #[inline(always)]
    unsafe fn raise(cells: &mut [f32], base: f32, step: f32) {
        raise_scalar(cells, base, step);
    }

    #[inline(always)]
    unsafe fn rises(cells: &[f32], base: f32, step: f32) -> bool {
        rises_scalar(cells, base, step)
    }
}

/// [`Raise`] with AVX2.
#[cfg(target_arch = "x86_64")]
pub(super) struct Avx2Raise;

#[cfg(target_arch = "x86_64")]
impl Raise for Avx2Raise {
    #[inline(always)]
    unsafe fn raise(cells: &mut [f32], base: f32, step: f32) {
        // SAFETY: the caller's.
        unsafe { avx2::raise(cells, base, step) }
    }

    #[inline(always)]
    unsafe fn rises(cells: &[f32], base: f32, step: f32) -> bool {
        // SAFETY: the caller's.
        unsafe { avx2::rises(cells, base, step) }
    }
}

/// `raise`, one cell at a time.
fn raise_scalar(cells: &mut [f32], base: f32, step: f32) {
    for (k, c) in cells.iter_mut().enumerate() {
        let v = base + k as f32 * step;
        if v > *c {
            *c = v;
        }
    }
}

/// `rises`, one cell at a time.
fn rises_scalar(cells: &[f32], base: f32, step: f32) -> bool {
    cells
        .iter()
        .enumerate()
        .any(|(k, &c)| base + k as f32 * step > c)
}

/// `spans`, one row and one edge at a time.
fn spans_scalar(
    left: &[Bound],
    right: &[Bound],
    (y_top, down): (f64, f64),
    last_col: f64,
    rows: &mut [Span],
) {
    for (k, out) in rows.iter_mut().enumerate() {
        // Whole numbers and a half: exact, however summed.
        let y = y_top + k as f64 * down;
        let mut first = 0.0f64;
        for &(p, q, at) in left {
            first = greater(first, p + q * (y + at));
        }
        let mut last = last_col;
        for &(p, q, at) in right {
            last = lesser(last, p + q * (y + at));
        }
        // Clamped to one past the ends, so that an empty row stays empty
        // and both fit in an i32.
        let (first, last) = (lesser(first, last_col + 1.0), greater(last, -1.0));
        *out = (ceil_i64(first) as i32, floor_i64(last) as i32);
    }
}

/// `outline`, one corner at a time.
fn outline_scalar(base: DVec3, [ex, ey, ez]: [DVec3; 3], z_floor: f64) -> Option<Outline> {
    let (b1, b2) = (base + ex, base + ey);
    let b3 = b1 + ey;
    let corners = [base, b1, b2, b3, base + ez, b1 + ez, b2 + ez, b3 + ez];
    let (inf, neg) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut z_min, mut x_lo, mut x_hi, mut y_lo, mut y_hi) = (inf, inf, neg, inf, neg);
    for v in corners {
        // Also NaN: not beyond.
        if v.z.partial_cmp(&z_floor) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        z_min = lesser(z_min, v.z);
        let inv = 1.0 / v.z;
        let (x, y) = (v.x * inv, v.y * inv);
        (x_lo, x_hi) = (lesser(x_lo, x), greater(x_hi, x));
        (y_lo, y_hi) = (lesser(y_lo, y), greater(y_hi, y));
    }
    Some(Outline {
        z_min,
        x: (x_lo, x_hi),
        y: (y_lo, y_hi),
    })
}

fn least_scalar(cells: &[f32], stride: usize, width: usize, rows: usize) -> f32 {
    let mut least = f32::INFINITY;
    for r in 0..rows {
        for &c in &cells[r * stride..r * stride + width] {
            least = least.min(c);
        }
    }
    least
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use glam::DVec3;

    /// `base + (k + lane)·step` in each of eight lanes: the values `raise`
    /// writes and `rises` compares, made in one place so that they are
    /// the same bits. `k + lane` is an integer below 2^24: exact in f32,
    /// as the scalar loops' `k as f32` is.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn values(base: __m256, step: __m256, k: usize) -> __m256 {
        let lanes = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let idx = _mm256_add_ps(_mm256_set1_ps(k as f32), lanes);
        _mm256_add_ps(base, _mm256_mul_ps(idx, step))
    }

    /// The lanes below `rest` (under eight), for a slice's last cells.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn first_lanes(rest: usize) -> __m256i {
        _mm256_cmpgt_epi32(
            _mm256_set1_epi32(rest as i32),
            _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
        )
    }

    /// # Safety
    /// The CPU must have AVX2.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn raise(cells: &mut [f32], base: f32, step: f32) {
        let n = cells.len();
        let (vb, vs) = (_mm256_set1_ps(base), _mm256_set1_ps(step));
        let mut k = 0;
        while k + 8 <= n {
            let v = values(vb, vs, k);
            // SAFETY: k + 8 <= n, so the eight cells are in the slice.
            unsafe {
                let p = cells.as_mut_ptr().add(k);
                // The old value second: on a tie `max` keeps it, as the
                // scalar loop's `v > c` does.
                _mm256_storeu_ps(p, _mm256_max_ps(v, _mm256_loadu_ps(p)));
            }
            k += 8;
        }
        if k < n {
            // The last cells through a mask: the same operations on them.
            let (v, mask) = (values(vb, vs, k), first_lanes(n - k));
            // SAFETY: the mask leaves out every lane past the slice's end.
            unsafe {
                let p = cells.as_mut_ptr().add(k);
                let old = _mm256_maskload_ps(p, mask);
                _mm256_maskstore_ps(p, mask, _mm256_max_ps(v, old));
            }
        }
    }

    /// # Safety
    /// The CPU must have AVX2.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn rises(cells: &[f32], base: f32, step: f32) -> bool {
        let n = cells.len();
        let (vb, vs) = (_mm256_set1_ps(base), _mm256_set1_ps(step));
        let mut k = 0;
        // Compared as `raise`'s `max` keeps them (ordered: a NaN rises
        // nowhere).
        while k + 8 <= n {
            // SAFETY: k + 8 <= n, so the eight cells are in the slice.
            let old = unsafe { _mm256_loadu_ps(cells.as_ptr().add(k)) };
            let above = _mm256_cmp_ps::<_CMP_GT_OQ>(values(vb, vs, k), old);
            if _mm256_movemask_ps(above) != 0 {
                return true;
            }
            k += 8;
        }
        if k < n {
            let mask = first_lanes(n - k);
            // SAFETY: the mask leaves out every lane past the slice's end.
            let old = unsafe { _mm256_maskload_ps(cells.as_ptr().add(k), mask) };
            let above = _mm256_cmp_ps::<_CMP_GT_OQ>(values(vb, vs, k), old);
            return _mm256_movemask_ps(_mm256_and_ps(above, _mm256_castsi256_ps(mask))) != 0;
        }
        false
    }

    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn spans(
        left: &[super::Bound],
        right: &[super::Bound],
        (y_top, down): (f64, f64),
        last_col: f64,
        rows: &mut [super::Span],
    ) {
        // Four rows at a time, each lane the scalar loop's operations on
        // its row: `y` is exact, then (y + at), q·, p + in that order.
        let steps = _mm256_setr_pd(0.0, 1.0, 2.0, 3.0);
        let vdown = _mm256_set1_pd(down);
        let (zero, vlast) = (_mm256_setzero_pd(), _mm256_set1_pd(last_col));
        let (past, before) = (_mm256_set1_pd(last_col + 1.0), _mm256_set1_pd(-1.0));
        let mut k = 0;
        while k < rows.len() {
            let ks = _mm256_add_pd(_mm256_set1_pd(k as f64), steps);
            let y = _mm256_add_pd(_mm256_set1_pd(y_top), _mm256_mul_pd(ks, vdown));
            let bound = |&(p, q, at): &super::Bound| {
                let at = _mm256_add_pd(y, _mm256_set1_pd(at));
                _mm256_add_pd(_mm256_set1_pd(p), _mm256_mul_pd(_mm256_set1_pd(q), at))
            };
            // `max(v, first)` is `first` on a tie, as `greater` is.
            let mut first = zero;
            for b in left {
                first = _mm256_max_pd(bound(b), first);
            }
            let mut last = vlast;
            for b in right {
                last = _mm256_min_pd(bound(b), last);
            }
            // The clamps: `lesser(first, past)` keeps `first` unless `past`
            // is smaller, as `min(past, first)` does. Whole numbers within
            // an i32 after them: converted exactly.
            let first = _mm256_cvttpd_epi32(_mm256_ceil_pd(_mm256_min_pd(past, first)));
            let last = _mm256_cvttpd_epi32(_mm256_floor_pd(_mm256_max_pd(before, last)));
            // Interleaved into (first, last) pairs, four rows' worth.
            let mut pairs = [(0i32, 0i32); 4];
            // SAFETY: four pairs of i32 are 32 bytes.
            unsafe {
                let out = pairs.as_mut_ptr().cast::<__m128i>();
                _mm_storeu_si128(out, _mm_unpacklo_epi32(first, last));
                _mm_storeu_si128(out.add(1), _mm_unpackhi_epi32(first, last));
            }
            for (out, &pair) in rows[k..].iter_mut().zip(&pairs) {
                *out = pair;
            }
            k += 4;
        }
    }

    /// # Safety
    /// The CPU must have AVX2, `x1 < 8`, and `cells` hold `(rows - 1) *
    /// stride + 8` values.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn above(
        cells: &[f32],
        stride: usize,
        rows: usize,
        (x0, x1): (usize, usize),
        w: f32,
    ) -> bool {
        let wanted = ((1u32 << (x1 + 1)) - 1) & !((1u32 << x0) - 1);
        let vw = _mm256_set1_ps(w);
        for r in 0..rows {
            // SAFETY: the caller's bound on `cells`.
            let v = unsafe { _mm256_loadu_ps(cells.as_ptr().add(r * stride)) };
            // Ordered: a NaN compares false, as `c > w` does.
            let above = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(v, vw)) as u32;
            if above & wanted != wanted {
                return false;
            }
        }
        true
    }

    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn outline(
        base: DVec3,
        [ex, ey, ez]: [DVec3; 3],
        z_floor: f64,
    ) -> Option<super::Outline> {
        // One coordinate of the eight corners in two vectors: lanes base,
        // +ex, +ey, +ex+ey, then each +ez, summed as the scalar loop sums
        // them (so a −0 stays −0 too).
        let corners = |b: f64, x: f64, y: f64, z: f64| {
            let near = _mm256_setr_pd(b, b + x, b + y, (b + x) + y);
            (near, _mm256_add_pd(near, _mm256_set1_pd(z)))
        };
        let (z0, z1) = corners(base.z, ex.z, ey.z, ez.z);
        let floor = _mm256_set1_pd(z_floor);
        // Ordered: a NaN depth is not beyond, as in the scalar loop.
        let beyond = _mm256_and_pd(
            _mm256_cmp_pd::<_CMP_GT_OQ>(z0, floor),
            _mm256_cmp_pd::<_CMP_GT_OQ>(z1, floor),
        );
        if _mm256_movemask_pd(beyond) != 0b1111 {
            return None;
        }
        let (x0, x1) = corners(base.x, ex.x, ey.x, ez.x);
        let (y0, y1) = corners(base.y, ex.y, ey.y, ez.y);
        let one = _mm256_set1_pd(1.0);
        let (inv0, inv1) = (_mm256_div_pd(one, z0), _mm256_div_pd(one, z1));
        let (x0, x1) = (_mm256_mul_pd(x0, inv0), _mm256_mul_pd(x1, inv1));
        let (y0, y1) = (_mm256_mul_pd(y0, inv0), _mm256_mul_pd(y1, inv1));
        // `min(v, acc)` is `acc` unless `v` is smaller (a NaN `v` never
        // is), as `lesser(acc, v)` is; likewise `max`: each new value
        // first, from a start of ±∞.
        let least = |a: __m256d, b: __m256d| {
            let m = _mm256_min_pd(b, _mm256_min_pd(a, _mm256_set1_pd(f64::INFINITY)));
            let m = _mm_min_pd(_mm256_extractf128_pd::<1>(m), _mm256_castpd256_pd128(m));
            _mm_cvtsd_f64(_mm_min_pd(_mm_unpackhi_pd(m, m), m))
        };
        let most = |a: __m256d, b: __m256d| {
            let m = _mm256_max_pd(b, _mm256_max_pd(a, _mm256_set1_pd(f64::NEG_INFINITY)));
            let m = _mm_max_pd(_mm256_extractf128_pd::<1>(m), _mm256_castpd256_pd128(m));
            _mm_cvtsd_f64(_mm_max_pd(_mm_unpackhi_pd(m, m), m))
        };
        Some(super::Outline {
            z_min: least(z0, z1),
            x: (least(x0, x1), most(x0, x1)),
            y: (least(y0, y1), most(y0, y1)),
        })
    }

    /// # Safety
    /// The CPU must have AVX2, and `cells` hold `(rows - 1) * stride + 8`
    /// values.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn least8(cells: &[f32], stride: usize, rows: usize) -> f32 {
        assert!(rows >= 1 && cells.len() >= (rows - 1) * stride + 8);
        let mut m = _mm256_set1_ps(f32::INFINITY);
        for r in 0..rows {
            // SAFETY: checked by the assertion above.
            m = _mm256_min_ps(m, unsafe {
                _mm256_loadu_ps(cells.as_ptr().add(r * stride))
            });
        }
        let mut out = [0f32; 8];
        // SAFETY: `out` holds eight floats.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), m) };
        out.into_iter().fold(f32::INFINITY, f32::min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Edge bounds as `Screen::draw` makes them, starting around column
    /// `from`: mostly slopes of a few cells a row, some nearly vertical or
    /// level, taken at either pixel row of a cell; and a bound at −0.
    fn bounds(from: f64) -> impl Strategy<Value = Vec<Bound>> {
        let slope = prop_oneof![
            6 => -3.0f64..3.0,
            1 => -1e-3f64..1e-3,
            1 => -1e12f64..1e12,
        ];
        let bound = (
            from - 200.0..from + 200.0,
            slope,
            prop_oneof![Just(0.0), Just(1.0), Just(3.0)],
        );
        let level = Just((-0.0, -0.0, 0.0));
        proptest::collection::vec(prop_oneof![12 => bound, 1 => level], 0..6)
    }

    proptest! {
        /// Both kernels find the same spans, bit for bit, on any number of
        /// rows (the vector loop's last lanes past the end included).
        #[test]
        fn spans_agree(
            left in bounds(0.0),
            right in bounds(300.0),
            first_row in 0u32..100,
            cell in 1u32..5,
            cols in 1u32..600,
            count in 1usize..40,
        ) {
            let (c, y_top) = (cell as f64, (first_row * cell) as f64 + 0.5);
            let last_col = (cols - 1) as f64;
            let (mut a, mut b) = (vec![(0, 0); count], vec![(1, 1); count]);
            Kernel::Scalar.spans(&left, &right, (y_top, c), last_col, &mut a);
            Kernel::detect().spans(&left, &right, (y_top, c), last_col, &mut b);
            prop_assert_eq!(&a, &b);
            for &(lo, hi) in &a {
                prop_assert!(lo >= 0 && hi as f64 <= last_col || lo > hi);
            }
            // Against the bounds themselves, at each row's binding row.
            for (k, &(lo, hi)) in a.iter().enumerate().filter(|(_, s)| s.0 <= s.1) {
                let (y, lo, hi) = (y_top + k as f64 * c, lo as f64, hi as f64);
                for &(p, q, at) in &left {
                    prop_assert!(lo >= p + q * (y + at));
                }
                for &(p, q, at) in &right {
                    prop_assert!(hi <= p + q * (y + at));
                }
            }
        }

        /// Both kernels say the same of a tile's part against a depth.
        #[test]
        fn above_agrees(
            cells in proptest::collection::vec(prop_oneof![Just(0.0f32), Just(1.0), 0.0f32..2.0], 8 * 12),
            rows in 1usize..8,
            x0 in 0usize..8,
            width in 0usize..8,
            w in prop_oneof![Just(1.0f32), 0.0f32..2.0, Just(f32::NAN)],
        ) {
            let x1 = (x0 + width).min(7);
            let plain = (0..rows).all(|r| (x0..=x1).all(|x| cells[r * 12 + x] > w));
            prop_assert_eq!(Kernel::Scalar.above(&cells, 12, rows, (x0, x1), w), plain);
            prop_assert_eq!(Kernel::detect().above(&cells, 12, rows, (x0, x1), w), plain);
        }

        /// Both kernels find the same outline of a box, bit for bit (a
        /// zero's sign aside), and it holds every corner; a corner not
        /// beyond the floor (or at a NaN depth) gives none.
        #[test]
        fn outlines_agree(
            base in (-1e3f64..1e3, -1e3f64..1e3, -1e3f64..1e3),
            edges in proptest::collection::vec((-50.0f64..50.0, -50.0f64..50.0, -50.0f64..50.0), 3),
            floor in prop_oneof![Just(0.1f64), -1e3f64..1e3, Just(f64::NAN)],
        ) {
            let v = |(x, y, z): (f64, f64, f64)| DVec3::new(x, y, z);
            let (base, edges) = (v(base), [v(edges[0]), v(edges[1]), v(edges[2])]);
            let plain = Kernel::Scalar.outline(base, edges, floor);
            let fast = Kernel::detect().outline(base, edges, floor);
            let same = |a: f64, b: f64| a.to_bits() == b.to_bits() || (a == 0.0 && b == 0.0);
            match (plain, fast) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    prop_assert!(same(a.z_min, b.z_min) && same(a.x.0, b.x.0) && same(a.x.1, b.x.1));
                    prop_assert!(same(a.y.0, b.y.0) && same(a.y.1, b.y.1), "{:?} {:?}", a, b);
                }
                (a, b) => prop_assert!(false, "{:?} against {:?}", a, b),
            }
            let corners = (0..8).map(|k| {
                let pick = |bit: usize, e: DVec3| if k & bit != 0 { e } else { DVec3::ZERO };
                base + pick(1, edges[0]) + pick(2, edges[1]) + pick(4, edges[2])
            });
            let beyond = corners.clone().all(|c| c.z > floor);
            prop_assert_eq!(plain.is_some(), beyond);
            if let Some(o) = plain {
                for c in corners {
                    // As the kernels divide: by a reciprocal. (A corner at
                    // the eye itself, past a floor below zero, has NaN
                    // tangents, 0/0; elsewhere at depth 0 infinite ones.)
                    let (x, y) = (c.x * (1.0 / c.z), c.y * (1.0 / c.z));
                    let within = |t: f64, (lo, hi): (f64, f64)| t.is_nan() || (lo <= t && t <= hi);
                    prop_assert!(o.z_min <= c.z && within(x, o.x) && within(y, o.y));
                }
            }
        }

        /// A box shrunk to the eye, past a floor below it: its tangents
        /// are all NaN (0/0), and left out; a corner exactly at the floor
        /// is not beyond it.
        #[test]
        fn an_outline_leaves_nan_tangents_out(floor in -1e3f64..-1e-3) {
            for kernel in [Kernel::Scalar, Kernel::detect()] {
                let o = kernel.outline(DVec3::ZERO, [DVec3::ZERO; 3], floor);
                prop_assert_eq!(o.map(|o| (o.z_min, o.x, o.y)), Some((0.0, (f64::INFINITY, f64::NEG_INFINITY), (f64::INFINITY, f64::NEG_INFINITY))));
                let at = DVec3::new(0.3, -0.2, -floor);
                prop_assert_eq!(kernel.outline(at, [DVec3::X, DVec3::Y, DVec3::Z], -floor), None);
                prop_assert!(kernel.outline(at, [DVec3::X, DVec3::Y, DVec3::Z], -floor * 0.999).is_some());
            }
        }

        /// Both kernels write the same bits and find the same least value.
        #[test]
        fn kernels_agree(
            start in proptest::collection::vec(-1e3f32..1e3, 1..70),
            base in -1e4f32..1e4,
            step in -1e2f32..1e2,
        ) {
            let fast = Kernel::detect();
            let (mut a, mut b) = (start.clone(), start.clone());
            let rises = Kernel::Scalar.rises(&a, base, step);
            prop_assert_eq!(fast.rises(&a, base, step), rises);
            Kernel::Scalar.raise(&mut a, base, step);
            prop_assert_eq!(a != start, rises);
            prop_assert!(!Kernel::Scalar.rises(&a, base, step) && !fast.rises(&a, base, step));
            fast.raise(&mut b, base, step);
            prop_assert_eq!(
                a.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                b.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            );
            let rows = a.len() / 8;
            if rows >= 1 {
                prop_assert_eq!(Kernel::Scalar.least(&a, 8, 8, rows), fast.least(&a, 8, 8, rows));
            }
        }
    }
}
