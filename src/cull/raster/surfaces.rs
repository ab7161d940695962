//! What `raster` draws of an object once it found the object visible: its
//! opaque triangles merged into maximal convex polygons (the merge the
//! occluders come from, `cull::occluder`, without their size threshold),
//! each with its plane, how far its triangles may stray from that plane,
//! and a bounding sphere to judge its size on screen; an object's surfaces
//! are grouped into small clusters of neighbours with a box each, so a
//! frame skips whole clusters that are off the view, too small, or hidden
//! already. The faces of an object's proxies ([`super::proxies`]) are
//! clusters of their own, drawn only from outside the object's box. Built
//! once per scene, on all cores.

use std::ops::Range;

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use super::proxies::Proxies;
use crate::cull::occluder::{PLANARITY_ULPS, object_polygons};
use crate::geom::{Aabb, Plane};
use crate::scene::{Object, Scene};

/// One polygon: its corners are `Surfaces::corners[corners]`.
#[derive(Clone, Debug)]
pub struct Surface {
    pub corners: Range<u32>,
    pub plane: Plane,
    /// How far its triangles may lie from `plane` (scene units).
    pub thickness: f64,
    /// Centre and radius of a sphere holding it.
    pub centre: DVec3,
    pub radius: f64,
    /// How wide it is for its size: its area over its diameter squared
    /// (a square's is ½, a long sliver's near 0), so that its width on
    /// screen is about this share of its size there.
    pub breadth: f64,
}

/// Neighbouring surfaces of one object, largest first.
#[derive(Clone, Debug)]
pub struct Cluster {
    pub surfaces: Range<u32>,
    /// A box holding them.
    pub bounds: Aabb,
    /// The radius of the largest.
    pub largest: f64,
    /// Its surfaces are faces of proxies inside the object
    /// ([`super::proxies`]), normals out: drawn only from outside its box.
    pub inner: bool,
}

/// Most surfaces in a cluster.
const CLUSTER: usize = 32;

/// The surfaces of every static object of a scene.
#[derive(Clone, Debug, Default)]
pub struct Surfaces {
    /// Every polygon's corners, in `f32`: they are the scene's own vertex
    /// positions, exactly (a polygon whose corner is not is left out).
    corners: Vec<Vec3>,
    surfaces: Vec<Surface>,
    clusters: Vec<Cluster>,
    /// Per object id, its clusters (none for movable objects: they are
    /// culled where they are now, and drawn nowhere).
    by_object: Vec<Range<u32>>,
    /// Per object id, which side of its surfaces is outside.
    outside: Vec<Outside>,
}

/// How far a polygon's triangles may lie from its plane, in `f32` ulps of
/// its largest coordinate: the merge keeps corners within
/// [`PLANARITY_ULPS`] of it; twice that covers the plane's own rounding.
fn thickness(corners: &[DVec3]) -> f64 {
    let size = corners
        .iter()
        .map(|v| v.abs().max_element())
        .fold(0.0, f64::max);
    2.0 * PLANARITY_ULPS * f32::EPSILON as f64 * size
}

/// The area of the convex polygon `corners`.
fn area(corners: &[DVec3]) -> f64 {
    let a = corners[0];
    let twice: DVec3 = corners
        .windows(2)
        .skip(1)
        .map(|w| (w[0] - a).cross(w[1] - a))
        .sum();
    0.5 * twice.length()
}

/// A sphere holding `corners`: their mean and farthest distance from it.
fn sphere(corners: &[DVec3]) -> (DVec3, f64) {
    let centre = corners.iter().sum::<DVec3>() / corners.len() as f64;
    let radius = corners
        .iter()
        .map(|c| c.distance(centre))
        .fold(0.0, f64::max);
    (centre, radius)
}

/// Which side of an object's surfaces is its outside, where its opaque
/// triangles close up consistently: then, seen from outside its box, the
/// faces turned away from the eye lie behind faces turned towards it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outside {
    /// Not closed, or not wound one way: every face is drawn.
    Unknown,
    /// Normals (counter-clockwise winding) point out.
    Front,
    /// Normals point in.
    Back,
}

