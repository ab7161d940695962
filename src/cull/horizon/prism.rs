//! Convex vertical prisms (CVPs) inside objects (Downs et al. §3.1–3.2).
//!
//! A prism is a convex footprint in (x, z) standing on the scene's ground
//! level `G` (the lowest point of any object) up to a `top`. The horizon may
//! only use a prism that lies inside its object's solid; this module builds
//! prisms and *proves* that, from the object's opaque surfaces alone:
//!
//! 1. The object's opaque triangles are sorted by plane: vertical ones are
//!    walls, horizontal ones roofs.
//! 2. The largest wall triangle fixes a frame (u, w) of the building (a city
//!    rotated 15° keeps its walls on the frame's axes); the walls' lines cut
//!    the footprint into a grid of cells.
//! 3. The sweep from the ground up (§3.2): each cell takes the highest roof
//!    that covers all of it, and steps down to the next while step 4 fails.
//! 4. Proof: the cells with a height make a union `U` of boxes on the ground.
//!    Each face of `U`'s boundary above the ground (each cell's top, and each
//!    side where the neighbour is lower or outside) must be covered by the
//!    object's triangles in that face's plane: no edge on the boundary of
//!    those triangles (used an odd number of times) enters the face, so the
//!    number of triangles over its points is the same everywhere mod 2, and
//!    it is odd at one point. Then `U`'s whole boundary above `G` is opaque
//!    surface, so a ray from an eye outside the object's box and not below
//!    `G` crosses that surface before it reaches the inside of `U`.
//! 5. The largest rectangles of cells at a few heights (the paper's "maximum
//!    rectangle that can be inscribed") become up to [`MAX_PRISMS`] prisms,
//!    shrunk by a margin so that they lie strictly inside `U`.
//!
//! Containment and coplanarity are checked to a few `f32` ulps of the
//! object's coordinates: the geometry is no more exact than that. An object
//! with nothing provable (an open mesh, a floating box, a see-through shell,
//! a sphere) gets no prism and only ever occludes nothing.

use rustc_hash::FxHashMap;
use std::ops::Range;

use glam::{DVec2, DVec3, Vec3};
use rayon::prelude::*;

use crate::scene::{BakeCache, Object, Scene};

/// At most this many prisms per object (the paper: "a small set").
pub const MAX_PRISMS: usize = 3;

/// Objects whose walls cut the footprint into more lines than this per axis
/// are not searched (detailed models: the grid would grow quadratically).
const MAX_LINES: usize = 16;

/// Prisms are shrunk by this share of their object's size (at least 8
/// containment tolerances), so that they lie strictly inside the proven
/// union: a smaller prism hides less, never more.
const SHRINK: f64 = 1e-5;

/// A triangle whose unit normal's vertical part is at most this is a wall
/// candidate. Classifying only proposes cells; the coverage proof (step 4)
/// is what a prism's soundness rests on, so a looser or tighter slope
/// changes which prisms are found, never whether they are inside.
const WALL_SLOPE: f64 = 1e-4;

/// Unit normals within this of a roof's (vertical) or a wall line's axis
/// count as aligned with it; like [`WALL_SLOPE`], only a proposal.
const ALIGNED: f64 = 1e-7;

/// A convex vertical prism from the ground level up to `top`, scene-local.
#[derive(Clone, Debug, PartialEq)]
pub struct Prism {
    /// The footprint's corners in (x, z), in order around it.
    pub footprint: Vec<DVec2>,
    /// Height of the prism's top.
    pub top: f64,
    /// Per corner, where it moves per unit of shrinking while every edge
    /// survives: `(n₁ + n₂) / (1 + n₁·n₂)` of its edges' inward unit
    /// normals (the point at distance 1 from both edge lines).
    bisectors: Vec<DVec2>,
    /// Shrinking by less than this keeps every edge (running the way it
    /// did), so the corners above give the erosion; 0 when unknown.
    fast_limit: f64,
}

/// A shrunk footprint's corners: on the stack for the few-cornered
/// footprints prisms have, so a sweep allocates nothing per mask.
pub enum Footprint {
    /// Up to [`SMALL`] corners.
    Small([DVec2; SMALL], usize),
    /// More.
    Large(Vec<DVec2>),
}

/// Corners a [`Footprint::Small`] holds.
pub const SMALL: usize = 8;

impl Footprint {
    /// The corners in order.
    pub fn corners(&self) -> &[DVec2] {
        match self {
            Footprint::Small(c, n) => &c[..*n],
            Footprint::Large(v) => v,
        }
    }
}

