//! Building triangle meshes out of quads, boxes, cylinders and spheres.

use glam::Vec3;

use crate::scene::glb::Mesh;

/// An indexed triangle mesh under construction. Winding is not relied on:
/// visibility in pvsd treats every triangle as two-sided.
#[derive(Debug, Default)]
pub struct MeshBuilder {
    positions: Vec<[f32; 3]>,
    indices: Vec<u32>,
}

impl MeshBuilder {
    /// An empty mesh.
    pub fn new() -> Self {
        Self::default()
    }

    /// How many triangles so far.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    fn vertex(&mut self, p: Vec3) -> u32 {
        self.positions.push(p.to_array());
        (self.positions.len() - 1) as u32
    }

    /// One triangle.
    pub fn triangle(&mut self, a: Vec3, b: Vec3, c: Vec3) {
        let ix = [self.vertex(a), self.vertex(b), self.vertex(c)];
        self.indices.extend_from_slice(&ix);
    }

    /// A planar quad `a b c d` in order, as two triangles.
    pub fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
        let ix = [
            self.vertex(a),
            self.vertex(b),
            self.vertex(c),
            self.vertex(d),
        ];
        self.indices
            .extend_from_slice(&[ix[0], ix[1], ix[2], ix[0], ix[2], ix[3]]);
    }

    /// A vertical wall from `a` to `b` (on the ground, `a.y == b.y`), `height`
    /// tall, cut into `columns × rows` quads (facade bays and floors).
    pub fn wall_grid(&mut self, a: Vec3, b: Vec3, height: f32, columns: u32, rows: u32) {
        let at = |i: u32, j: u32| {
            a.lerp(b, i as f32 / columns as f32) + Vec3::Y * (height * j as f32 / rows as f32)
        };
        for j in 0..rows {
            for i in 0..columns {
                self.quad(at(i + 1, j), at(i, j), at(i, j + 1), at(i + 1, j + 1));
            }
        }
    }

    /// A box; `bottom` says whether its underside is closed.
    pub fn cuboid(&mut self, min: Vec3, max: Vec3, bottom: bool) {
        let c = |x: bool, y: bool, z: bool| {
            Vec3::new(
                if x { max.x } else { min.x },
                if y { max.y } else { min.y },
                if z { max.z } else { min.z },
            )
        };
        let (f, t) = (false, true);
        self.quad(c(f, f, t), c(t, f, t), c(t, t, t), c(f, t, t)); // +z
        self.quad(c(t, f, f), c(f, f, f), c(f, t, f), c(t, t, f)); // -z
        self.quad(c(t, f, t), c(t, f, f), c(t, t, f), c(t, t, t)); // +x
        self.quad(c(f, f, f), c(f, f, t), c(f, t, t), c(f, t, f)); // -x
        self.quad(c(f, t, t), c(t, t, t), c(t, t, f), c(f, t, f)); // +y
        if bottom {
            self.quad(c(f, f, f), c(t, f, f), c(t, f, t), c(f, f, t)); // -y
        }
    }

    /// A closed vertical cylinder standing on `base`.
    pub fn cylinder(&mut self, base: Vec3, radius: f32, height: f32, segments: u32) {
        let ring = |k: u32, y: f32| {
            let a = std::f32::consts::TAU * k as f32 / segments as f32;
            base + Vec3::new(radius * a.cos(), y, -radius * a.sin())
        };
        for k in 0..segments {
            let (b0, b1) = (ring(k, 0.0), ring(k + 1, 0.0));
            let (t0, t1) = (ring(k, height), ring(k + 1, height));
            self.quad(b0, b1, t1, t0);
            if k > 0 && k + 1 < segments {
                self.triangle(ring(0, height), ring(k, height), ring(k + 1, height));
                self.triangle(ring(0, 0.0), ring(k + 1, 0.0), ring(k, 0.0));
            }
        }
    }

    /// A UV sphere: `stacks` bands from pole to pole, `slices` around.
    pub fn uv_sphere(&mut self, center: Vec3, radius: f32, stacks: u32, slices: u32) {
        // The seam and the poles are the same points however `sin` and
        // `cos` round at τ and π, so the sphere closes up exactly.
        let at = |i: u32, j: u32| {
            if i == 0 || i == stacks {
                return center + radius * if i == 0 { Vec3::Y } else { -Vec3::Y };
            }
            let j = j % slices;
            let theta = std::f32::consts::PI * i as f32 / stacks as f32;
            let phi = std::f32::consts::TAU * j as f32 / slices as f32;
            center
                + radius
                    * Vec3::new(
                        theta.sin() * phi.cos(),
                        theta.cos(),
                        -theta.sin() * phi.sin(),
                    )
        };
        for i in 0..stacks {
            for j in 0..slices {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                if i == 0 {
                    self.triangle(a, b, c);
                } else if i + 1 == stacks {
                    self.triangle(a, b, d);
                } else {
                    self.quad(a, b, c, d);
                }
            }
        }
    }

    /// The finished mesh.
    pub fn build(self, see_through: bool) -> Mesh {
        Mesh {
            positions: self.positions,
            indices: self.indices,
            see_through,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_counts() {
        let mut m = MeshBuilder::new();
        m.cuboid(Vec3::ZERO, Vec3::ONE, true);
        assert_eq!(m.triangle_count(), 12);
        let mut m = MeshBuilder::new();
        m.cylinder(Vec3::ZERO, 1.0, 1.0, 24);
        assert_eq!(m.triangle_count(), 48 + 2 * 22);
        let mut m = MeshBuilder::new();
        m.uv_sphere(Vec3::ZERO, 1.0, 15, 20);
        assert_eq!(m.triangle_count(), 20 * 13 * 2 + 40);
        let mut m = MeshBuilder::new();
        m.wall_grid(Vec3::ZERO, Vec3::X * 4.0, 3.0, 4, 3);
        assert_eq!(m.triangle_count(), 24);
    }

    #[test]
    fn a_sphere_closes_up_exactly() {
        let mut m = MeshBuilder::new();
        m.uv_sphere(Vec3::new(0.3, -2.0, 7.0), 1.7, 11, 14);
        let mesh = m.build(false);
        let key = |v: Vec3| v.to_array().map(f32::to_bits);
        let mut edges = std::collections::HashMap::new();
        for t in mesh.triangles() {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                let (a, b) = (key(a), key(b));
                *edges
                    .entry(if a < b { (a, b) } else { (b, a) })
                    .or_insert(0) += 1;
            }
        }
        assert!(edges.values().all(|&n| n == 2), "{edges:?}");
    }
}