/// [`Outside`] for `o`: every directed edge (its ends' exact positions)
/// is matched by as many running the other way, and the sign of the
/// enclosed volume tells which way the winding turns. Also whether `o`'s
/// opaque triangles close up at all, however wound: every edge shared by
/// an even number of them (then crossing them an odd number of times is
/// what being inside means, which is all [`super::proxies`] needs).
pub(super) fn outside(scene: &Scene, o: &Object) -> (Outside, bool) {
    let key = |v: Vec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
    // Per undirected edge: its directed balance and how many use it.
    let mut edges: FxHashMap<([u32; 3], [u32; 3]), (i32, u32)> = FxHashMap::default();
    let centre = o.bounds.center().as_dvec3();
    let mut volume = 0.0f64;
    for r in o.opaque_ranges() {
        for t in &scene.triangles()[r.start as usize..r.end as usize] {
            let [a, b, c] = t.map(|v| v.as_dvec3() - centre);
            volume += a.dot(b.cross(c));
            for i in 0..3 {
                let (a, b) = (key(t[i]), key(t[(i + 1) % 3]));
                if a != b {
                    let (e, d) = if a < b { ((a, b), 1) } else { ((b, a), -1) };
                    let entry = edges.entry(e).or_insert((0, 0));
                    (entry.0, entry.1) = (entry.0 + d, entry.1 + 1);
                }
            }
        }
    }
    if o.triangle_count() == 0 {
        return (Outside::Unknown, false);
    }
    let closed = !edges.is_empty() && edges.values().all(|&(_, n)| n % 2 == 0);
    let side = if edges.values().any(|&(d, _)| d != 0) {
        Outside::Unknown
    } else if volume > 0.0 {
        Outside::Front
    } else if volume < 0.0 {
        Outside::Back
    } else {
        Outside::Unknown
    };
    (side, closed)
}

/// One object's polygons with their planes and spheres, split into
/// clusters by halving along the longest axis of their centres.
struct ObjectSurfaces {
    polygons: Vec<Polygon>,
    /// Ranges of `polygons`, after it was reordered cluster by cluster,
    /// and whether they are proxies' faces.
    clusters: Vec<(Range<usize>, bool)>,
    outside: Outside,
}

/// A polygon being built: corners, plane, centre and radius.
type Polygon = (Vec<DVec3>, Plane, DVec3, f64);

/// The faces of box `b`, normals out.
fn faces(b: &Aabb) -> impl Iterator<Item = Polygon> + '_ {
    let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
    (0..3).flat_map(move |axis| {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        [(lo, -1.0), (hi, 1.0)].into_iter().filter_map(move |(at, sign)| {
            let corner = |a: f64, b: f64| {
                let mut c = DVec3::ZERO;
                (c[axis], c[u], c[v]) = (at[axis], a, b);
                c
            };
            let corners = vec![
                corner(lo[u], lo[v]),
                corner(hi[u], lo[v]),
                corner(hi[u], hi[v]),
                corner(lo[u], hi[v]),
            ];
            let mut normal = DVec3::ZERO;
            normal[axis] = sign;
            let plane = Plane::from_point_normal(corners[0], normal)?;
            let (centre, radius) = sphere(&corners);
            Some((corners, plane, centre, radius))
        })
    })
}

fn split(polygons: &mut [Polygon], at: usize, out: &mut Vec<Range<usize>>) {
    if polygons.len() <= CLUSTER {
        // Largest first, so a frame stops at the first too small.
        polygons.sort_by(|a, b| b.3.total_cmp(&a.3));
        out.push(at..at + polygons.len());
        return;
    }
    let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
    for p in polygons.iter() {
        (lo, hi) = (lo.min(p.2), hi.max(p.2));
    }
    let e = hi - lo;
    let axis = if e.x >= e.y && e.x >= e.z { 0 } else if e.y >= e.z { 1 } else { 2 };
    let mid = polygons.len() / 2;
    polygons.select_nth_unstable_by(mid, |a, b| a.2[axis].total_cmp(&b.2[axis]));
    let (left, right) = polygons.split_at_mut(mid);
    split(left, at, out);
    split(right, at + mid, out);
}

