//! Planes in `f64`, and where a box lies with respect to one.
//!
//! Planes are kept in `f64` although scene data is `f32`: a frustum's side
//! planes pass through the eye, and with `far = 1e9` an error of one `f32` ulp
//! in a normal moves the plane by tens of units at the far end. Converting an
//! `f32` box corner to `f64` is exact, so the only rounding left is in the
//! dot product, about 1e-16 of the distance.

use glam::{DVec3, Vec3};

use super::Aabb;

/// The plane `normal · p + d = 0`; the *positive* side (`> 0`) is "in front".
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal, pointing to the positive side.
    pub normal: DVec3,
    /// Offset: `−normal · p` for any point `p` on the plane.
    pub d: f64,
}

/// Where a box lies with respect to a plane or a set of planes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// Every point of the box is strictly on the negative side.
    Outside,
    /// Every point of the box is on the positive side or on the plane.
    Inside,
    /// The box has points on both sides.
    Intersecting,
}

impl Plane {
    /// The plane through `point` with the given normal, normalised.
    ///
    /// Returns `None` when the normal is zero or not finite.
    pub fn from_point_normal(point: DVec3, normal: DVec3) -> Option<Plane> {
        let n = normal.try_normalize()?;
        Some(Plane {
            normal: n,
            d: -n.dot(point),
        })
    }

    /// The plane `(a, b, c, d)` of a matrix row combination, normalised so
    /// that `|(a, b, c)| = 1`. `None` when `(a, b, c)` is zero.
    pub fn from_coefficients(a: f64, b: f64, c: f64, d: f64) -> Option<Plane> {
        let n = DVec3::new(a, b, c);
        let len = n.length();
        if !(len > 0.0 && len.is_finite()) {
            return None;
        }
        Some(Plane {
            normal: n / len,
            d: d / len,
        })
    }

    /// Signed distance of `p` (positive in front).
    pub fn signed_distance(&self, p: DVec3) -> f64 {
        self.normal.dot(p) + self.d
    }

    /// The same plane facing the other way.
    pub fn flipped(&self) -> Plane {
        Plane {
            normal: -self.normal,
            d: -self.d,
        }
    }

    /// Where the closed box lies. An empty box is [`Side::Outside`].
    ///
    /// Uses the corner furthest along the normal (the "p-vertex") and the one
    /// furthest against it (the "n-vertex"). The result is monotone in the
    /// box: a box inside another is never classified less outside or less
    /// inside than it, even after rounding, because each product and sum is
    /// monotone in each coordinate. Hierarchical culling relies on that.
    pub fn classify(&self, b: &Aabb) -> Side {
        if b.is_empty() {
            return Side::Outside;
        }
        let (p, n) = self.extreme_corners(b);
        if self.dot3(p) + self.d < 0.0 {
            Side::Outside
        } else if self.dot3(n) + self.d >= 0.0 {
            Side::Inside
        } else {
            Side::Intersecting
        }
    }

    /// The smallest and largest signed distance of the box's eight corners,
    /// from two of them (n-vertex, p-vertex). Exactly what evaluating all
    /// eight with [`Plane::signed_distance`] and taking the extremes gives,
    /// rounding included (up to the sign of a zero): each product and sum
    /// of the dot product is monotone in each coordinate (see
    /// [`Plane::classify`]). An empty box has no corners: `(+inf, -inf)`.
    pub fn box_range(&self, b: &Aabb) -> (f64, f64) {
        if b.is_empty() {
            return (f64::INFINITY, f64::NEG_INFINITY);
        }
        let (p, n) = self.extreme_corners(b);
        (
            self.signed_distance(n.as_dvec3()),
            self.signed_distance(p.as_dvec3()),
        )
    }

    /// The smallest signed distance of the box's corners: the first half of
    /// [`Plane::box_range`] at half its cost, for tests that ask only
    /// whether a box lies wholly in front.
    pub fn box_min(&self, b: &Aabb) -> f64 {
        if b.is_empty() {
            return f64::INFINITY;
        }
        let pick = |n: f64, lo: f32, hi: f32| if n >= 0.0 { lo } else { hi };
        self.signed_distance(DVec3::new(
            pick(self.normal.x, b.min.x, b.max.x) as f64,
            pick(self.normal.y, b.min.y, b.max.y) as f64,
            pick(self.normal.z, b.min.z, b.max.z) as f64,
        ))
    }

