//! The rasterizer behind [`Truth`]: view-space transform, near-plane
//! clipping, pixel-centre coverage with inclusive edges (a centre on an edge
//! shared by two triangles is covered by both, so meshes have no cracks),
//! perspective-correct depth, and a two-surface depth buffer.

use std::ops::Range;

use glam::DVec3;
use rayon::prelude::*;

use super::{NO_OBJECT, Truth};
use crate::geom::Camera;
use crate::scene::{Object, Scene};

/// The camera set up in scene-local view space.
struct Eye {
    /// Eye position, scene-local.
    pos: DVec3,
    right: DVec3,
    up: DVec3,
    forward: DVec3,
    /// Half-field tangents.
    tx: f64,
    ty: f64,
    near: f64,
    far: f64,
    width: usize,
    height: usize,
}

impl Eye {
    fn to_view(&self, p: DVec3) -> DVec3 {
        let d = p - self.pos;
        DVec3::new(d.dot(self.right), d.dot(self.up), d.dot(self.forward))
    }

    /// Whether every corner of the box lies outside one plane of the view
    /// pyramid (or behind the near plane, or beyond the far plane): then no
    /// part of the object can reach a pixel.
    fn rejects(&self, o: &Object) -> bool {
        if o.bounds.is_empty() {
            return true;
        }
        let corners = o.bounds.corners().map(|c| self.to_view(c.as_dvec3()));
        let all = |f: &dyn Fn(&DVec3) -> bool| corners.iter().all(f);
        all(&|v| v.z < self.near)
            || all(&|v| v.z > self.far)
            || all(&|v| v.x > self.tx * v.z)
            || all(&|v| v.x < -self.tx * v.z)
            || all(&|v| v.y > self.ty * v.z)
            || all(&|v| v.y < -self.ty * v.z)
    }
}

/// One pixel of the two-surface depth buffer.
#[derive(Clone, Copy)]
struct Pixel {
    /// Depth and object of the nearest opaque surface.
    d1: f64,
    id1: u32,
    /// Depth and object of the nearest opaque surface of *another* object.
    d2: f64,
    id2: u32,
}

const EMPTY: Pixel = Pixel {
    d1: f64::INFINITY,
    id1: NO_OBJECT,
    d2: f64::INFINITY,
    id2: NO_OBJECT,
};

impl Pixel {
    fn opaque(&mut self, z: f64, id: u32) {
        if id == self.id1 {
            self.d1 = self.d1.min(z);
        } else if z < self.d1 {
            (self.d2, self.id2) = (self.d1, self.id1);
            (self.d1, self.id1) = (z, id);
        } else if z < self.d2 {
            (self.d2, self.id2) = (z, id);
        }
    }
}

/// See-through fragments counted by one band.
struct SeeThrough {
    clean: Vec<u32>,
    tied: Vec<u32>,
}

pub(super) fn render(scene: &Scene, camera: &Camera) -> Truth {
    let basis = camera.basis().expect("validated camera");
    let (tx, ty) = camera.half_tangents();
    let [w, h] = camera.viewport;
    let eye = Eye {
        pos: camera.eye - scene.origin,
        right: basis.right,
        up: basis.up,
        forward: basis.forward,
        tx,
        ty,
        near: camera.near,
        far: camera.far,
        width: w as usize,
        height: h as usize,
    };
    let objects: Vec<&Object> = scene.objects().iter().filter(|o| !eye.rejects(o)).collect();
    let n = scene.objects().len();
    let tol = |z: f64| Truth::depth_tolerance(scene, z);

    let mut pixels = vec![EMPTY; eye.width * eye.height];
    // Bands of rows, a few per thread so uneven bands even out.
    let rows = eye.height.div_ceil(rayon::current_num_threads() * 4).max(1);
    let bands: Vec<SeeThrough> = pixels
        .par_chunks_mut(rows * eye.width)
        .enumerate()
        .map(|(b, band)| {
            let y0 = b * rows;
            let y1 = (y0 + rows).min(eye.height);
            let mut st = SeeThrough {
                clean: vec![0; n],
                tied: vec![0; n],
            };
            for o in &objects {
                for r in o.opaque_ranges() {
                    for t in &scene.triangles()[r.start as usize..r.end as usize] {
                        rasterize(&eye, t, y0..y1, |x, y, z| {
                            band[(y - y0) * eye.width + x].opaque(z, o.id)
                        });
                    }
                }
            }
            // Which object last counted a pixel: an object's triangles meet
            // on shared edges, and a pixel centre there is covered twice.
            let mut counted = vec![NO_OBJECT; band.len()];
            for o in &objects {
                for r in &o.see_through {
                    for t in &scene.triangles()[r.start as usize..r.end as usize] {
                        rasterize(&eye, t, y0..y1, |x, y, z| {
                            let i = (y - y0) * eye.width + x;
                            let d1 = band[i].d1;
                            if counted[i] == o.id || z > d1 + tol(d1) {
                                return;
                            }
                            counted[i] = o.id;
                            if z < d1 - tol(d1) {
                                st.clean[o.id as usize] += 1;
                            } else {
                                st.tied[o.id as usize] += 1;
                            }
                        });
                    }
                }
            }
            st
        })
        .collect();

    let mut truth = Truth {
        width: w,
        height: h,
        winner: Vec::with_capacity(pixels.len()),
        clean: vec![0; n],
        tied: vec![0; n],
        see_through: vec![0; n],
    };
    for p in &pixels {
        truth.winner.push(p.id1);
        if p.id1 == NO_OBJECT {
            continue;
        }
        if p.id2 != NO_OBJECT && p.d2 - p.d1 <= tol(p.d1) {
            truth.tied[p.id1 as usize] += 1;
            truth.tied[p.id2 as usize] += 1;
        } else {
            truth.clean[p.id1 as usize] += 1;
        }
    }
    for st in bands {
        for i in 0..n {
            truth.clean[i] += st.clean[i];
            truth.tied[i] += st.tied[i];
            truth.see_through[i] += st.clean[i] + st.tied[i];
        }
    }
    truth
}