impl Surfaces {
    /// The surfaces of `scene`'s static objects, and the faces of their
    /// `proxies`.
    pub fn build(scene: &Scene, proxies: &Proxies) -> Surfaces {
        let per_object: Vec<ObjectSurfaces> = scene
            .objects()
            .par_iter()
            .enumerate()
            .map(|(id, o)| {
                if !o.is_static() {
                    return ObjectSurfaces {
                        polygons: Vec::new(),
                        clusters: Vec::new(),
                        outside: Outside::Unknown,
                    };
                }
                let mut polygons: Vec<_> = object_polygons(scene, o)
                    .into_iter()
                    .filter_map(|p| {
                        // Merged corners are triangle corners; kept in f32
                        // only if that is exact (drawing less is safe).
                        if p.vertices.iter().any(|v| v.as_vec3().as_dvec3() != *v) {
                            return None;
                        }
                        let plane = p.plane()?;
                        let (centre, radius) = sphere(&p.vertices);
                        Some((p.vertices, plane, centre, radius))
                    })
                    .collect();
                let mut ranges = Vec::new();
                split(&mut polygons, 0, &mut ranges);
                let mut clusters: Vec<_> = ranges.into_iter().map(|r| (r, false)).collect();
                // A proxy is worth its faces only where it is larger than
                // the object's largest polygon, which hides as much already.
                let own = polygons.iter().map(|p| area(&p.0)).fold(0.0, f64::max);
                let mut faces: Vec<Polygon> = proxies
                    .of(id)
                    .iter()
                    .filter(|b| {
                        let e = b.extent().as_dvec3();
                        (e.x * e.y).max(e.y * e.z).max(e.z * e.x) > own
                    })
                    .flat_map(faces)
                    .collect();
                let (at, mut ranges) = (polygons.len(), Vec::new());
                if !faces.is_empty() {
                    split(&mut faces, at, &mut ranges);
                }
                polygons.extend(faces);
                clusters.extend(ranges.into_iter().map(|r| (r, true)));
                let (outside, _) = outside(scene, o);
                ObjectSurfaces {
                    polygons,
                    clusters,
                    outside,
                }
            })
            .collect();
        let mut out = Surfaces::default();
        for object in per_object {
            out.outside.push(object.outside);
            let first = out.clusters.len() as u32;
            for (range, inner) in object.clusters {
                let start = out.surfaces.len() as u32;
                let mut bounds = Aabb::EMPTY;
                let mut largest = 0.0f64;
                for (corners, plane, centre, radius) in &object.polygons[range] {
                    let at = out.corners.len() as u32;
                    out.surfaces.push(Surface {
                        corners: at..at + corners.len() as u32,
                        plane: *plane,
                        thickness: thickness(corners),
                        centre: *centre,
                        radius: *radius,
                        breadth: area(corners) / (4.0 * radius * radius),
                    });
                    out.corners.extend(corners.iter().map(|c| c.as_vec3()));
                    bounds.merge(&Aabb::enclosing(centre - *radius, centre + *radius));
                    largest = largest.max(*radius);
                }
                out.clusters.push(Cluster {
                    surfaces: start..out.surfaces.len() as u32,
                    bounds,
                    largest,
                    inner,
                });
            }
            out.by_object.push(first..out.clusters.len() as u32);
        }
        out
    }

    /// The clusters of object `id`.
    pub fn clusters_of(&self, id: u32) -> &[Cluster] {
        let r = &self.by_object[id as usize];
        &self.clusters[r.start as usize..r.end as usize]
    }

    /// The surfaces of cluster `c`, largest first.
    pub fn of_cluster(&self, c: &Cluster) -> &[Surface] {
        &self.surfaces[c.surfaces.start as usize..c.surfaces.end as usize]
    }

    /// Which side of object `id`'s surfaces is its outside.
    pub fn outside(&self, id: u32) -> Outside {
        self.outside[id as usize]
    }

    /// The corners of `s`.
    pub fn corners(&self, s: &Surface) -> &[Vec3] {
        &self.corners[s.corners.start as usize..s.corners.end as usize]
    }

    /// Number of surfaces.
    pub fn len(&self) -> usize {
        self.surfaces.len()
    }
}
