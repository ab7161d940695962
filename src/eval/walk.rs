//! Walkthroughs: deterministic camera paths through a scene.
//!
//! - `orbit`: around the scene from outside, looking at its centre.
//! - `street`: eye height above the floor, long straight runs along open
//!   space, turning only when blocked (city streets).
//! - `random`: eye height above the floor, a heading that wanders smoothly
//!   and turns away from walls (interiors as well as streets).
//!
//! **How free space is found.** The floor is the most common height of the
//! topmost horizontal surface over the cells of a plan grid, counting only
//! the lowest quarter of the scene (see `find_floor`). A person occupies the
//! slab from 0.3 m above the floor to 0.2 m above the eye. Every triangle
//! crossing that slab is clipped to it ([`ConvexPolygon::clipped`]) and the
//! cells of a 2D grid over the scene that the clipped part touches are
//! blocked (its corners, points along its edges at half a cell, and the
//! cells whose centres it covers). Triangles, not boxes: one object's box may
//! span a whole atrium. A distance transform gives each free cell its
//! clearance; a walker stands only where the clearance is at least 0.3 m.

use glam::{DVec2, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::geom::{Camera, ConvexPolygon, Plane};
use crate::scene::Scene;

/// The kind of walkthrough.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WalkKind {
    /// Long straight runs at eye height.
    Street,
    /// Around the scene from outside, looking at its centre.
    Orbit,
    /// A smoothly wandering path at eye height.
    Random,
    /// Unrelated views, as an occlusion culler's benchmark takes them: eyes
    /// uniform in the scene's bounds, headings uniform, pitch uniform
    /// within ±0.6 rad. No frame follows from the last.
    Views,
}

impl WalkKind {
    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            WalkKind::Street => "street",
            WalkKind::Orbit => "orbit",
            WalkKind::Random => "random",
            WalkKind::Views => "views",
        }
    }

    /// Whether each frame follows from the last, as a session's do (all
    /// but `views`).
    pub fn follows_on(self) -> bool {
        self != WalkKind::Views
    }
}

impl std::str::FromStr for WalkKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "street" => Ok(WalkKind::Street),
            "orbit" => Ok(WalkKind::Orbit),
            "random" => Ok(WalkKind::Random),
            "views" => Ok(WalkKind::Views),
            _ => Err(format!(
                "unknown walk '{s}'; walks: street, orbit, random, views"
            )),
        }
    }
}

/// What a walkthrough is made of.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkParams {
    /// Kind of path.
    pub kind: WalkKind,
    /// Number of cameras.
    pub frames: usize,
    /// Seed: the same seed gives the same path.
    pub seed: u64,
    /// Image size of every camera.
    pub viewport: [u32; 2],
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Eye height above the floor, metres.
    pub eye_height: f64,
}

impl Default for WalkParams {
    fn default() -> Self {
        WalkParams {
            kind: WalkKind::Street,
            frames: 100,
            seed: 1,
            viewport: [1024, 768],
            fov_y_deg: 60.0,
            eye_height: 1.7,
        }
    }
}

/// Why no walkthrough could be made.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum WalkError {
    /// The scene has no geometry.
    #[error("the scene has no geometry to walk through")]
    Empty,
    /// No place at eye height has 0.3 m of clearance.
    #[error("no free space at eye height ({0}): try --walk orbit")]
    NoFreeSpace(String),
}

