//! Convex planar polygons and their split by a plane.
//!
//! Occlusion trees (Bittner et al. §4) and supporting planes (Coorg–Teller)
//! cut occluder polygons by shadow planes; this is the one clipping routine
//! they share.

use glam::DVec3;

use super::Plane;

/// A convex planar polygon, vertices in counter-clockwise order seen from
/// the side its [`ConvexPolygon::normal`] points to.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvexPolygon {
    /// The corners in order; at least three for a polygon with area.
    pub vertices: Vec<DVec3>,
}

/// The parts of a polygon on either side of a plane.
#[derive(Clone, Debug, PartialEq)]
pub struct Split {
    /// The part with positive signed distance (`None` when there is none).
    pub front: Option<ConvexPolygon>,
    /// The part with negative signed distance (`None` when there is none).
    pub back: Option<ConvexPolygon>,
    /// Whether every vertex lies within the tolerance of the plane.
    pub coplanar: bool,
}

impl ConvexPolygon {
    /// A polygon from its corners in order.
    pub fn new(vertices: Vec<DVec3>) -> Self {
        ConvexPolygon { vertices }
    }

    /// The area-weighted normal (Newell's method): its length is twice the area.
    fn newell(&self) -> DVec3 {
        let n = self.vertices.len();
        (0..n).fold(DVec3::ZERO, |acc, i| {
            let a = self.vertices[i];
            let b = self.vertices[(i + 1) % n];
            acc + a.cross(b)
        })
    }

    /// The unit normal, or `None` for a polygon with no area.
    pub fn normal(&self) -> Option<DVec3> {
        self.newell().try_normalize()
    }

    /// The area (zero for a degenerate polygon).
    pub fn area(&self) -> f64 {
        self.newell().length() * 0.5
    }

    /// The mean of the corners.
    pub fn centroid(&self) -> DVec3 {
        self.vertices.iter().copied().sum::<DVec3>() / self.vertices.len().max(1) as f64
    }

    /// The supporting plane, facing along [`ConvexPolygon::normal`].
    pub fn plane(&self) -> Option<Plane> {
        Plane::from_point_normal(self.centroid(), self.normal()?)
    }

    /// The polygon with every edge moved inwards by `by` within its plane
    /// (its erosion by a disc of radius `by`), or `None` when nothing is
    /// left. Each edge's line moves by `by` exactly, then the intersection
    /// points are rounded: callers that need the result strictly inside ask
    /// for a little more.
    pub fn inset(&self, by: f64) -> Option<ConvexPolygon> {
        let normal = self.normal()?;
        let centre = self.centroid();
        let n = self.vertices.len();
        let mut part = self.clone();
        for i in 0..n {
            let (a, b) = (self.vertices[i], self.vertices[(i + 1) % n]);
            let Some(mut inward) = normal.cross(b - a).try_normalize() else {
                continue;
            };
            if inward.dot(centre - a) < 0.0 {
                inward = -inward;
            }
            let edge = Plane::from_point_normal(a + inward * by, inward)?;
            part = part.clipped(&edge, 0.0)?;
            if part.vertices.len() < 3 || part.area() == 0.0 {
                return None;
            }
        }
        Some(part)
    }

    /// The part in front of `plane` (on it within `eps` counts as in front),
    /// or `None` when nothing is.
    pub fn clipped(&self, plane: &Plane, eps: f64) -> Option<ConvexPolygon> {
        let s = self.split(plane, eps);
        if s.coplanar || s.back.is_none() {
            return (self.vertices.len() >= 3).then(|| self.clone());
        }
        s.front
    }