impl Prism {
    /// A prism of a convex footprint (corners in order, either way round)
    /// up to `top`.
    pub fn new(footprint: Vec<DVec2>, top: f64) -> Prism {
        let n = footprint.len();
        let (mut bisectors, mut fast_limit) = (vec![DVec2::ZERO; n], 0.0);
        if let Some(normals) = inward_normals(&footprint) {
            let mut ok = true;
            for i in 0..n {
                let (a, b) = (normals[(i + n - 1) % n], normals[i]);
                let d = 1.0 + a.dot(b);
                // Edges turning back on themselves: no corner to move.
                ok &= d > 1e-9;
                bisectors[i] = (a + b) / d;
            }
            // Edge i from corner i to i + 1 keeps its direction while
            // `|e|² + by (m₊ − m)·e > 0`.
            fast_limit = if ok { f64::INFINITY } else { 0.0 };
            for i in 0..n {
                let e = footprint[(i + 1) % n] - footprint[i];
                let shrink_rate = -(bisectors[(i + 1) % n] - bisectors[i]).dot(e);
                if shrink_rate > 0.0 {
                    fast_limit = f64::min(fast_limit, e.length_squared() / shrink_rate);
                }
            }
            // Just below the exact limit, where an edge shrinks to nothing.
            fast_limit *= 1.0 - 1e-6;
        }
        Prism {
            footprint,
            top,
            bisectors,
            fast_limit,
        }
    }

    /// The footprint with every edge moved inwards by `by` (its erosion by
    /// a disc of radius `by`), or `None` when nothing is left: a footprint
    /// point of the result has the whole disc of radius `by` around it in
    /// the footprint. Rounding is the caller's to cover (ask for more).
    ///
    /// While every edge survives (`by` well under the footprint's size,
    /// the usual case), the erosion of a convex polygon is the polygon of
    /// its consecutive offset lines' intersections: each corner moves
    /// along its bisector, found once per prism. Otherwise the footprint
    /// is clipped by each offset line.
    pub fn shrunk_footprint(&self, by: f64) -> Option<Footprint> {
        let f = &self.footprint;
        let n = f.len();
        if n < 3 {
            return None;
        }
        if by < self.fast_limit && n <= SMALL {
            let mut out = [DVec2::ZERO; SMALL];
            for (o, (p, m)) in out.iter_mut().zip(f.iter().zip(&self.bisectors)) {
                *o = *p + *m * by;
            }
            return Some(Footprint::Small(out, n));
        }
        let normals = inward_normals(f)?;
        let mut part = f.clone();
        for (i, m) in normals.iter().enumerate() {
            let a = f[i];
            // Keep where `m · (p − a) ≥ by`.
            let dist = |p: DVec2| m.dot(p - a) - by;
            let mut next = Vec::with_capacity(part.len() + 1);
            for k in 0..part.len() {
                let (p, q) = (part[k], part[(k + 1) % part.len()]);
                let (dp, dq) = (dist(p), dist(q));
                if dp >= 0.0 {
                    next.push(p);
                }
                if (dp >= 0.0) != (dq >= 0.0) {
                    next.push(p + (q - p) * (dp / (dp - dq)));
                }
            }
            if next.len() < 3 {
                return None;
            }
            part = next;
        }
        Some(Footprint::Large(part))
    }
}

/// The inward unit normal of each edge (corner i to i + 1) of a convex
/// footprint; `None` when an edge has no length.
fn inward_normals(f: &[DVec2]) -> Option<Vec<DVec2>> {
    let n = f.len();
    if n < 3 {
        return None;
    }
    let centre = f.iter().copied().sum::<DVec2>() / n as f64;
    (0..n)
        .map(|i| {
            let (a, b) = (f[i], f[(i + 1) % n]);
            let m = (b - a).perp().try_normalize()?;
            Some(if m.dot(centre - a) < 0.0 { -m } else { m })
        })
        .collect()
}

/// What a bake of the prisms depends on beyond the scene file: change it
/// whenever how prisms are proven changes, so that old bakes are rebuilt.
const BAKE_PARAMS: &str = "prisms-v1";

