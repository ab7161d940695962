//! Axis-aligned bounding boxes in scene-local `f32` coordinates.
//!
//! Boxes are the currency of every culling method: objects, kd-tree cells and
//! the subtree bounds of Bittner et al. §2.2 are all `Aabb`s.

use glam::{DVec3, Vec3};

/// An axis-aligned box `[min, max]`, closed on both sides.
///
/// A box with `min > max` on any axis is *empty*: it contains no point and
/// intersects nothing. [`Aabb::EMPTY`] is the identity of [`Aabb::merge`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box to start merges from (`min = +∞`, `max = −∞`).
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// The box with the given corners (not reordered).
    pub const fn new(min: Vec3, max: Vec3) -> Self {
        Aabb { min, max }
    }

    /// The smallest box holding every point of `points` (empty for none).
    pub fn from_points(points: impl IntoIterator<Item = Vec3>) -> Self {
        let mut b = Aabb::EMPTY;
        for p in points {
            b.grow(p);
        }
        b
    }

    /// The smallest `f32` box holding the `f64` box `[min, max]`: each
    /// bound is rounded outwards, so no point of it is lost.
    pub fn enclosing(min: DVec3, max: DVec3) -> Self {
        Aabb {
            min: Vec3::new(round_down(min.x), round_down(min.y), round_down(min.z)),
            max: Vec3::new(round_up(max.x), round_up(max.y), round_up(max.z)),
        }
    }

    /// The largest `f32` box inside the `f64` box `[min, max]`: each bound
    /// rounded inwards, so it holds no point the other does not; `None`
    /// when nothing with positive extent is left.
    pub fn enclosed(min: DVec3, max: DVec3) -> Option<Self> {
        let b = Aabb {
            min: Vec3::new(round_up(min.x), round_up(min.y), round_up(min.z)),
            max: Vec3::new(round_down(max.x), round_down(max.y), round_down(max.z)),
        };
        b.min.cmplt(b.max).all().then_some(b)
    }

    /// Whether the box holds no point.
    pub fn is_empty(&self) -> bool {
        !(self.min.x <= self.max.x && self.min.y <= self.max.y && self.min.z <= self.max.z)
    }

    /// Grows the box in place to hold `p`.
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Grows the box in place to hold `other`.
    pub fn merge(&mut self, other: &Aabb) {
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
    }

    /// The smallest box holding both `self` and `other`.
    pub fn merged(&self, other: &Aabb) -> Aabb {
        let mut b = *self;
        b.merge(other);
        b
    }

    /// The part of `self` inside `other` (empty when they do not meet).
    pub fn clipped(&self, other: &Aabb) -> Aabb {
        Aabb {
            min: self.min.max(other.min),
            max: self.max.min(other.max),
        }
    }

    /// Whether `other` lies inside `self` (an empty `other` always does).
    pub fn contains(&self, other: &Aabb) -> bool {
        other.is_empty() || (self.min.cmple(other.min).all() && other.max.cmple(self.max).all())
    }

    /// Whether the point lies in the closed box.
    pub fn contains_point(&self, p: Vec3) -> bool {
        self.min.cmple(p).all() && p.cmple(self.max).all()
    }

    /// Whether the two closed boxes share a point.
    pub fn intersects(&self, other: &Aabb) -> bool {
        self.min.cmple(other.max).all() && other.min.cmple(self.max).all()
    }

    /// The centre point (meaningless for an empty box).
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Euclidean distance from `p` to the box, in `f64`; 0 inside it.
    pub fn distance_to(&self, p: DVec3) -> f64 {
        let (lo, hi) = (self.min.as_dvec3(), self.max.as_dvec3());
        (lo - p).max(p - hi).max(DVec3::ZERO).length()
    }

    /// The side lengths (negative for an empty box).
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// The index (0 = x, 1 = y, 2 = z) of the longest side; ties pick the lower axis.
    pub fn longest_axis(&self) -> usize {
        let e = self.extent();
        if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        }
    }

    /// The eight corners, in the order of the bits of their index (bit 0 = x max, bit 1 = y max, bit 2 = z max).
    pub fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|i| {
            Vec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            )
        })
    }
}