    /// Splits the polygon by `plane`. Vertices within `eps` of the plane
    /// count as on it and go to both parts, so no sliver is lost between them.
    pub fn split(&self, plane: &Plane, eps: f64) -> Split {
        let dist: Vec<f64> = self
            .vertices
            .iter()
            .map(|&v| plane.signed_distance(v))
            .collect();
        let (mut front, mut back) = (Vec::new(), Vec::new());
        let n = self.vertices.len();
        for i in 0..n {
            let (a, da) = (self.vertices[i], dist[i]);
            let (b, db) = (self.vertices[(i + 1) % n], dist[(i + 1) % n]);
            if da >= -eps {
                front.push(a);
            }
            if da <= eps {
                back.push(a);
            }
            // A proper crossing: strictly on opposite sides beyond the tolerance.
            if (da > eps && db < -eps) || (da < -eps && db > eps) {
                let t = da / (da - db);
                let p = a + (b - a) * t;
                front.push(p);
                back.push(p);
            }
        }
        let keep = |vs: Vec<DVec3>, sign: f64| {
            // A part made only of on-plane vertices is not a part on that side.
            let has_side = self
                .vertices
                .iter()
                .zip(&dist)
                .any(|(_, &d)| d * sign > eps);
            (vs.len() >= 3 && has_side).then(|| ConvexPolygon::new(vs))
        };
        Split {
            coplanar: dist.iter().all(|d| d.abs() <= eps),
            front: keep(front, 1.0),
            back: keep(back, -1.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> ConvexPolygon {
        ConvexPolygon::new(vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(2.0, 2.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
        ])
    }

    #[test]
    fn inset_moves_every_edge_in_and_vanishes_when_thin() {
        let s = square().inset(0.25).unwrap();
        assert!((s.area() - 1.5 * 1.5).abs() < 1e-12);
        for v in &s.vertices {
            assert!(v.x >= 0.25 - 1e-12 && v.x <= 1.75 + 1e-12, "{v:?}");
            assert!(v.y >= 0.25 - 1e-12 && v.y <= 1.75 + 1e-12, "{v:?}");
        }
        // Either winding.
        let mut flipped = square();
        flipped.vertices.reverse();
        assert!((flipped.inset(0.25).unwrap().area() - 2.25).abs() < 1e-12);
        assert_eq!(square().inset(1.0), None);
        assert_eq!(square().inset(3.0), None);
    }

    #[test]
    fn area_and_normal() {
        assert!((square().area() - 4.0).abs() < 1e-12);
        assert_eq!(square().normal(), Some(DVec3::Z));
        let flat = ConvexPolygon::new(vec![DVec3::ZERO, DVec3::X, DVec3::X * 2.0]);
        assert_eq!(flat.normal(), None);
        assert_eq!(flat.area(), 0.0);
    }

    #[test]
    fn split_preserves_area_and_sides() {
        let plane =
            Plane::from_point_normal(DVec3::new(0.5, 0.0, 0.0), DVec3::new(1.0, 0.3, 0.0)).unwrap();
        let s = square().split(&plane, 1e-9);
        let (f, b) = (s.front.unwrap(), s.back.unwrap());
        assert!((f.area() + b.area() - 4.0).abs() < 1e-9);
        assert!(
            f.vertices
                .iter()
                .all(|&v| plane.signed_distance(v) >= -1e-9)
        );
        assert!(b.vertices.iter().all(|&v| plane.signed_distance(v) <= 1e-9));
        assert!(!s.coplanar);
    }

    #[test]
    fn split_through_a_vertex_and_along_an_edge() {
        // Along the edge x = 0: everything is in front, nothing behind.
        let plane = Plane::from_point_normal(DVec3::ZERO, DVec3::X).unwrap();
        let s = square().split(&plane, 1e-9);
        assert_eq!(s.front.as_ref().map(|p| p.area()), Some(4.0));
        assert!(s.back.is_none());
        // Through two opposite corners: two triangles of area 2.
        let diag = Plane::from_point_normal(DVec3::ZERO, DVec3::new(1.0, -1.0, 0.0)).unwrap();
        let s = square().split(&diag, 1e-9);
        assert!((s.front.unwrap().area() - 2.0).abs() < 1e-12);
        assert!((s.back.unwrap().area() - 2.0).abs() < 1e-12);
    }

    #[test]
    fn coplanar_polygon_has_no_sides() {
        let plane = Plane::from_point_normal(DVec3::ZERO, DVec3::Z).unwrap();
        let s = square().split(&plane, 1e-9);
        assert!(s.coplanar);
        assert!(s.front.is_none() && s.back.is_none());
    }
}
