//! Viewspace regions (Bernardini et al. §3, Fig. 3): the discretized sets
//! of viewpoints from which an octree face may be a valid occluder.
//!
//! A face lies in the plane `t = 0` of its own frame `(u, v, t)`, with `t`
//! growing into its node (the viewer's side). Only eyes at least twice the
//! node's size `s` from the face (`t ≥ 2s`: the paper's clipping plane,
//! [`super::validity::CLIP`]) are considered. An eye's *slopes* are `a = (u − u_c) / t` and
//! `b = (v − v_c) / t`, from the face's centre `(u_c, v_c)`; the region is
//! the pair of bins its slopes fall in, the bins being equal steps of the
//! angle `atan(slope)`:
//!
//! - **64 regions**: 8 × 8 bins of 22.5° (edges at slopes 0, ±tan 22.5°, ±1,
//!   ±tan 67.5°);
//! - **32 regions**: 6 × 6 bins of 30° without the four grazing corners.
//!
//! The outermost bins reach grazing directions, where the slopes are
//! unbounded: no finite geometry blocks every ray from them, so their bit
//! is never set ([`Regions::slopes`] is `None`).

/// `tan(22.5°)`, `tan(67.5°)`, `tan(30°)`, `tan(60°)`.
const TAN_22_5: f64 = std::f64::consts::SQRT_2 - 1.0;
const TAN_67_5: f64 = std::f64::consts::SQRT_2 + 1.0;
const TAN_30: f64 = 0.577_350_269_189_625_8;
const TAN_60: f64 = 1.732_050_807_568_877_2;

const EDGES_64: [f64; 7] = [-TAN_67_5, -1.0, -TAN_22_5, 0.0, TAN_22_5, 1.0, TAN_67_5];
const EDGES_32: [f64; 5] = [-TAN_60, -TAN_30, 0.0, TAN_30, TAN_60];

/// One way of cutting a face's viewpoints into regions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Regions {
    /// 6 × 6 bins of 30°, corners dropped.
    R32,
    /// 8 × 8 bins of 22.5°.
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

    /// Finite bin edges along one slope, ascending.
    fn edges(self) -> &'static [f64] {
        match self {
            Regions::R32 => &EDGES_32,
            Regions::R64 => &EDGES_64,
        }
    }

    /// Bins along one slope.
    fn bins(self) -> usize {
        self.edges().len() + 1
    }

    /// The region of an eye with slopes `(a, b)`, or `None` for a dropped
    /// corner (32 regions). A slope on a bin edge takes the upper bin; the
    /// bake widens every region past its edges, so an eye that rounding
    /// puts in the neighbouring bin is still inside what was checked.
    pub fn region_of(self, a: f64, b: f64) -> Option<usize> {
        let bin = |x: f64| self.edges().partition_point(|&e| e <= x);
        self.region_at(bin(a), bin(b))
    }

    /// The region of bins `(i, j)`.
    fn region_at(self, i: usize, j: usize) -> Option<usize> {
        let n = self.bins();
        match self {
            Regions::R64 => Some(i * n + j),
            Regions::R32 => {
                let corner = (i == 0 || i == n - 1) && (j == 0 || j == n - 1);
                if corner {
                    return None;
                }
                // Row-major over the 36 bins, less the corners before (i, j).
                let cell = i * n + j;
                let before = match (i, j) {
                    (0, _) => 1,
                    (i, _) if i < n - 1 => 2,
                    (_, _) => 3,
                };
                Some(cell - before)
            }
        }
    }

    /// The slope ranges `([a_lo, a_hi], [b_lo, b_hi])` of `region`'s eyes,
    /// or `None` when the region reaches grazing directions (unbounded).
    pub fn slopes(self, region: usize) -> Option<([f64; 2], [f64; 2])> {
        let n = self.bins();
        let edges = self.edges();
        let (i, j) = (0..n)
            .flat_map(|i| (0..n).map(move |j| (i, j)))
            .find(|&(i, j)| self.region_at(i, j) == Some(region))?;
        let range = |k: usize| -> Option<[f64; 2]> {
            (k > 0 && k < n - 1).then(|| [edges[k - 1], edges[k]])
        };
        Some((range(i)?, range(j)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_region_is_one_bit_and_every_bit_one_region() {
        for r in Regions::ALL {
            let mut seen = vec![0; r.count()];
            let n = r.bins();
            for i in 0..n {
                for j in 0..n {
                    if let Some(k) = r.region_at(i, j) {
                        seen[k] += 1;
                    }
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "{r:?}: {seen:?}");
        }
    }

    #[test]
    fn an_eye_falls_in_the_region_whose_slopes_hold_it() {
        for r in Regions::ALL {
            for &a in &[-5.0, -1.2, -0.3, 0.0, 0.2, 0.7, 1.5, 9.0] {
                for &b in &[-3.0, -0.5, 0.1, 0.9, 2.0] {
                    let Some(k) = r.region_of(a, b) else { continue };
                    if let Some(([a0, a1], [b0, b1])) = r.slopes(k) {
                        assert!(a0 <= a && a <= a1 && b0 <= b && b <= b1, "{r:?} {a} {b}");
                    }
                }
            }
            // Straight on is a bounded region; grazing is not.
            assert!(r.slopes(r.region_of(0.1, 0.1).unwrap()).is_some());
            assert!(r.slopes(r.region_of(100.0, 0.1).unwrap()).is_none());
        }
    }
}