/// Cameras along a walkthrough of `scene`, in world coordinates.
pub fn walk(scene: &Scene, p: &WalkParams) -> Result<Vec<Camera>, WalkError> {
    let b = scene.bounds();
    if b.is_empty() {
        return Err(WalkError::Empty);
    }
    let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
    let diagonal = (hi - lo).length().max(1e-3);
    let template = Camera {
        fov_y_deg: p.fov_y_deg,
        aspect: p.viewport[0] as f64 / p.viewport[1] as f64,
        near: (diagonal * 1e-5).clamp(1e-4, 0.1),
        far: diagonal * 4.0,
        viewport: p.viewport,
        ..Camera::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let local = match p.kind {
        WalkKind::Orbit => orbit(lo, hi, p.frames, &mut rng),
        WalkKind::Views => views(lo, hi, p.frames, &mut rng),
        WalkKind::Street | WalkKind::Random => {
            let grid = FreeSpace::new(scene, p.eye_height);
            grid.walk(p.kind, p.frames, &mut rng)?
        }
    };
    Ok(local
        .into_iter()
        .map(|(eye, forward)| Camera {
            eye: eye + scene.origin,
            forward,
            ..template
        })
        .collect())
}

/// `frames` cameras `step` apart along the path `cameras` trace (a client
/// replaying a walk at its own speed: `step` = speed / frame rate). Each
/// looks along the walk's camera it lies behind; past the path's end the
/// last camera repeats. The path's own steps are 0.5–2 m.
pub fn resample(cameras: &[Camera], step: f64, frames: usize) -> Vec<Camera> {
    let Some(&last) = cameras.last() else {
        return Vec::new();
    };
    let mut out = Vec::with_capacity(frames);
    // Distance along the path at the current segment's start.
    let (mut seg, mut at) = (0, 0.0);
    for i in 0..frames {
        let want = step * i as f64;
        while seg + 1 < cameras.len() {
            let len = cameras[seg].eye.distance(cameras[seg + 1].eye);
            if at + len > want {
                break;
            }
            at += len;
            seg += 1;
        }
        if seg + 1 >= cameras.len() {
            out.push(last);
            continue;
        }
        let (a, b) = (&cameras[seg], &cameras[seg + 1]);
        let len = a.eye.distance(b.eye);
        let t = if len > 0.0 { (want - at) / len } else { 0.0 };
        out.push(Camera {
            eye: a.eye.lerp(b.eye, t),
            ..*a
        });
    }
    out
}

fn orbit(lo: DVec3, hi: DVec3, frames: usize, rng: &mut ChaCha8Rng) -> Vec<(DVec3, DVec3)> {
    let center = (lo + hi) * 0.5;
    let radius = (hi - lo).length() * 0.5;
    let start = rng.random_range(0.0..std::f64::consts::TAU);
    (0..frames)
        .map(|i| {
            let a = start + std::f64::consts::TAU * i as f64 / frames.max(1) as f64;
            let eye =
                center + DVec3::new(a.cos() * radius * 1.5, radius * 0.4, a.sin() * radius * 1.5);
            (eye, center - eye)
        })
        .collect()
}

/// Most pitch of [`WalkKind::Views`], radians.
const VIEWS_PITCH: f64 = 0.6;

fn views(lo: DVec3, hi: DVec3, frames: usize, rng: &mut ChaCha8Rng) -> Vec<(DVec3, DVec3)> {
    (0..frames)
        .map(|_| {
            let eye = DVec3::new(
                rng.random_range(lo.x..=hi.x),
                rng.random_range(lo.y..=hi.y),
                rng.random_range(lo.z..=hi.z),
            );
            let yaw = rng.random_range(0.0..std::f64::consts::TAU);
            let pitch = rng.random_range(-VIEWS_PITCH..=VIEWS_PITCH);
            let forward = DVec3::new(
                yaw.cos() * pitch.cos(),
                pitch.sin(),
                yaw.sin() * pitch.cos(),
            );
            (eye, forward)
        })
        .collect()
}

/// How far a cell's floor may be from the walk's floor and still be walked
/// on (a kerb, a door sill), metres.
const STEP: f64 = 0.3;

/// Clearance a walker keeps from anything at body height, metres: about a
/// person's radius, so a 1 m door is passable.
const CLEARANCE: f64 = 0.3;

/// A 2D grid over the scene's footprint (x, z), scene-local.
struct FreeSpace {
    origin: DVec2,
    cell: f64,
    nx: usize,
    nz: usize,
    /// Distance in metres from each cell to the nearest blocked cell.
    clearance: Vec<f64>,
    floor: f64,
    eye_height: f64,
}

impl FreeSpace {
    /// Free space on the scene's most open floor: of the common floor
    /// heights, the one whose largest connected region has the most
    /// clearance (Sponza's courtyard rather than its arcades).
    fn new(scene: &Scene, eye_height: f64) -> FreeSpace {
        let b = scene.bounds();
        let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
        let cell = ((hi.x - lo.x).max(hi.z - lo.z) / 2048.0).max(0.1);
        let nx = (((hi.x - lo.x) / cell).ceil() as usize).max(1);
        let nz = (((hi.z - lo.z) / cell).ceil() as usize).max(1);
        let openness = |g: &FreeSpace| {
            g.largest_region()
                .iter()
                .map(|&i| g.clearance[i])
                .fold(0.0, f64::max)
        };
        let top = floor_tops(scene, lo, hi, cell, nx, nz);
        floor_candidates(&top, lo.y)
            .into_iter()
            .map(|floor| FreeSpace::at_floor(scene, &top, floor, eye_height, lo, cell, nx, nz))
            .max_by(|a, b| openness(a).total_cmp(&openness(b)))
            .expect("at least one candidate floor")
    }

    #[allow(clippy::too_many_arguments)]
    fn at_floor(
        scene: &Scene,
        top: &[f64],
        floor: f64,
        eye_height: f64,
        lo: DVec3,
        cell: f64,
        nx: usize,
        nz: usize,
    ) -> FreeSpace {
        // Only cells whose floor is this floor can be stood in: not the void
        // around a rotated city, not a lower arcade seen from a raised courtyard.
        let mut blocked: Vec<bool> = top.iter().map(|&t| (t - floor).abs() > STEP).collect();
        let (slab_lo, slab_hi) = (floor + 0.3, floor + eye_height + 0.2);
        let below = Plane {
            normal: DVec3::Y,
            d: -slab_lo,
        };
        let above = Plane {
            normal: DVec3::NEG_Y,
            d: slab_hi,
        };
        let origin = DVec2::new(lo.x, lo.z);
        let mut mark = |p: DVec3| {
            let (i, k) = (
                ((p.x - origin.x) / cell).floor(),
                ((p.z - origin.y) / cell).floor(),
            );
            if i >= 0.0 && k >= 0.0 && (i as usize) < nx && (k as usize) < nz {
                blocked[k as usize * nx + i as usize] = true;
            }
        };
        for t in scene.triangles() {
            let ys = [t[0].y as f64, t[1].y as f64, t[2].y as f64];
            if ys.iter().all(|&y| y < slab_lo) || ys.iter().all(|&y| y > slab_hi) {
                continue;
            }
            let tri = ConvexPolygon::new(t.iter().map(|v| v.as_dvec3()).collect());
            let Some(part) = tri
                .clipped(&below, 1e-9)
                .and_then(|p| p.clipped(&above, 1e-9))
            else {
                continue;
            };
            let vs = &part.vertices;
            for (i, &a) in vs.iter().enumerate() {
                let b = vs[(i + 1) % vs.len()];
                let steps = ((DVec2::new(b.x - a.x, b.z - a.z).length() / (cell * 0.5)).ceil()
                    as usize)
                    .max(1);
                for s in 0..=steps {
                    mark(a.lerp(b, s as f64 / steps as f64));
                }
            }
            // Interior of a part that is wide in plan (a ramp, a slanted roof).
            let (pmin, pmax) = vs.iter().fold(
                (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
                |(l, h), v| (l.min(*v), h.max(*v)),
            );
            if (pmax.x - pmin.x) > cell && (pmax.z - pmin.z) > cell && plan_area(vs) > cell * cell {
                let mut z = pmin.z;
                while z <= pmax.z {
                    let mut x = pmin.x;
                    while x <= pmax.x {
                        if inside_plan(vs, x, z) {
                            mark(DVec3::new(x, 0.0, z));
                        }
                        x += cell * 0.5;
                    }
                    z += cell * 0.5;
                }
            }
        }
        let clearance = distance_transform(&blocked, nx, nz, cell);
        FreeSpace {
            origin,
            cell,
            nx,
            nz,
            clearance,
            floor,
            eye_height,
        }
    }

    fn clearance_at(&self, p: DVec2) -> f64 {
        let (i, k) = (
            ((p.x - self.origin.x) / self.cell).floor(),
            ((p.y - self.origin.y) / self.cell).floor(),
        );
        if i < 0.0 || k < 0.0 || i as usize >= self.nx || k as usize >= self.nz {
            return 0.0;
        }
        self.clearance[k as usize * self.nx + i as usize]
    }

    /// How far one can go from `p` along `dir` keeping the clearance.
    fn free_run(&self, p: DVec2, dir: DVec2, limit: f64) -> f64 {
        let mut d = 0.0;
        while d < limit && self.clearance_at(p + dir * (d + self.cell)) >= CLEARANCE {
            d += self.cell;
        }
        d
    }

    /// The cells of the largest 4-connected region a walker may stand in.
    fn largest_region(&self) -> Vec<usize> {
        let free = |i: usize| self.clearance[i] >= CLEARANCE;
        let mut label = vec![usize::MAX; self.clearance.len()];
        let (mut best, mut best_cells) = (usize::MAX, Vec::new());
        for seed in 0..self.clearance.len() {
            if !free(seed) || label[seed] != usize::MAX {
                continue;
            }
            let mut cells = vec![seed];
            label[seed] = seed;
            let mut next = 0;
            while next < cells.len() {
                let c = cells[next];
                next += 1;
                let (i, k) = (c % self.nx, c / self.nx);
                let neighbours = [
                    (i > 0).then(|| c - 1),
                    (i + 1 < self.nx).then(|| c + 1),
                    (k > 0).then(|| c - self.nx),
                    (k + 1 < self.nz).then(|| c + self.nx),
                ];
                for n in neighbours.into_iter().flatten() {
                    if free(n) && label[n] == usize::MAX {
                        label[n] = seed;
                        cells.push(n);
                    }
                }
            }
            if best == usize::MAX || cells.len() > best_cells.len() {
                (best, best_cells) = (seed, cells);
            }
        }
        best_cells
    }

    fn walk(
        &self,
        kind: WalkKind,
        frames: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<Vec<(DVec3, DVec3)>, WalkError> {
        let best = self.clearance.iter().copied().fold(0.0, f64::max);
        if best < CLEARANCE {
            return Err(WalkError::NoFreeSpace(format!(
                "floor at {:.2}, best clearance {best:.2} m",
                self.floor
            )));
        }
        // Start in the largest connected free region (the atrium, the street
        // grid, the rooms joined by doors, not a niche behind a wall), at a
        // seeded random place with 2 m of clearance (or 0.8 of the best there
        // is, if less): a street rather than a gap between two houses, and
        // not always the one emptiest field of the city.
        let region = self.largest_region();
        let best = region
            .iter()
            .map(|&i| self.clearance[i])
            .fold(0.0, f64::max);
        let want = (best * 0.8).clamp(CLEARANCE, 2.0);
        let open: Vec<usize> = region
            .into_iter()
            .filter(|&i| self.clearance[i] >= want)
            .collect();
        let start = open[rng.random_range(0..open.len())];
        let mut p = self.origin
            + DVec2::new(
                (start % self.nx) as f64 + 0.5,
                (start / self.nx) as f64 + 0.5,
            ) * self.cell;
        let step = (self.cell * 2.0).clamp(0.5, 2.0);
        let headings = 72;
        let dir_of = |k: usize| {
            let a = std::f64::consts::TAU * k as f64 / headings as f64;
            DVec2::new(a.cos(), a.sin())
        };
        // The longest free run from the start sets the street's axis.
        let mut heading = (0..headings)
            .max_by(|&a, &b| {
                self.free_run(p, dir_of(a), 200.0)
                    .total_cmp(&self.free_run(p, dir_of(b), 200.0))
            })
            .map(dir_of)
            .unwrap_or(DVec2::X);
        let mut out = Vec::with_capacity(frames);
        for _ in 0..frames {
            out.push((
                DVec3::new(p.x, self.floor + self.eye_height, p.y),
                DVec3::new(heading.x, 0.0, heading.y),
            ));
            if kind == WalkKind::Random {
                heading = DVec2::from_angle(rng.random_range(-0.15..0.15)).rotate(heading);
            }
            if self.free_run(p, heading, step * 3.0) < step {
                // Blocked: streets turn square, wanderers to the longest run.
                let options: Vec<DVec2> = match kind {
                    WalkKind::Street => {
                        let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                        vec![heading.perp() * side, -heading.perp() * side, -heading]
                    }
                    _ => (0..headings).map(dir_of).collect(),
                };
                heading = options
                    .iter()
                    .copied()
                    .max_by(|a, b| {
                        self.free_run(p, *a, 50.0)
                            .total_cmp(&self.free_run(p, *b, 50.0))
                    })
                    .unwrap_or(-heading);
            }
            if self.free_run(p, heading, step) >= step {
                p += heading * step;
            }
        }
        Ok(out)
    }
}

/// The area of the plan (xz projection) of a polygon.
fn plan_area(vs: &[DVec3]) -> f64 {
    let twice: f64 = (0..vs.len())
        .map(|i| {
            let (a, b) = (vs[i], vs[(i + 1) % vs.len()]);
            a.x * b.z - b.x * a.z
        })
        .sum();
    twice.abs() * 0.5
}

/// Whether `(x, z)` lies in the plan (xz projection) of a convex polygon.
fn inside_plan(vs: &[DVec3], x: f64, z: f64) -> bool {
    let mut sign = 0.0;
    for (i, a) in vs.iter().enumerate() {
        let b = vs[(i + 1) % vs.len()];
        let c = (b.x - a.x) * (z - a.z) - (b.z - a.z) * (x - a.x);
        if c != 0.0 {
            if sign != 0.0 && c.signum() != sign {
                return false;
            }
            sign = c.signum();
        }
    }
    true
}

/// Over a grid of the scene's plan, each cell's topmost horizontal surface
/// in the lowest quarter of the scene: what one would stand on there
/// (−∞ where there is none).
fn floor_tops(scene: &Scene, lo: DVec3, hi: DVec3, cell: f64, nx: usize, nz: usize) -> Vec<f64> {
    let limit = lo.y + (hi.y - lo.y) * 0.25;
    let mut top = vec![f64::NEG_INFINITY; nx * nz];
    let index = |x: f64, z: f64| {
        let (i, k) = (((x - lo.x) / cell).floor(), ((z - lo.z) / cell).floor());
        (i >= 0.0 && k >= 0.0 && (i as usize) < nx && (k as usize) < nz)
            .then(|| k as usize * nx + i as usize)
    };
    for t in scene.triangles() {
        let n = (t[1] - t[0]).cross(t[2] - t[0]);
        if n.length() == 0.0 || n.y.abs() < 0.95 * n.length() {
            continue;
        }
        let y = (t[0].y + t[1].y + t[2].y) as f64 / 3.0;
        if y > limit {
            continue;
        }
        let vs: Vec<DVec3> = t.iter().map(|v| v.as_dvec3()).collect();
        let centroid = (vs[0] + vs[1] + vs[2]) / 3.0;
        let mut raise = |c: Option<usize>| {
            if let Some(c) = c {
                top[c] = top[c].max(y);
            }
        };
        raise(index(centroid.x, centroid.z));
        let (pmin, pmax) = vs.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(l, h), v| (l.min(*v), h.max(*v)),
        );
        let mut z = (((pmin.z - lo.z) / cell).floor() + 0.5) * cell + lo.z;
        while z <= pmax.z {
            let mut x = (((pmin.x - lo.x) / cell).floor() + 0.5) * cell + lo.x;
            while x <= pmax.x {
                if inside_plan(&vs, x, z) {
                    raise(index(x, z));
                }
                x += cell;
            }
            z += cell;
        }
    }
    top
}

/// Candidate floor heights: the cell tops shared by at least a tenth as many
/// cells as the most common one, at most four, most common first. Under
/// buildings a roof may be a cell's top, but no roof height is that common;
/// a slab's top hides its underside.
fn floor_candidates(top: &[f64], lowest: f64) -> Vec<f64> {
    let bin = 0.05;
    let mut count = std::collections::BTreeMap::<i64, usize>::new();
    for &y in top.iter().filter(|y| y.is_finite()) {
        *count.entry((y / bin).round() as i64).or_default() += 1;
    }
    let most = count.values().copied().max().unwrap_or(0);
    let mut common: Vec<(usize, i64)> = count
        .iter()
        .filter(|&(_, &n)| n * 10 >= most)
        .map(|(&k, &n)| (n, k))
        .collect();
    common.sort_unstable_by(|a, b| b.cmp(a));
    // Each bin's exact height: the highest of its members.
    let heights: Vec<f64> = common
        .iter()
        .take(4)
        .map(|&(_, k)| {
            top.iter()
                .copied()
                .filter(|y| ((y / bin).round() as i64) == k)
                .fold(lowest, f64::max)
        })
        .collect();
    if heights.is_empty() {
        vec![lowest]
    } else {
        heights
    }
}

/// Euclidean-ish (chamfer 3-4) distance from each cell to the nearest blocked one, metres.
fn distance_transform(blocked: &[bool], nx: usize, nz: usize, cell: f64) -> Vec<f64> {
    let big = u32::MAX / 4;
    let mut d: Vec<u32> = blocked.iter().map(|&b| if b { 0 } else { big }).collect();
    let at = |i: usize, k: usize| k * nx + i;
    for k in 0..nz {
        for i in 0..nx {
            let mut v = d[at(i, k)];
            if i > 0 {
                v = v.min(d[at(i - 1, k)] + 3);
            }
            if k > 0 {
                v = v.min(d[at(i, k - 1)] + 3);
                if i > 0 {
                    v = v.min(d[at(i - 1, k - 1)] + 4);
                }
                if i + 1 < nx {
                    v = v.min(d[at(i + 1, k - 1)] + 4);
                }
            }
            d[at(i, k)] = v;
        }
    }
    for k in (0..nz).rev() {
        for i in (0..nx).rev() {
            let mut v = d[at(i, k)];
            if i + 1 < nx {
                v = v.min(d[at(i + 1, k)] + 3);
            }
            if k + 1 < nz {
                v = v.min(d[at(i, k + 1)] + 3);
                if i + 1 < nx {
                    v = v.min(d[at(i + 1, k + 1)] + 4);
                }
                if i > 0 {
                    v = v.min(d[at(i - 1, k + 1)] + 4);
                }
            }
            d[at(i, k)] = v;
        }
    }
    // The grid's border counts as blocked: distance to it too.
    (0..nx * nz)
        .map(|c| {
            let (i, k) = (c % nx, c / nx);
            let edge = i.min(k).min(nx - 1 - i).min(nz - 1 - k) as f64 * cell;
            (d[c] as f64 / 3.0 * cell).min(edge)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_keeps_even_steps_along_the_path() {
        let at = |x: f64, z: f64| Camera {
            eye: DVec3::new(x, 1.7, z),
            forward: DVec3::X,
            ..Camera::default()
        };
        // An L: 2 m along x, a repeat (a blocked step), then 2 m along z.
        let path = [at(0.0, 0.0), at(2.0, 0.0), at(2.0, 0.0), at(2.0, 2.0)];
        let out = resample(&path, 0.5, 11);
        let eyes: Vec<(f64, f64)> = out.iter().map(|c| (c.eye.x, c.eye.z)).collect();
        assert_eq!(
            eyes,
            [
                (0.0, 0.0),
                (0.5, 0.0),
                (1.0, 0.0),
                (1.5, 0.0),
                (2.0, 0.0),
                (2.0, 0.5),
                (2.0, 1.0),
                (2.0, 1.5),
                (2.0, 2.0),
                (2.0, 2.0),
                (2.0, 2.0),
            ]
        );
        assert!(resample(&[], 1.0, 3).is_empty());
    }
}
