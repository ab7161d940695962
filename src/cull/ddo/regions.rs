//! Viewspace regions (Bernardini et al. §3, Fig. 3): the discretized sets
//! of viewpoints from which an octree face may be a valid occluder.
//!
//! A face lies in the plane `t = 0` of its own frame `(u, v, t)`, with `t`
//! growing into its node (the viewer's side). Only eyes at least twice the
//! node's size `s` from the face (`t ≥ 2s`: the paper's clipping plane,
//! [`super::validity::CLIP`]) are considered. An eye's *slopes* are `a = (u − u_c) / t` and
//! `b = (v − v_c) / t`, from the face's centre `(u_c, v_c)`; the region is
//! the pair of bins its slopes fall in, the bins being 8 equal steps of
//! 20° of the angle `atan(slope)` between `−80°` and `80°`
//! ([`MAX_ANGLE_DEG`]):
//!
//! - **64 regions**: the 8 × 8 bins;
//! - **32 regions**: 8 × 4, each the union of two 64-regions neighbouring
//!   along `b` (bins of 20° × 40°). A face valid from both halves is valid
//!   from their union (validity is a property of each eye: every eye of
//!   the union is in a half whose proof covers it), so the bake proves the
//!   64 regions only and derives the 32 ([`coarse_mask`]); a direct proof
//!   over the union's wider viewspace frustum could only fail more often.
//!
//! An eye further than 80° from the face's normal along either slope is in
//! no region ([`Regions::region_of`] is `None`): towards grazing the slopes
//! are unbounded and no finite geometry blocks every ray. Stopping the bins
//! there, rather than letting the outermost bins run to 90°, keeps every
//! region bounded, so a face can be valid from eyes 60–80° off its normal:
//! the roof of a body seen from an orbit a little above it, a wall seen
//! along a street.

/// The largest angle from the normal, along either slope, of a region's eyes.
pub const MAX_ANGLE_DEG: f64 = 80.0;

/// Bin edges along one slope, ascending: `tan` of `−80°` to `80°` in steps
/// of 20°; the 8 bins between them are the regions', the slopes below the
/// first and above the last in none.
const EDGES: [f64; 9] = [-5.671281819617707, -1.7320508075688767, -0.8390996311772799, -0.36397023426620234, 0.0, 0.36397023426620234, 0.8390996311772799, 1.7320508075688767, 5.671281819617707];

/// Bins along one slope.
const BINS: usize = EDGES.len() - 1;

/// One way of cutting a face's viewpoints into regions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Regions {
    /// 8 × 4 bins of 20° × 40°.
    R32,
    /// 8 × 8 bins of 20°.
    R64,
}

impl Regions {
    /// Both partitions, in the order their masks are stored.
    pub const ALL: [Regions; 2] = [Regions::R32, Regions::R64];

    /// The partition with `n` regions.
    pub fn with_count(n: usize) -> Option<Regions> {
        match n {
            32 => Some(Regions::R32),
            64 => Some(Regions::R64),
            _ => None,
        }
    }

    /// How many regions (the bits of a face's mask).
    pub fn count(self) -> usize {
        match self {
            Regions::R32 => 32,
            Regions::R64 => 64,
        }
    }

    /// 64-regions merged into one of this partition's, along `b`.
    fn merged(self) -> usize {
        match self {
            Regions::R32 => 2,
            Regions::R64 => 1,
        }
    }

    /// The region of an eye with slopes `(a, b)`, or `None` when either is
    /// beyond [`MAX_ANGLE_DEG`] (or NaN). A slope on a bin edge takes the
    /// upper bin; the bake widens every region past its edges, so an eye
    /// that rounding puts in the neighbouring bin is still inside what was
    /// checked.
    pub fn region_of(self, a: f64, b: f64) -> Option<usize> {
        let bin = |x: f64| {
            let k = EDGES.partition_point(|&e| e <= x);
            // `k = 0` is below the first edge (or NaN), `BINS + 1` above
            // the last.
            (1..=BINS).contains(&k).then(|| k - 1)
        };
        Some((bin(a)? * BINS + bin(b)?) / self.merged())
    }

