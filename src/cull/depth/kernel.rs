//! The two loops a depth buffer spends its time in, written twice: with
//! AVX2 through `std::arch` where the CPU has it, and in plain Rust. Both
//! do the same `f32` operations in the same order on every cell (a product
//! then a sum, never fused; a maximum; a minimum), so they write the same
//! bits, and a test holds them to it.

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

    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn raise(cells: &mut [f32], base: f32, step: f32) {
        let n = cells.len();
        let lanes = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let (vb, vs) = (_mm256_set1_ps(base), _mm256_set1_ps(step));
        let mut k = 0;
        while k + 8 <= n {
            // `k + lane` is an integer below 2^24: exact in f32, as the
            // scalar loop's `k as f32` is.
            let idx = _mm256_add_ps(_mm256_set1_ps(k as f32), lanes);
            let v = _mm256_add_ps(vb, _mm256_mul_ps(idx, vs));
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
            let idx = _mm256_add_ps(_mm256_set1_ps(k as f32), lanes);
            let v = _mm256_add_ps(vb, _mm256_mul_ps(idx, vs));
            let rest = (n - k) as i32;
            let mask = _mm256_cmpgt_epi32(
                _mm256_set1_epi32(rest),
                _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
            );
            // SAFETY: the mask leaves out every lane past the slice's end.
            unsafe {
                let p = cells.as_mut_ptr().add(k);
                let old = _mm256_maskload_ps(p, mask);
                _mm256_maskstore_ps(p, mask, _mm256_max_ps(v, old));
            }
        }
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

    proptest! {
        /// Both kernels write the same bits and find the same least value.
        #[test]
        fn kernels_agree(
            start in proptest::collection::vec(-1e3f32..1e3, 1..70),
            base in -1e4f32..1e4,
            step in -1e2f32..1e2,
        ) {
            let fast = Kernel::detect();
            let (mut a, mut b) = (start.clone(), start.clone());
            Kernel::Scalar.raise(&mut a, base, step);
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