/// The bake of a scene's prisms (or of why it has none): a tag byte (1:
/// prisms, 0: the reason, UTF-8); then the ground (`f64`), a `u32` count
/// of prisms, each a `u32` count of footprint corners, two `f64` each, and
/// its top (`f64`); then a `u32` count of objects, each its range of
/// prisms (two `u32`). Little-endian.
fn encode(found: &Result<Prisms, String>) -> Vec<u8> {
    let mut out = Vec::new();
    match found {
        Err(reason) => {
            out.push(0);
            out.extend_from_slice(reason.as_bytes());
        }
        Ok(p) => {
            out.push(1);
            out.extend_from_slice(&p.ground.to_le_bytes());
            out.extend_from_slice(&(p.prisms.len() as u32).to_le_bytes());
            for prism in &p.prisms {
                out.extend_from_slice(&(prism.footprint.len() as u32).to_le_bytes());
                for c in &prism.footprint {
                    out.extend_from_slice(&c.x.to_le_bytes());
                    out.extend_from_slice(&c.y.to_le_bytes());
                }
                out.extend_from_slice(&prism.top.to_le_bytes());
            }
            out.extend_from_slice(&(p.ranges.len() as u32).to_le_bytes());
            for r in &p.ranges {
                out.extend_from_slice(&r.start.to_le_bytes());
                out.extend_from_slice(&r.end.to_le_bytes());
            }
        }
    }
    out
}

fn decode(bytes: &[u8]) -> Result<Result<Prisms, String>, String> {
    let (&tag, rest) = bytes.split_first().ok_or("prisms: empty")?;
    if tag == 0 {
        let reason = std::str::from_utf8(rest).map_err(|_| "prisms: a reason not UTF-8")?;
        return Ok(Err(reason.to_string()));
    }
    let mut at = 0usize;
    let mut take = |n: usize| -> Result<&[u8], String> {
        let part = rest.get(at..at + n).ok_or("prisms: truncated")?;
        at += n;
        Ok(part)
    };
    let f64_of = |b: &[u8]| f64::from_le_bytes(b.try_into().expect("8 bytes"));
    let u32_of = |b: &[u8]| u32::from_le_bytes(b.try_into().expect("4 bytes"));
    let ground = f64_of(take(8)?);
    let count = u32_of(take(4)?);
    let mut prisms = Vec::with_capacity(count.min(1 << 20) as usize);
    for _ in 0..count {
        let corners = u32_of(take(4)?);
        let mut footprint = Vec::with_capacity(corners.min(1 << 16) as usize);
        for _ in 0..corners {
            let x = f64_of(take(8)?);
            let z = f64_of(take(8)?);
            footprint.push(DVec2::new(x, z));
        }
        let top = f64_of(take(8)?);
        prisms.push(Prism::new(footprint, top));
    }
    let objects = u32_of(take(4)?);
    let mut ranges = Vec::with_capacity(objects.min(1 << 24) as usize);
    for _ in 0..objects {
        let start = u32_of(take(4)?);
        let end = u32_of(take(4)?);
        if start > end || end > count {
            return Err("prisms: a range outside the list".into());
        }
        ranges.push(start..end);
    }
    if at != rest.len() {
        return Err("prisms: bytes left over".into());
    }
    Ok(Ok(Prisms {
        ground,
        prisms,
        ranges,
    }))
}

/// The prisms of a scene's objects, and the ground level they stand on.
#[derive(Clone, Debug, PartialEq)]
pub struct Prisms {
    ground: f64,
    prisms: Vec<Prism>,
    /// Per object id, its range of `prisms`.
    ranges: Vec<Range<u32>>,
}

impl Prisms {
    /// Prisms for every object of `scene` that provably holds some, or why
    /// the scene has none (the reason `/scenes` gives for not listing `horizon`).
    pub fn find(scene: &Scene) -> Result<Prisms, String> {
        let ground = scene
            .objects()
            .iter()
            .filter(|o| !o.bounds.is_empty())
            .map(|o| o.bounds.min.y as f64)
            .fold(f64::INFINITY, f64::min);
        if !ground.is_finite() {
            return Err("the scene has no geometry".into());
        }
        let per_object: Vec<Vec<Prism>> = scene
            .objects()
            .par_iter()
            .map(|o| object_prisms(scene, o, ground))
            .collect();
        let mut prisms = Vec::new();
        let mut ranges = Vec::with_capacity(per_object.len());
        for list in per_object {
            let start = prisms.len() as u32;
            prisms.extend(list);
            ranges.push(start..prisms.len() as u32);
        }
        if prisms.is_empty() {
            return Err(format!(
                "no object is an opaque closed solid standing on the ground (y = {:.6} locally): \
                 no convex vertical prisms, so the scene is not a height field for occlusion horizons",
                ground
            ));
        }
        Ok(Prisms {
            ground,
            prisms,
            ranges,
        })
    }