/// The largest `f32` not above `v`.
fn round_down(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) <= v {
        f
    } else if f == 0.0 {
        -f32::from_bits(1)
    } else if f > 0.0 {
        f32::from_bits(f.to_bits() - 1)
    } else {
        f32::from_bits(f.to_bits() + 1)
    }
}

/// The smallest `f32` not below `v`.
fn round_up(v: f64) -> f32 {
    -round_down(-v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enclosing_rounds_outwards() {
        for v in [0.0, 1e-40, -1e-40, 0.1, -0.1, 1.7, -1.7, 1e7 + 0.3, -3e38] {
            let b = Aabb::enclosing(DVec3::splat(v), DVec3::splat(v));
            assert!(f64::from(b.min.x) <= v && f64::from(b.max.x) >= v, "{v}");
            // Tight: one step in is past v (or v is exact).
            assert!(
                b.max.x - b.min.x <= f32::EPSILON * b.max.x.abs().max(1e-38) * 2.0,
                "{v}"
            );
        }
    }

    #[test]
    fn enclosed_rounds_inwards() {
        let (lo, hi) = (
            DVec3::new(0.1, -1e7 - 0.3, 1.0),
            DVec3::new(0.7, 1e7 + 0.3, 1.5),
        );
        let b = Aabb::enclosed(lo, hi).unwrap();
        for a in 0..3 {
            assert!(f64::from(b.min[a]) >= lo[a] && f64::from(b.max[a]) <= hi[a]);
        }
        assert_eq!(b.min.z, 1.0);
        assert_eq!(
            Aabb::enclosed(DVec3::splat(1e7 + 0.1), DVec3::splat(1e7 + 0.2)),
            None
        );
    }

    #[test]
    fn empty_is_identity_of_merge_and_intersects_nothing() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        assert_eq!(Aabb::EMPTY.merged(&b), b);
        assert!(Aabb::EMPTY.is_empty());
        assert!(!Aabb::EMPTY.intersects(&b));
        assert!(b.contains(&Aabb::EMPTY));
        assert!(Aabb::from_points([]).is_empty());
    }

    #[test]
    fn touching_boxes_intersect_because_they_are_closed() {
        let a = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let b = Aabb::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0));
        assert!(a.intersects(&b));
        let c = Aabb::new(Vec3::new(1.001, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0));
        assert!(!a.intersects(&c));
    }

    #[test]
    fn clipping_keeps_the_common_part() {
        let a = Aabb::new(Vec3::ZERO, Vec3::splat(2.0));
        let b = Aabb::new(Vec3::ONE, Vec3::splat(3.0));
        assert_eq!(a.clipped(&b), Aabb::new(Vec3::ONE, Vec3::splat(2.0)));
        let far = Aabb::new(Vec3::splat(5.0), Vec3::splat(6.0));
        assert!(a.clipped(&far).is_empty());
        // Touching boxes share a flat, non-empty face.
        let touch = Aabb::new(Vec3::new(2.0, 0.0, 0.0), Vec3::splat(3.0));
        assert!(!a.clipped(&touch).is_empty());
    }

    #[test]
    fn degenerate_point_box_is_not_empty() {
        let p = Aabb::from_points([Vec3::splat(3.0)]);
        assert!(!p.is_empty());
        assert!(p.contains_point(Vec3::splat(3.0)));
        assert_eq!(p.extent(), Vec3::ZERO);
    }

    #[test]
    fn corners_follow_index_bits() {
        let b = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0));
        let c = b.corners();
        assert_eq!(c[0], Vec3::ZERO);
        assert_eq!(c[7], Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(c[5], Vec3::new(1.0, 0.0, 3.0));
        assert_eq!(b.longest_axis(), 2);
    }
}