    /// `(p-vertex, n-vertex)` of the box for this normal.
    fn extreme_corners(&self, b: &Aabb) -> (Vec3, Vec3) {
        let pick = |n: f64, lo: f32, hi: f32| if n >= 0.0 { (hi, lo) } else { (lo, hi) };
        let (px, nx) = pick(self.normal.x, b.min.x, b.max.x);
        let (py, ny) = pick(self.normal.y, b.min.y, b.max.y);
        let (pz, nz) = pick(self.normal.z, b.min.z, b.max.z);
        (Vec3::new(px, py, pz), Vec3::new(nx, ny, nz))
    }

    /// `normal · p` in a fixed evaluation order (see [`Plane::classify`]).
    fn dot3(&self, p: Vec3) -> f64 {
        self.normal.x * p.x as f64 + self.normal.y * p.y as f64 + self.normal.z * p.z as f64
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;

    #[test]
    fn a_box_range_is_the_range_of_its_eight_corners_exactly() {
        // Awkward magnitudes, so rounding differs from corner to corner.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut next = || rng.random_range(-0.5..0.5);
        for _ in 0..2000 {
            let n = DVec3::new(next(), next(), next()) * 3.0;
            let Some(plane) = Plane::from_point_normal(DVec3::new(next(), next(), next()) * 1e6, n)
            else {
                continue;
            };
            let c = Vec3::new(next() as f32, next() as f32, next() as f32) * 1e6;
            let h = Vec3::new(next() as f32, next() as f32, next() as f32).abs() * 1e3;
            let b = Aabb::new(c - h, c + h);
            let want = b
                .corners()
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |r, c| {
                    let d = plane.signed_distance(c.as_dvec3());
                    (r.0.min(d), r.1.max(d))
                });
            assert_eq!(plane.box_range(&b), want);
        }
        assert_eq!(
            Plane::from_point_normal(DVec3::ZERO, DVec3::Y)
                .unwrap()
                .box_range(&Aabb::EMPTY),
            (f64::INFINITY, f64::NEG_INFINITY)
        );
    }

    fn unit_box() -> Aabb {
        Aabb::new(Vec3::ZERO, Vec3::ONE)
    }

    #[test]
    fn classify_sides() {
        let p = Plane::from_point_normal(DVec3::new(0.5, 0.0, 0.0), DVec3::X).unwrap();
        assert_eq!(p.classify(&unit_box()), Side::Intersecting);
        let p = Plane::from_point_normal(DVec3::new(-1.0, 0.0, 0.0), DVec3::X).unwrap();
        assert_eq!(p.classify(&unit_box()), Side::Inside);
        let p = Plane::from_point_normal(DVec3::new(2.0, 0.0, 0.0), DVec3::X).unwrap();
        assert_eq!(p.classify(&unit_box()), Side::Outside);
        assert_eq!(p.classify(&Aabb::EMPTY), Side::Outside);
    }

    #[test]
    fn box_touching_plane_is_not_outside() {
        // The box's face lies on the plane: it is "inside" (closed half-space).
        let p = Plane::from_point_normal(DVec3::new(1.0, 0.0, 0.0), DVec3::NEG_X).unwrap();
        assert_eq!(p.classify(&unit_box()), Side::Inside);
        let p = Plane::from_point_normal(DVec3::new(1.0, 0.0, 0.0), DVec3::X).unwrap();
        assert_eq!(p.classify(&unit_box()), Side::Intersecting);
    }

    #[test]
    fn zero_normal_is_rejected() {
        assert!(Plane::from_point_normal(DVec3::ONE, DVec3::ZERO).is_none());
        assert!(Plane::from_coefficients(0.0, 0.0, 0.0, 1.0).is_none());
        assert!(Plane::from_coefficients(f64::NAN, 0.0, 0.0, 1.0).is_none());
    }

    #[test]
    fn flipped_negates_distance() {
        let p =
            Plane::from_point_normal(DVec3::new(0.0, 2.0, 0.0), DVec3::new(0.0, 3.0, 4.0)).unwrap();
        let q = DVec3::new(1.0, 5.0, -2.0);
        assert!((p.signed_distance(q) + p.flipped().signed_distance(q)).abs() < 1e-12);
    }
}