/// Calls `frag(x, y, depth)` for every pixel centre in `rows` that the
/// triangle covers between the near and far planes.
fn rasterize(
    eye: &Eye,
    t: &[glam::Vec3; 3],
    rows: Range<usize>,
    mut frag: impl FnMut(usize, usize, f64),
) {
    let v = t.map(|p| eye.to_view(p.as_dvec3()));
    // Clip against the near plane (z >= near): at most four corners.
    let mut poly = [DVec3::ZERO; 4];
    let mut len = 0;
    for i in 0..3 {
        let (a, b) = (v[i], v[(i + 1) % 3]);
        let (ina, inb) = (a.z >= eye.near, b.z >= eye.near);
        if ina {
            poly[len] = a;
            len += 1;
        }
        if ina != inb {
            let s = (eye.near - a.z) / (b.z - a.z);
            let mut p = a + (b - a) * s;
            p.z = eye.near; // exactly on the plane, whatever the rounding
            poly[len] = p;
            len += 1;
        }
    }
    if len < 3 {
        return;
    }
    let poly = &poly[..len];
    let all = |f: &dyn Fn(&DVec3) -> bool| poly.iter().all(f);
    if all(&|p| p.z > eye.far)
        || all(&|p| p.x > eye.tx * p.z)
        || all(&|p| p.x < -eye.tx * p.z)
        || all(&|p| p.y > eye.ty * p.z)
        || all(&|p| p.y < -eye.ty * p.z)
    {
        return;
    }
    let (wf, hf) = (eye.width as f64, eye.height as f64);
    // Screen position (pixels, y down) and 1/z, for perspective-correct depth.
    let screen: Vec<(f64, f64, f64)> = poly
        .iter()
        .map(|p| {
            (
                (p.x / (p.z * eye.tx) + 1.0) * 0.5 * wf,
                (1.0 - p.y / (p.z * eye.ty)) * 0.5 * hf,
                1.0 / p.z,
            )
        })
        .collect();
    for k in 1..screen.len() - 1 {
        fill(eye, [screen[0], screen[k], screen[k + 1]], &rows, &mut frag);
    }
}

fn fill(
    eye: &Eye,
    s: [(f64, f64, f64); 3],
    rows: &Range<usize>,
    frag: &mut impl FnMut(usize, usize, f64),
) {
    let edge = |a: (f64, f64, f64), b: (f64, f64, f64), px: f64, py: f64| {
        (b.0 - a.0) * (py - a.1) - (b.1 - a.1) * (px - a.0)
    };
    let area = edge(s[0], s[1], s[2].0, s[2].1);
    if area == 0.0 || !area.is_finite() {
        return; // no area (covers no pixel centre), or beyond f64's range
    }
    let sign = area.signum();
    let (minx, maxx) = (
        s[0].0.min(s[1].0).min(s[2].0),
        s[0].0.max(s[1].0).max(s[2].0),
    );
    let (miny, maxy) = (
        s[0].1.min(s[1].1).min(s[2].1),
        s[0].1.max(s[1].1).max(s[2].1),
    );
    // Pixel (i, j) has its centre at (i + 0.5, j + 0.5).
    let x0 = (minx - 0.5).ceil().max(0.0);
    let x1 = (maxx - 0.5).floor().min(eye.width as f64 - 1.0);
    let y0 = (miny - 0.5).ceil().max(rows.start as f64);
    let y1 = (maxy - 0.5).floor().min(rows.end as f64 - 1.0);
    if !(x0 <= x1 && y0 <= y1) {
        return;
    }
    for y in y0 as usize..=y1 as usize {
        let py = y as f64 + 0.5;
        for x in x0 as usize..=x1 as usize {
            let px = x as f64 + 0.5;
            let e0 = edge(s[1], s[2], px, py) * sign;
            let e1 = edge(s[2], s[0], px, py) * sign;
            let e2 = edge(s[0], s[1], px, py) * sign;
            if e0 < 0.0 || e1 < 0.0 || e2 < 0.0 {
                continue;
            }
            let inv_z = (e0 * s[0].2 + e1 * s[1].2 + e2 * s[2].2) / (area * sign);
            let z = 1.0 / inv_z;
            if z <= eye.far && z >= eye.near * (1.0 - 1e-12) {
                frag(x, y, z);
            }
        }
    }
}