    /// The slope ranges `([a_lo, a_hi], [b_lo, b_hi])` of `region`'s eyes.
    ///
    /// # Panics
    /// If `region` is not below [`Regions::count`].
    pub fn slopes(self, region: usize) -> ([f64; 2], [f64; 2]) {
        assert!(region < self.count(), "region {region} of {self:?}");
        let first = region * self.merged();
        let (i, j) = (first / BINS, first % BINS);
        (
            [EDGES[i], EDGES[i + 1]],
            [EDGES[j], EDGES[j + self.merged()]],
        )
    }
}

/// The 32-region mask of a face whose 64-region mask is `fine`: a region's
/// bit is set when both of its halves' are (see the module doc).
pub fn coarse_mask(fine: u64) -> u32 {
    let both = fine & (fine >> 1);
    (0..32).fold(0, |m, k| m | (((both >> (2 * k)) & 1) as u32) << k)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_region_is_one_bit_and_every_bit_one_region() {
        for r in Regions::ALL {
            let mut seen = vec![0; r.count()];
            for i in 0..BINS {
                for j in 0..BINS {
                    let (a, b) = (0.5 * (EDGES[i] + EDGES[i + 1]), 0.5 * (EDGES[j] + EDGES[j + 1]));
                    seen[r.region_of(a, b).unwrap()] += 1;
                }
            }
            assert!(seen.iter().all(|&c| c == 64 / r.count()), "{r:?}: {seen:?}");
        }
    }

    #[test]
    fn an_eye_falls_in_the_region_whose_slopes_hold_it() {
        for r in Regions::ALL {
            for &a in &[-5.0, -1.2, -0.3, 0.0, 0.2, 0.7, 1.5, 3.0] {
                for &b in &[-3.0, -0.5, 0.1, 0.9, 2.0, 5.5] {
                    let k = r.region_of(a, b).unwrap();
                    let ([a0, a1], [b0, b1]) = r.slopes(k);
                    assert!(a0 <= a && a <= a1 && b0 <= b && b <= b1, "{r:?} {a} {b}");
                }
            }
            // 70° off is a region; past 80°, or NaN, none.
            assert!(r.region_of(2.75, 0.1).is_some(), "{r:?}");
            for (a, b) in [(5.8, 0.1), (0.1, -5.8), (100.0, 0.0), (f64::NAN, 0.0)] {
                assert_eq!(r.region_of(a, b), None, "{r:?} {a} {b}");
            }
        }
    }

    #[test]
    fn the_edges_are_equal_steps_of_angle_up_to_the_largest() {
        let step = 2.0 * MAX_ANGLE_DEG / BINS as f64;
        for (k, e) in EDGES.iter().enumerate() {
            let angle = k as f64 * step - MAX_ANGLE_DEG;
            assert!((e.atan().to_degrees() - angle).abs() < 1e-9, "{k}");
            assert_eq!(*e, -EDGES[BINS - k]);
        }
    }

    #[test]
    fn a_coarse_region_is_its_two_halves_and_valid_when_both_are() {
        for k in 0..32 {
            let (a, b) = Regions::R32.slopes(k);
            let (a0, b0) = Regions::R64.slopes(2 * k);
            let (a1, b1) = Regions::R64.slopes(2 * k + 1);
            assert_eq!((a, a), (a0, a1), "{k}");
            assert_eq!(b, [b0[0], b1[1]], "{k}");
            assert_eq!(b0[1], b1[0], "{k}");
            assert_eq!(coarse_mask(0b11 << (2 * k)), 1 << k);
            assert_eq!(coarse_mask(0b01 << (2 * k)), 0);
            assert_eq!(coarse_mask(0b10 << (2 * k)), 0);
        }
        assert_eq!(coarse_mask(u64::MAX), u32::MAX);
        // Two halves of different regions make none.
        assert_eq!(coarse_mask(0b0110), 0);
    }
}