    /// [`Prisms::find`], read from `cache` when an earlier run baked the
    /// prisms of this scene file (or the reason it has none), and baked
    /// there when not.
    pub fn find_baked(scene: &Scene, cache: &BakeCache) -> Result<Prisms, String> {
        cache
            .load_or_build(
                scene,
                "prisms",
                BAKE_PARAMS,
                || Prisms::find(scene),
                encode,
                decode,
            )
            .0
    }

    /// The ground level `G`: no object reaches below it; every prism stands on it.
    pub fn ground(&self) -> f64 {
        self.ground
    }

    /// The prisms of object `id`.
    pub fn of(&self, id: u32) -> &[Prism] {
        let r = &self.ranges[id as usize];
        &self.prisms[r.start as usize..r.end as usize]
    }

    /// How many prisms in all.
    pub fn len(&self) -> usize {
        self.prisms.len()
    }

    /// Whether there are none (never, for a built `Prisms`).
    pub fn is_empty(&self) -> bool {
        self.prisms.is_empty()
    }
}

/// An edge by its endpoints' exact bits, the smaller first.
type EdgeKey = ([u32; 3], [u32; 3]);

/// The object's opaque triangles lying in one plane (a wall line or a roof
/// height), in 2D coordinates of that plane, with their mod-2 boundary.
struct Sheet {
    triangles: Vec<[DVec2; 3]>,
    /// Edges used an odd number of times: where the sheet may end.
    boundary: Vec<[DVec2; 2]>,
}

impl Sheet {
    /// The triangles within `tol` of the plane through `origin` spanned by
    /// the unit vectors `e1`, `e2`.
    fn new(tris: &[[Vec3; 3]], origin: DVec3, e1: DVec3, e2: DVec3, tol: f64) -> Sheet {
        let normal = e1.cross(e2);
        let flat = |v: Vec3| {
            let d = v.as_dvec3() - origin;
            DVec2::new(d.dot(e1), d.dot(e2))
        };
        let mut triangles = Vec::new();
        let mut edges: FxHashMap<EdgeKey, (u32, [DVec2; 2])> = FxHashMap::default();
        for t in tris {
            if !t
                .iter()
                .all(|v| normal.dot(v.as_dvec3() - origin).abs() <= tol)
            {
                continue;
            }
            let f = t.map(flat);
            if (f[1] - f[0]).perp_dot(f[2] - f[0]) == 0.0 {
                continue; // covers nothing
            }
            triangles.push(f);
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let (ka, kb) = (
                    a.to_array().map(f32::to_bits),
                    b.to_array().map(f32::to_bits),
                );
                let key = if ka <= kb { (ka, kb) } else { (kb, ka) };
                edges.entry(key).or_insert((0, [f[k], f[(k + 1) % 3]])).0 += 1;
            }
        }
        let boundary = edges
            .into_values()
            .filter(|(n, _)| n % 2 == 1)
            .map(|(_, e)| e)
            .collect();
        Sheet {
            triangles,
            boundary,
        }
    }

    /// Whether the sheet covers the rectangle `[lo, hi]` (plane coordinates)
    /// but for a `tol` rim: no boundary edge enters the rectangle shrunk by
    /// `tol`, so the number of triangles over its points is constant mod 2,
    /// and it is odd at a point clear of every edge.
    fn covers(&self, lo: DVec2, hi: DVec2, tol: f64) -> bool {
        let (lo, hi) = (lo + DVec2::splat(tol), hi - DVec2::splat(tol));
        if !(lo.x < hi.x && lo.y < hi.y) || self.triangles.is_empty() {
            return false;
        }
        if self
            .boundary
            .iter()
            .any(|&[a, b]| segment_meets_box(a, b, lo, hi))
        {
            return false;
        }
        // A few fixed points inside, off both diagonals but the first (a
        // quad's split); the first one clear of all edges decides.
        for f in [
            (0.5, 0.5),
            (0.31, 0.57),
            (0.73, 0.41),
            (0.17, 0.29),
            (0.61, 0.83),
        ] {
            let p = lo + (hi - lo) * DVec2::new(f.0, f.1);
            let mut count = 0;
            let mut clear = true;
            for t in &self.triangles {
                let d = [0, 1, 2].map(|k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    (b - a).perp_dot(p - a) / (b - a).length()
                });
                if d.iter().any(|x| x.abs() <= tol) {
                    clear = false;
                    break;
                }
                if d.iter().all(|&x| x > 0.0) || d.iter().all(|&x| x < 0.0) {
                    count += 1;
                }
            }
            if clear {
                return count % 2 == 1;
            }
        }
        false
    }
}

/// Whether the segment `a b` shares a point with the closed box `[lo, hi]`
/// (Liang–Barsky clipping).
fn segment_meets_box(a: DVec2, b: DVec2, lo: DVec2, hi: DVec2) -> bool {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-d.x, a.x - lo.x),
        (d.x, hi.x - a.x),
        (-d.y, a.y - lo.y),
        (d.y, hi.y - a.y),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return false;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    t0 <= t1
}

/// Step 1–5 of the module docs for one object.
fn object_prisms(scene: &Scene, object: &Object, ground: f64) -> Vec<Prism> {
    let b = object.bounds;
    if !object.is_static() || b.min.y as f64 != ground {
        // Walls must reach the ground level exactly, or rays pass below them.
        return Vec::new();
    }
    let magnitude = b.min.abs().max(b.max.abs()).max_element() as f64;
    let size = b.extent().max_element() as f64;
    let tol = 4.0 * f32::EPSILON as f64 * magnitude.max(size);
    let margin = (SHRINK * size).max(8.0 * tol);
    let tris: Vec<[Vec3; 3]> = (object.triangles.start..object.triangles.end)
        .filter(|t| !object.see_through.iter().any(|r| r.contains(t)))
        .map(|t| scene.triangles()[t as usize])
        .collect();
    // Step 1: vertical and horizontal triangles, by their planes.
    let normal = |t: &[Vec3; 3]| {
        (t[1] - t[0])
            .as_dvec3()
            .cross((t[2] - t[0]).as_dvec3())
            .try_normalize()
    };
    let vertical: Vec<(DVec2, &[Vec3; 3], f64)> = tris
        .iter()
        .filter_map(|t| {
            let n = normal(t)?;
            let h = DVec2::new(n.x, n.z);
            let area = (t[1] - t[0])
                .as_dvec3()
                .cross((t[2] - t[0]).as_dvec3())
                .length();
            (n.y.abs() <= WALL_SLOPE).then(|| (h.normalize(), t, area))
        })
        .collect();
    let mut heights: Vec<f64> = tris
        .iter()
        .filter(|t| normal(t).is_some_and(|n| n.y.abs() >= 1.0 - ALIGNED))
        .map(|t| t.iter().map(|v| v.y as f64).sum::<f64>() / 3.0)
        .filter(|&y| y > ground + tol)
        .collect();
    heights.sort_by(|a, b| b.total_cmp(a));
    heights.dedup_by(|a, b| (*a - *b).abs() <= tol);
    // Step 2: the frame of the largest wall triangle, and the wall lines.
    let Some(&(axis_u, _, _)) = vertical.iter().max_by(|p, q| p.2.total_cmp(&q.2)) else {
        return Vec::new();
    };
    let axis_w = axis_u.perp();
    let xz = |u: f64, w: f64| axis_u * u + axis_w * w;
    let at = |u: f64, w: f64, y: f64| {
        let p = xz(u, w);
        DVec3::new(p.x, y, p.y)
    };
    let lines = |axis: DVec2| -> Option<Vec<f64>> {
        let mut v: Vec<f64> = vertical
            .iter()
            .filter(|(n, _, _)| n.dot(axis).abs() >= 1.0 - ALIGNED)
            .map(|(_, t, _)| {
                t.iter()
                    .map(|p| axis.dot(DVec2::new(p.x as f64, p.z as f64)))
                    .sum::<f64>()
                    / 3.0
            })
            .collect();
        v.sort_by(f64::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() <= tol);
        (2..=MAX_LINES).contains(&v.len()).then_some(v)
    };
    let (Some(us), Some(ws)) = (lines(axis_u), lines(axis_w)) else {
        return Vec::new();
    };
    let (nu, nw) = (us.len() - 1, ws.len() - 1);
    let y3 = DVec3::Y;
    let (u3, w3) = (at(1.0, 0.0, 0.0), at(0.0, 1.0, 0.0));
    // One sheet per wall line (coordinates: along the wall, height) and per
    // roof height (coordinates: u, w).
    let u_sheets: Vec<Sheet> = us
        .iter()
        .map(|&u| Sheet::new(&tris, at(u, 0.0, 0.0), w3, y3, tol))
        .collect();
    let w_sheets: Vec<Sheet> = ws
        .iter()
        .map(|&w| Sheet::new(&tris, at(0.0, w, 0.0), u3, y3, tol))
        .collect();
    let roofs: Vec<(f64, Sheet)> = heights
        .iter()
        .map(|&y| (y, Sheet::new(&tris, DVec3::new(0.0, y, 0.0), u3, w3, tol)))
        .collect();
    // Step 3: the roofs covering each cell, highest first; a cell starts at
    // the highest and steps down while its faces are not provably closed.
    let covering: Vec<Vec<f64>> = (0..nu * nw)
        .map(|c| {
            let (i, j) = (c % nu, c / nu);
            roofs
                .iter()
                .filter(|(_, sheet)| {
                    sheet.covers(
                        DVec2::new(us[i], ws[j]),
                        DVec2::new(us[i + 1], ws[j + 1]),
                        tol,
                    )
                })
                .map(|(y, _)| *y)
                .collect()
        })
        .collect();
    let mut choice = vec![0usize; nu * nw];
    let height = |choice: &[usize], c: usize| covering[c].get(choice[c]).copied();
    // Step 4: lower (or drop) cells with a side face no wall covers, until stable.
    let h = |choice: &[usize], i: isize, j: isize| -> f64 {
        if i < 0 || j < 0 || i >= nu as isize || j >= nw as isize {
            return ground;
        }
        height(choice, j as usize * nu + i as usize).unwrap_or(ground)
    };
    loop {
        let mut changed = false;
        for c in 0..nu * nw {
            let Some(top) = height(&choice, c) else {
                continue;
            };
            let (i, j) = (c % nu, c / nu);
            let (ii, jj) = (i as isize, j as isize);
            // (neighbour, the wall sheet, the face's span along that sheet)
            let sides = [
                (ii - 1, jj, &u_sheets[i], (ws[j], ws[j + 1])),
                (ii + 1, jj, &u_sheets[i + 1], (ws[j], ws[j + 1])),
                (ii, jj - 1, &w_sheets[j], (us[i], us[i + 1])),
                (ii, jj + 1, &w_sheets[j + 1], (us[i], us[i + 1])),
            ];
            let closed = sides.iter().all(|&(ni, nj, sheet, (s0, s1))| {
                let low = h(&choice, ni, nj);
                low >= top || sheet.covers(DVec2::new(s0, low), DVec2::new(s1, top), tol)
            });
            if !closed {
                choice[c] += 1;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let height: Vec<Option<f64>> = (0..nu * nw).map(|c| height(&choice, c)).collect();
    // Step 5: the largest rectangle of cells at each height level.
    let mut levels: Vec<f64> = height.iter().flatten().copied().collect();
    levels.sort_by(|a, b| b.total_cmp(a));
    levels.dedup();
    let mut candidates: Vec<(f64, [usize; 4], f64)> = levels
        .iter()
        .filter_map(|&level| {
            let inside = |i: usize, j: usize| height[j * nu + i].is_some_and(|y| y >= level);
            let mut best: Option<(f64, [usize; 4])> = None;
            for i0 in 0..nu {
                for j0 in 0..nw {
                    if !inside(i0, j0) {
                        continue;
                    }
                    let mut j_end = nw;
                    for i1 in i0..nu {
                        if !inside(i1, j0) {
                            break;
                        }
                        let mut j1 = j0;
                        while j1 + 1 < j_end && inside(i1, j1 + 1) {
                            j1 += 1;
                        }
                        j_end = j1 + 1;
                        let area = (us[i1 + 1] - us[i0]) * (ws[j1 + 1] - ws[j0]);
                        if best.is_none_or(|(a, _)| area > a) {
                            best = Some((area, [i0, j0, i1, j1]));
                        }
                    }
                }
            }
            best.map(|(_, r)| {
                let span = (us[r[2] + 1] - us[r[0]]) + (ws[r[3] + 1] - ws[r[1]]);
                (span * (level - ground), r, level)
            })
        })
        .collect();
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut chosen: Vec<([usize; 4], f64)> = Vec::new();
    for (_, r, level) in candidates {
        let within = |(c, l): &([usize; 4], f64)| {
            c[0] <= r[0] && c[1] <= r[1] && r[2] <= c[2] && r[3] <= c[3] && level <= *l
        };
        if chosen.len() < MAX_PRISMS && !chosen.iter().any(within) {
            chosen.push((r, level));
        }
    }
    chosen
        .into_iter()
        .filter_map(|(r, level)| {
            let (u0, u1) = (us[r[0]] + margin, us[r[2] + 1] - margin);
            let (w0, w1) = (ws[r[1]] + margin, ws[r[3] + 1] - margin);
            let top = level - margin;
            (u0 < u1 && w0 < w1 && top > ground).then(|| {
                Prism::new(
                    vec![xz(u0, w0), xz(u1, w0), xz(u1, w1), xz(u0, w1)],
                    top,
                )
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Baked prisms are the proven ones, bit for bit; so is a baked reason.
    #[test]
    fn baked_prisms_are_the_found_ones() {
        use crate::scene::generate::{CityOptions, OfficeOptions, city, office};
        use crate::scene::{Baked, load_slice};
        let dir = tempfile::tempdir().unwrap();
        let cache = BakeCache::new(dir.path());
        let path = std::path::Path::new("x.glb");
        let city = city(&CityOptions {
            buildings: 60,
            ..CityOptions::default()
        });
        let office = office(&OfficeOptions::default());
        for doc in [city, office] {
            let scene = load_slice("x", &doc.to_glb(), None, path).unwrap();
            let found = Prisms::find(&scene);
            assert_eq!(Prisms::find_baked(&scene, &cache), found);
            let (loaded, how) = cache.load_or_build(
                &scene,
                "prisms",
                BAKE_PARAMS,
                || Err("not built".into()),
                encode,
                decode,
            );
            assert_eq!((loaded, how), (found, Baked::Loaded));
        }
    }

    use crate::scene::SceneBuilder;
    use crate::scene::generate::MeshBuilder;

    fn world(m: MeshBuilder) -> Vec<[DVec3; 3]> {
        m.build(false)
            .triangles()
            .map(|t| t.map(|v| v.as_dvec3()))
            .collect()
    }

    fn cuboid(min: Vec3, max: Vec3, bottom: bool) -> Vec<[DVec3; 3]> {
        let mut m = MeshBuilder::new();
        m.cuboid(min, max, bottom);
        world(m)
    }

    /// A scene of one ground quad (object 0) and the given meshes.
    fn scene(meshes: Vec<Vec<[DVec3; 3]>>) -> Scene {
        let mut b = SceneBuilder::new("t");
        b.begin_object("ground", None);
        let mut g = MeshBuilder::new();
        g.quad(
            Vec3::new(-100.0, 0.0, -100.0),
            Vec3::new(-100.0, 0.0, 100.0),
            Vec3::new(100.0, 0.0, 100.0),
            Vec3::new(100.0, 0.0, -100.0),
        );
        b.add_triangles(world(g), false);
        for (i, m) in meshes.into_iter().enumerate() {
            b.begin_object(format!("b{i}"), None);
            b.add_triangles(m, false);
        }
        b.finish()
    }

    /// The prisms of object `id` in world coordinates: (footprint, top).
    fn prisms_of(s: &Scene, p: &Prisms, id: u32) -> Vec<(Vec<DVec2>, f64)> {
        let o = DVec2::new(s.origin.x, s.origin.z);
        p.of(id)
            .iter()
            .map(|q| {
                (
                    q.footprint.iter().map(|&v| v + o).collect(),
                    q.top + s.origin.y,
                )
            })
            .collect()
    }

    #[test]
    fn a_shrunk_footprint_is_the_erosion_both_ways() {
        let square = Prism::new(
            vec![
                DVec2::new(0.0, 0.0),
                DVec2::new(4.0, 0.0),
                DVec2::new(4.0, 2.0),
                DVec2::new(0.0, 2.0),
            ],
            10.0,
        );
        let s = square.shrunk_footprint(0.5).unwrap();
        assert!(matches!(s, Footprint::Small(..)));
        let want = [
            DVec2::new(0.5, 0.5),
            DVec2::new(3.5, 0.5),
            DVec2::new(3.5, 1.5),
            DVec2::new(0.5, 1.5),
        ];
        for (g, w) in s.corners().iter().zip(want) {
            assert!(g.distance(w) < 1e-12, "{g} {w}");
        }
        // Edges that vanish take the general clip: nothing is left.
        assert!(square.shrunk_footprint(1.5).is_none());
        // A triangle, reversed: the same erosion.
        let tri = Prism::new(
            vec![DVec2::new(0.0, 0.0), DVec2::new(0.0, 6.0), DVec2::new(6.0, 0.0)],
            1.0,
        );
        // Beyond the fast limit the clip answers, the same erosion.
        let big = tri.shrunk_footprint(1.2).unwrap();
        assert!(matches!(big, Footprint::Large(_)) || tri.fast_limit > 1.2);
        let t = tri.shrunk_footprint(0.5).unwrap();
        for c in t.corners() {
            assert!(c.x >= 0.5 - 1e-12 && c.y >= 0.5 - 1e-12, "{c}");
            assert!((c.x + c.y - 6.0) / 2f64.sqrt() <= -0.5 + 1e-12, "{c}");
        }
    }

    #[test]
    fn a_box_on_the_ground_gets_itself_less_a_margin() {
        let s = scene(vec![cuboid(Vec3::ZERO, Vec3::new(10.0, 20.0, 6.0), false)]);
        let p = Prisms::find(&s).expect("a box stands on the ground");
        assert_eq!(p.ground() + s.origin.y, 0.0);
        let prisms = prisms_of(&s, &p, 1);
        assert_eq!(prisms.len(), 1);
        let (footprint, top) = &prisms[0];
        assert!(*top < 20.0 && *top > 19.99, "{top}");
        let (lo, hi) = footprint
            .iter()
            .fold((DVec2::MAX, DVec2::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        assert!(
            lo.x > 0.0 && lo.y > 0.0 && hi.x < 10.0 && hi.y < 6.0,
            "{lo} {hi}"
        );
        assert!(
            lo.x < 0.01 && lo.y < 0.01 && hi.x > 9.99 && hi.y > 5.99,
            "{lo} {hi}"
        );
        assert!(p.of(0).is_empty(), "the ground quad encloses nothing");
    }

    #[test]
    fn open_floating_or_see_through_shells_get_none() {
        let mut open = cuboid(Vec3::ZERO, Vec3::new(10.0, 20.0, 6.0), false);
        open.drain(0..2); // one wall missing
        let floating = cuboid(Vec3::new(20.0, 1.0, 0.0), Vec3::new(30.0, 9.0, 6.0), true);
        let s = scene(vec![open, floating]);
        assert!(Prisms::find(&s).is_err());

        let mut b = SceneBuilder::new("glass");
        b.begin_object("glass", None);
        b.add_triangles(cuboid(Vec3::ZERO, Vec3::splat(5.0), true), true);
        assert!(Prisms::find(&b.finish()).is_err());
    }

    #[test]
    fn an_l_and_a_stepped_tower_stay_inside_their_shape() {
        // An L of outline (0,0) (10,0) (10,4) (4,4) (4,10) (0,10), 12 high.
        let mut m = MeshBuilder::new();
        let outline = [
            (0.0, 0.0),
            (10.0, 0.0),
            (10.0, 4.0),
            (4.0, 4.0),
            (4.0, 10.0),
            (0.0, 10.0),
        ];
        for k in 0..6 {
            let (a, b) = (outline[k], outline[(k + 1) % 6]);
            m.quad(
                Vec3::new(a.0, 0.0, a.1),
                Vec3::new(b.0, 0.0, b.1),
                Vec3::new(b.0, 12.0, b.1),
                Vec3::new(a.0, 12.0, a.1),
            );
        }
        let y = 12.0;
        m.quad(
            Vec3::new(0.0, y, 0.0),
            Vec3::new(0.0, y, 4.0),
            Vec3::new(10.0, y, 4.0),
            Vec3::new(10.0, y, 0.0),
        );
        m.quad(
            Vec3::new(0.0, y, 4.0),
            Vec3::new(0.0, y, 10.0),
            Vec3::new(4.0, y, 10.0),
            Vec3::new(4.0, y, 4.0),
        );
        let l = world(m);
        // A 10 × 5 × 10 base with a 4 × 20 × 4 tower standing on it.
        let mut t = cuboid(Vec3::new(30.0, 0.0, 0.0), Vec3::new(40.0, 5.0, 10.0), false);
        t.extend(cuboid(
            Vec3::new(33.0, 5.0, 3.0),
            Vec3::new(37.0, 25.0, 7.0),
            false,
        ));
        let s = scene(vec![l, t]);
        let p = Prisms::find(&s).expect("both provable");
        let l_prisms = prisms_of(&s, &p, 1);
        assert!(!l_prisms.is_empty());
        for (footprint, top) in &l_prisms {
            assert!(*top < 12.0);
            // A convex footprint with every corner in one arm lies in the L.
            let in_arm = |x1: f64, z1: f64| {
                footprint
                    .iter()
                    .all(|v| v.x > 0.0 && v.y > 0.0 && v.x < x1 && v.y < z1)
            };
            assert!(in_arm(10.0, 4.0) || in_arm(4.0, 10.0), "{footprint:?}");
        }
        let tower = prisms_of(&s, &p, 2);
        assert!(tower.iter().any(|(_, top)| *top > 24.9), "{tower:?}");
        for (footprint, top) in &tower {
            let in_tower = footprint
                .iter()
                .all(|v| v.x > 33.0 && v.x < 37.0 && v.y > 3.0 && v.y < 7.0);
            assert!(*top < 5.0 || in_tower, "{footprint:?} {top}");
        }
    }
}
