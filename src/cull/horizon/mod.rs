//! `horizon`: occlusion horizons for cities seen from the street (Downs,
//! Möller, Séquin 2001).
//!
//! Per view, a plane sweeps away from the eye along the horizontal view
//! direction `d` (§3.5). An event queue orders the sweep: quadtree cells and
//! objects are *tested* when the plane first touches their box, prisms are
//! *added* when it has passed their far side. A box is hidden when its
//! bounding frame on the vertical plane at distance 1 along `d` lies below
//! the horizon ([`Horizon`]); otherwise a cell opens its objects and
//! children, and an object is visible and queues its prisms' masks.
//!
//! Why a mask may hide what lies behind it. A prism `C × [G, top]` lies inside
//! its object's opaque surface ([`prism`]), every object lies at or above
//! the ground level `G`, and the eye is outside the object's box and not
//! below `G`. Its mask covers the screen columns of `C`'s silhouette up to
//! the lowest projected corner of its top, and is added at `ev`, the
//! farthest depth of `C`. A ray in those columns below that height either
//! passes through the prism before `ev` (so through the object's surface), or
//! is below `G` at every depth beyond `ev`, where no object is. Objects are
//! tested at their nearest depth, which is not before `ev`, so every point
//! of theirs on such a ray is behind the surface. Ties in depth are broken
//! tests first.
//!
//! A box is also tested when its cell opens, before it is queued: a cell's
//! bounds hold the boxes below it, so every mask in the horizon then was
//! added at a depth not beyond the box's nearest, and a box hidden then
//! never costs the queue a push and a pop (most of a street view's boxes).
//! A queued box keeps the frame it was tested with and is tested again at
//! its pop only if a mask was added since (the horizon only rises, and
//! only through masks).
//!
//! Tilted and vertical views (§3.7): the horizon lives on the vertical
//! plane whatever the pitch; only the window of screen x changes. When all
//! four edges of the frustum point forward along `d`, the window is their x
//! range and a frame is only compared over its part inside it (the rest is
//! outside the frustum). When some edge does not (looking steeply up or
//! down), the window is a fixed wide range and a frame leaving it is
//! visible; a box reaching the eye's vertical plane (depth ≈ 0, the
//! near-vertical part of the view) is never projected and gets frustum
//! culling only. With the eye below `G`, the view is frustum culled.
//!
//! Regions (a request's `radius` and `angle`): the sweep runs from the top
//! of the ball, `c + (0, r, 0)`, over prisms whose footprints are shrunk by
//! `r` (their erosion by a disc). A ray from that eye to a point `p` that
//! a shrunk mask hides passes through a shrunk prism at some parameter `t`;
//! the ray to `p` from any eye `c'` with `|c'ₓ₂ − cₓ₂| ≤ r` and
//! `G ≤ c'.y ≤ c.y + r` is within `(1 − t) r ≤ r` of it horizontally at
//! `t` (so over the whole footprint) and no higher there (heights
//! interpolate linearly between eye and `p`), and not below `G` (both ends
//! are not): it passes through the whole prism, so through the object's
//! surface, since no such eye is inside the object's box (prisms of boxes
//! the cylinder reaches are not used). The cylinder holds the ball when the
//! ball is not below `G`; when it is, the view gets frustum culling only.
//! The top is not lowered (the highest eye already sees the most over it);
//! the `angle` is the view's enclosing frustum alone. The enclosing
//! frustum is a pyramid from an apex behind the sweep's eye, so its window
//! widens near that eye (`Sweep::new`).
//!
//! Levels of detail (§3.6): with `areas=true` each visible object carries an
//! upper bound of the pixels it can cover: the pixel centres inside the
//! smaller of its box's screen rectangle and the screen rectangle of its
//! frame's part above the horizon. `min_area=N` drops objects whose bound
//! is below N pixels (an aggressive setting: it reports misses in eval).

pub mod prism;
mod tree;

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::sync::Arc;

use glam::DVec3;

pub use prism::{Prism, Prisms};
pub use tree::{Horizon, Opening};

use crate::cull::pool::BufferPool;
use crate::cull::{
    CullCounters, CullError, CullMethod, Culler, InFrustum, MethodEntry, MethodError,
    MethodOptions, Occludees, Preparation, Ranged, View, VisibleSet,
};
use crate::geom::{ALL_PLANES, Aabb, PlaneMask, Side, greater, lesser, ordered_bits};
use crate::scene::Scene;
use crate::spatial::QuadTree;

/// `areas=true`: each visible id carries a bound of the pixels it covers.
const AREAS: &str = "areas";

/// Objects whose area bound is under this many pixels are dropped (not
/// conservative unless 0).
const MIN_AREA: Ranged<f64> = Ranged {
    key: "min_area",
    noun: "a pixel count",
    default: 0.0,
    min: 0.0,
    max: 1e9,
};

/// Columns of the horizon across the view.
const COLUMNS: Ranged<usize> = Ranged {
    key: "columns",
    noun: "a whole number",
    default: 1024,
    min: 16,
    max: 65536,
};

const OPTIONS: [&str; 3] = [AREAS, MIN_AREA.key, COLUMNS.key];

/// Most spare sweep buffers a method keeps (about a busy server's
/// concurrent culls); more are freed.
const SPARE_BUFFERS: usize = 16;

/// A depth is usable for projection when it exceeds this share of the
/// point's distance: far above the rounding of the depth itself.
const DEPTH_EPSILON: f64 = 1e-9;

/// A unit forward whose horizontal part is shorter than this looks
/// straight up or down: the sweep then runs along the image's up, since a
/// direction normalized from so short a vector would be mostly rounding.
const VERTICAL_VIEW: f64 = 1e-9;

/// Pixel centres within this many pixels outside a projected rectangle
/// count as inside it, so that the rounding of the projection can only
/// raise an area bound (§3.6), never lower it below the pixels shown.
const PIXEL_SLACK: f64 = 1e-6;

/// The window of screen x when the frustum reaches the eye's vertical plane
/// (about ±89°): wider views fall back to frustum culling at the sides.
const WIDE_WINDOW: f64 = 64.0;

/// The method's registry entry; the table checks a coarse horizon too.
pub const ENTRY: MethodEntry = MethodEntry {
    name: "horizon",
    purpose: "occlusion horizons over convex vertical prisms (Downs et al.): cities standing on a ground",
    options: &OPTIONS,
    checked_with: &["columns=64"],
    regions: None,
    build,
};

fn build(p: &Preparation<'_>) -> Result<Arc<dyn Culler>, String> {
    let prisms = p.prisms()?;
    Ok(Arc::new(HorizonCulling::with_prisms(
        p.scene().clone(),
        Prisms::clone(&prisms),
    )))
}

/// Occlusion horizons over a quadtree of the scene, with the prisms proven
/// inside its objects.
pub struct HorizonCulling {
    scene: Arc<Scene>,
    quadtree: QuadTree,
    prisms: Prisms,
    /// Every object's box, by object index: the sweep reads thousands a
    /// frame, and packed they stay in cache where the objects do not.
    bounds: Vec<Aabb>,
    /// Sweep buffers no cull is using ([`HorizonState`]).
    spare: BufferPool<SweepBuffers>,
}

impl HorizonCulling {
    /// The method for `scene`, or why the scene is no height field for it.
    pub fn new(scene: Arc<Scene>) -> Result<HorizonCulling, String> {
        let prisms = Prisms::find(&scene)?;
        Ok(HorizonCulling::with_prisms(scene, prisms))
    }

    /// The method for `scene` with its prisms, found already.
    pub fn with_prisms(scene: Arc<Scene>, prisms: Prisms) -> HorizonCulling {
        HorizonCulling {
            quadtree: QuadTree::build(&scene),
            bounds: scene.objects().iter().map(|o| o.bounds).collect(),
            scene,
            prisms,
            spare: BufferPool::new(SPARE_BUFFERS),
        }
    }

    /// The prisms it occludes with.
    pub fn prisms(&self) -> &Prisms {
        &self.prisms
    }

    /// The quadtree it sweeps.
    pub fn quadtree(&self) -> &QuadTree {
        &self.quadtree
    }
}

/// A client's state: its options. A sweep keeps nothing from one frame to
/// the next, so the buffers it needs (`SweepBuffers`, 42 KB on the 10k
/// city street walk) are not the client's but lent by the method for one
/// cull ([`BufferPool`]): a server with thousands of sessions holds as
/// many sets as it runs culls at once (keeping at most `SPARE_BUFFERS`),
/// not one a session.
pub struct HorizonState {
    areas: bool,
    min_area: f64,
    columns: usize,
}

/// The buffers one sweep needs, kept between frames so that culling
/// allocates nothing once warm.
struct SweepBuffers {
    horizon: Horizon,
    /// A bit per object, set once it is tested this frame (§3.3's stamps,
    /// cleared each frame).
    tested: Vec<u64>,
    queue: BinaryHeap<Event>,
    masks: Vec<Mask>,
    /// The cells and objects in the queue, each with the frame it was
    /// tested with when pushed: the horizon may have risen by its pop (and
    /// is tested again only if a mask was added since), the frame has not
    /// changed.
    pending: Vec<Pending>,
}

impl SweepBuffers {
    fn new() -> SweepBuffers {
        SweepBuffers {
            horizon: Horizon::new(COLUMNS.default),
            tested: Vec::new(),
            queue: BinaryHeap::new(),
            masks: Vec::new(),
            pending: Vec::new(),
        }
    }

    /// Emptied for a sweep with `columns` columns over `objects` objects
    /// (sessions with other column counts share them without allocating,
    /// once they are as large as the largest).
    fn fit(&mut self, columns: usize, objects: usize) {
        self.horizon.set_columns(columns);
        self.tested.clear();
        self.tested.resize(objects.div_ceil(64), 0);
        self.queue.clear();
        self.masks.clear();
        self.pending.clear();
    }
}

/// A cell or object in the queue and its frame (`None`: it cannot be
/// hidden), found not hidden when pushed with `masks` masks in the horizon.
#[derive(Clone, Copy, Debug)]
struct Pending {
    index: u32,
    frame: Option<Frame>,
    masks: u32,
}

/// A prism's rectangular mask (§3.4, Fig. 4c).
#[derive(Clone, Copy, Debug)]
struct Mask {
    x_lo: f64,
    x_hi: f64,
    height: f64,
}

/// A box's bounding frame on the view plane.
#[derive(Clone, Copy, Debug)]
struct Frame {
    x_lo: f64,
    x_hi: f64,
    y_lo: f64,
    y_hi: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Kind {
    Cell,
    Object,
    /// A dynamic occludee ([`Occludees`]), tested like an object.
    Dynamic,
    /// Added after every test at the same depth.
    Mask,
}

/// One event of the sweep, all of it in its key: sifting the heap moves
/// and compares two words and nothing else.
#[derive(Clone, Copy, Debug)]
struct Event {
    /// The order of events: depth, then kind, then index ([`Event::new`]);
    /// the second word also holds a cell's planes, below the index, which
    /// is unique within a kind, so they never decide an order.
    key: (u64, u64),
}

impl Event {
    /// An event at `depth`. Its key orders events as `f64::total_cmp` of
    /// the depths, then the kinds, then the indices (two integer compares
    /// where the heap's sifting spent most of a pop on the float's).
    /// `planes` are a cell's planes still to test (its parent was inside
    /// the others); unused for the rest: objects are frustum-tested when
    /// pushed.
    fn new(depth: f64, kind: Kind, index: u32, planes: PlaneMask) -> Event {
        Event {
            key: (
                ordered_bits(depth),
                ((kind as u64) << 40) | (u64::from(index) << 8) | u64::from(planes),
            ),
        }
    }

    fn kind(&self) -> Kind {
        match self.key.1 >> 40 {
            0 => Kind::Cell,
            1 => Kind::Object,
            2 => Kind::Dynamic,
            _ => Kind::Mask,
        }
    }

    fn index(&self) -> u32 {
        (self.key.1 >> 8) as u32
    }

    fn planes(&self) -> PlaneMask {
        self.key.1 as PlaneMask
    }

    /// A cell's or an object's event: `index` is its [`Pending`] slot.
    fn pending(depth: f64, kind: Kind, planes: PlaneMask, pending: &mut Vec<Pending>, p: Pending) -> Event {
        pending.push(p);
        Event::new(depth, kind, (pending.len() - 1) as u32, planes)
    }
}

impl PartialEq for Event {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Event {}
impl PartialOrd for Event {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Event {
    /// Reversed: the heap pops the nearest event, tests before masks.
    fn cmp(&self, other: &Self) -> Ordering {
        other.key.cmp(&self.key)
    }
}

/// The horizontal view of one camera: the plane the horizon lives on.
struct Sweep {
    eye: DVec3,
    /// Horizontal unit view direction (the sweep's axis).
    d: DVec3,
    /// Horizontal unit right: screen x.
    r: DVec3,
    /// Whether the window holds the frustum's whole x range (for boxes
    /// from depth `clamp_from` on).
    clamped: bool,
    /// Boxes nearer than this are compared whole: a frame leaving the
    /// window is visible (0 for a point view).
    clamp_from: f64,
    /// A region's apex lies this far behind the sweep's eye along `d`.
    behind: f64,
    /// The window seen from a region's apex.
    apex_window: (f64, f64),
    x0: f64,
    x1: f64,
    /// Whether masks may be used at all (the eye is not below the ground).
    occludes: bool,
    /// How far prisms are shrunk horizontally (a region's radius, rounded
    /// up; 0 for a point view).
    shrink: f64,
}

impl Sweep {
    fn new(view: &View, ground: f64) -> Sweep {
        let basis = view.basis();
        let horizontal = |v: DVec3| DVec3::new(v.x, 0.0, v.z);
        // Straight up or down the forward has no horizontal part; the
        // image's up then points along the ground.
        let d = horizontal(basis.forward)
            .try_normalize()
            .filter(|_| horizontal(basis.forward).length() > VERTICAL_VIEW)
            .or_else(|| horizontal(basis.up).try_normalize())
            .unwrap_or(DVec3::X);
        let r = DVec3::new(-d.z, 0.0, d.x);
        // A region sweeps from the top of its ball, with prisms shrunk by
        // its radius (module docs, "Regions").
        let radius = view.region().radius();
        let centre = view.eye();
        let eye = centre + DVec3::Y * radius;
        // The window: the x range of the frustum's far corners seen from
        // its apex. For a point view the apex is the eye, and every frame
        // is compared only over its part inside the window (the rest is
        // outside the frustum). A region's apex `a` lies behind the sweep's
        // eye `e` by `δ = e − a` (back along the forward, and up by the
        // radius; `δ · r` = 0): a frustum point at depth `t` from `e` has
        // `x_e = x_a (t + δ·d) / t`, so a box from depth `t` on is
        // compared over the apex window scaled by `1 + δ·d / t`
        // ([`Sweep::frame`]). The horizon's columns span that for depths
        // from `2 δ·d` on; a nearer box is compared whole (one leaving the
        // window is visible). A cube has no apex: the wide window, frames
        // whole.
        let (mut x0, mut x1, mut clamped) = (f64::INFINITY, f64::NEG_INFINITY, true);
        let apex = view.apex();
        let from = apex.unwrap_or(eye);
        for c in &view.frustum().corners()[4..] {
            let rel = *c - from;
            let t = rel.dot(d);
            if t <= DEPTH_EPSILON * rel.abs().max_element() {
                clamped = false;
                break;
            }
            let x = rel.dot(r) / t;
            x0 = x0.min(x);
            x1 = x1.max(x);
        }
        let (mut clamp_from, mut behind, apex_window) = (0.0, 0.0, (x0, x1));
        if let (Some(a), true) = (apex, radius > 0.0 && clamped) {
            let delta = eye - a;
            let (dd, dr) = (delta.dot(d), delta.dot(r));
            if dd >= 0.0 && dr.abs() <= DEPTH_EPSILON * delta.length() {
                (clamp_from, behind) = (2.0 * dd, dd);
                let s = 1.5 * (1.0 + 1e-9);
                (x0, x1) = (x0.min(x0 * s) - 2e-9, x1.max(x1 * s) + 2e-9);
            } else {
                clamped = false;
            }
        }
        if apex.is_none() {
            clamped = false;
        }
        if !clamped {
            (x0, x1) = (-WIDE_WINDOW, WIDE_WINDOW);
        }
        let occludes =
            centre.y - radius >= ground && x0.is_finite() && x1.is_finite() && x0 < x1;
        let shrink = if radius > 0.0 {
            radius * (1.0 + 1e-9) + centre.abs().max_element() * 16.0 * f64::EPSILON
        } else {
            0.0
        };
        Sweep {
            eye,
            d,
            r,
            clamped,
            clamp_from,
            behind,
            apex_window,
            x0,
            x1,
            occludes,
            shrink,
        }
    }

    /// Whether some eye of the view may be inside `b`, whose prisms then
    /// hide nothing: for a region, any eye of the upright cylinder of
    /// radius `shrink` from the ground to the sweep's eye.
    fn reaches_into(&self, b: &Aabb) -> bool {
        if self.shrink == 0.0 {
            return contains(b, self.eye);
        }
        let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
        let gap = |v: f64, lo: f64, hi: f64| (lo - v).max(v - hi).max(0.0);
        let (gx, gz) = (gap(self.eye.x, lo.x, hi.x), gap(self.eye.z, lo.z, hi.z));
        gx * gx + gz * gz <= self.shrink * self.shrink && lo.y <= self.eye.y
    }

    /// The bounding frame of a box when masks may hide it: `None` when the
    /// eye is below the ground or the box cannot be hidden ([`Sweep::frame`]).
    fn frame_if_occluding(&self, b: &Aabb) -> Option<Frame> {
        if self.occludes { self.frame(b) } else { None }
    }

    /// The nearest depth of a box along `d`.
    fn near_depth(&self, b: &Aabb) -> f64 {
        let (lo, hi) = (b.min.as_dvec3() - self.eye, b.max.as_dvec3() - self.eye);
        (lo * self.d).min(hi * self.d).element_sum()
    }

    /// The bounding frame of a box, or `None` when it cannot be hidden: it
    /// reaches the eye's vertical plane, or it leaves a window that does not
    /// hold the whole frustum.
    fn frame(&self, b: &Aabb) -> Option<Frame> {
        let (lo, hi) = (b.min.as_dvec3() - self.eye, b.max.as_dvec3() - self.eye);
        // `d` and `r` are horizontal (y exactly 0), so a corner's depth and
        // screen x are those of its footprint corner whatever its height:
        // four corners give them, and the box's bottom and top give y from
        // the nearest and farthest depth (y / t is monotone in t, rounding
        // included). The same values as projecting all eight corners (up to
        // the sign of a zero).
        let tall = greater(lo.y.abs(), hi.y.abs());
        let (mut t_near, mut t_far) = (f64::INFINITY, f64::NEG_INFINITY);
        let (mut x_lo, mut x_hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (x, z) in [(lo.x, lo.z), (hi.x, lo.z), (lo.x, hi.z), (hi.x, hi.z)] {
            let rel = DVec3::new(x, 0.0, z);
            let t = rel.dot(self.d);
            let size = greater(greater(tall, x.abs()), z.abs());
            if t.partial_cmp(&(DEPTH_EPSILON * size)) != Some(Ordering::Greater) {
                return None;
            }
            let x = rel.dot(self.r) / t;
            (x_lo, x_hi) = (lesser(x_lo, x), greater(x_hi, x));
            (t_near, t_far) = (lesser(t_near, t), greater(t_far, t));
        }
        if self.clamp_from > 0.0 && t_near >= self.clamp_from {
            // A region's box: only its part inside the frustum matters,
            // which from this depth on lies within the apex window widened
            // by `1 + δ·d / t_near` (`Sweep::new`).
            let s = (1.0 + self.behind / t_near) * (1.0 + 1e-9);
            let (a0, a1) = self.apex_window;
            // Rounded outwards, relatively and by what `δ · r` (zero to
            // within rounding) can shift `x`.
            let (lo, hi) = (a0.min(a0 * s) - 1e-9, a1.max(a1 * s) + 1e-9);
            if x_lo.max(lo) <= x_hi.min(hi) {
                (x_lo, x_hi) = (x_lo.max(lo), x_hi.min(hi));
            }
        }
        let f = Frame {
            x_lo,
            x_hi,
            y_lo: lo.y / if lo.y >= 0.0 { t_far } else { t_near },
            y_hi: hi.y / if hi.y >= 0.0 { t_near } else { t_far },
        };
        if (!self.clamped || t_near < self.clamp_from) && (f.x_lo < self.x0 || f.x_hi > self.x1) {
            return None;
        }
        Some(f)
    }

    /// The mask of a prism and the depth to add it at, or `None` when some
    /// corner is not clearly in front of the eye.
    fn mask(&self, prism: &Prism) -> Option<(Mask, f64)> {
        let (mut x_lo, mut x_hi) = (f64::INFINITY, f64::NEG_INFINITY);
        let (mut near, mut far) = (f64::INFINITY, f64::NEG_INFINITY);
        let rise = prism.top - self.eye.y;
        let shrunk;
        let footprint = if self.shrink > 0.0 {
            shrunk = prism.shrunk_footprint(self.shrink)?;
            shrunk.corners()
        } else {
            &prism.footprint
        };
        for v in footprint {
            let rel = DVec3::new(v.x - self.eye.x, rise, v.y - self.eye.z);
            let t = rel.dot(self.d);
            if t.partial_cmp(&(DEPTH_EPSILON * rel.abs().max_element())) != Some(Ordering::Greater)
            {
                return None;
            }
            let x = rel.dot(self.r) / t;
            (x_lo, x_hi) = (lesser(x_lo, x), greater(x_hi, x));
            (near, far) = (lesser(near, t), greater(far, t));
        }
        // The lowest projected corner of the top (Fig. 4c).
        let height = if rise >= 0.0 { rise / far } else { rise / near };
        Some((Mask { x_lo, x_hi, height }, far))
    }

    /// The direction of view-plane point `(x, y)`.
    fn direction(&self, x: f64, y: f64) -> DVec3 {
        self.d + self.r * x + DVec3::Y * y
    }
}

impl CullMethod for HorizonCulling {
    type State = HorizonState;

    fn name(&self) -> &'static str {
        "horizon"
    }

    fn new_state(&self, options: &MethodOptions) -> Result<HorizonState, MethodError> {
        let r = options.reader("horizon", &OPTIONS);
        let areas = r.flag(AREAS, false)?;
        let min_area = r.ranged(&MIN_AREA)?;
        let columns = r.ranged(&COLUMNS)?;
        r.finish()?;
        Ok(HorizonState {
            areas,
            min_area,
            columns,
        })
    }

    fn is_conservative(&self, state: &HorizonState) -> bool {
        state.min_area == 0.0
    }

    fn state_bytes(&self, _state: &HorizonState) -> usize {
        std::mem::size_of::<HorizonState>()
    }

    /// Dynamic boxes join the sweep as events at their near depth, so only
    /// masks nearer than them can hide them; a box reaching below the
    /// ground level is not occlusion-tested (the masks' reasoning needs
    /// everything at or above it).
    fn cull(
        &self,
        view: &View,
        state: &mut HorizonState,
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        let mut buffers = self.spare.take().unwrap_or_else(SweepBuffers::new);
        buffers.fit(state.columns, self.scene.objects().len());
        let counters = self.sweep(view, state, &mut buffers, out, occludees);
        self.spare.put(buffers);
        Ok(counters)
    }
}

impl HorizonCulling {
    /// One view's sweep with a client's `options`, in emptied `buffers`.
    fn sweep(
        &self,
        view: &View,
        options: &HorizonState,
        buffers: &mut SweepBuffers,
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> CullCounters {
        let mut counters = CullCounters {
            nodes_tested: 0,
            in_frustum: InFrustum::Unknown,
        };
        let cells = self.quadtree.cells();
        if cells.is_empty() {
            return counters;
        }
        let sweep = Sweep::new(view, self.prisms.ground());
        buffers.horizon.reset(sweep.x0, sweep.x1);
        let lod = options.areas || options.min_area > 0.0;
        // The empty horizon hides nothing: the root is not hidden at 0 masks.
        let root = Pending {
            index: 0,
            frame: sweep.frame_if_occluding(&cells[0].bounds),
            masks: 0,
        };
        let mut masks_added = 0u32;
        let event = Event::pending(
            sweep.near_depth(&cells[0].bounds),
            Kind::Cell,
            ALL_PLANES,
            &mut buffers.pending,
            root,
        );
        buffers.queue.push(event);
        let ground = self.prisms.ground();
        for (i, b) in occludees.boxes().iter().enumerate() {
            if occludees.visible()[i] && sweep.occludes && f64::from(b.min.y) >= ground {
                buffers.queue.push(Event::new(sweep.near_depth(b), Kind::Dynamic, i as u32, 0));
            }
        }
        while let Some(ev) = buffers.queue.pop() {
            match ev.kind() {
                Kind::Mask => {
                    let m = buffers.masks[ev.index() as usize];
                    buffers.horizon.insert(m.x_lo, m.x_hi, m.height);
                    masks_added += 1;
                }
                Kind::Cell => {
                    let p = buffers.pending[ev.index() as usize];
                    let cell = &cells[p.index as usize];
                    counters.nodes_tested += 1;
                    let (side, planes) = view.frustum().classify(&cell.bounds, ev.planes());
                    if side == Side::Outside
                        || (p.masks != masks_added && buffers.horizon.hides_frame(p.frame))
                    {
                        continue;
                    }
                    for &o in self.quadtree.objects(cell) {
                        // Stamped and frustum-tested as the cell opens, so
                        // repeats and objects outside the view never
                        // enter the queue (most of its cost).
                        let (word, bit) = (&mut buffers.tested[o as usize >> 6], 1 << (o & 63));
                        if *word & bit != 0 {
                            continue;
                        }
                        *word |= bit;
                        counters.nodes_tested += 1;
                        let b = &self.bounds[o as usize];
                        if view.frustum().classify_exact(b, planes).0 == Side::Outside {
                            continue;
                        }
                        let frame = sweep.frame_if_occluding(b);
                        if buffers.horizon.hides_frame(frame) {
                            continue;
                        }
                        let p = Pending {
                            index: o,
                            frame,
                            masks: masks_added,
                        };
                        let event = Event::pending(
                            sweep.near_depth(b),
                            Kind::Object,
                            0,
                            &mut buffers.pending,
                            p,
                        );
                        buffers.queue.push(event);
                    }
                    for &c in cell.children.iter().filter(|&&c| c != 0) {
                        let b = &cells[c as usize].bounds;
                        let frame = sweep.frame_if_occluding(b);
                        if buffers.horizon.hides_frame(frame) {
                            continue;
                        }
                        let p = Pending {
                            index: c,
                            frame,
                            masks: masks_added,
                        };
                        let event = Event::pending(
                            sweep.near_depth(b),
                            Kind::Cell,
                            planes,
                            &mut buffers.pending,
                            p,
                        );
                        buffers.queue.push(event);
                    }
                }
                Kind::Dynamic => {
                    let i = ev.index() as usize;
                    let frame = sweep.frame_if_occluding(&occludees.boxes()[i]);
                    if buffers.horizon.hides_frame(frame) {
                        occludees.hide(i);
                    }
                }
                Kind::Object => {
                    let Pending {
                        index,
                        frame,
                        masks,
                    } = buffers.pending[ev.index() as usize];
                    // The quadtree holds ids, and objects are indexed by
                    // id: reading the object back (88 bytes, far from the
                    // packed boxes) was a cache miss for each visible
                    // object in a server of many sessions.
                    let id = index;
                    let bounds = &self.bounds[index as usize];
                    if masks != masks_added && buffers.horizon.hides_frame(frame) {
                        continue;
                    }
                    let area =
                        lod.then(|| area_bound(view, &sweep, &buffers.horizon, bounds, frame));
                    match area {
                        Some(a) if a < options.min_area => {}
                        Some(a) if options.areas => out.push_with_area(id, a),
                        _ => out.push(id),
                    }
                    // Even a dropped object occludes: its prisms are real.
                    if sweep.occludes && !sweep.reaches_into(bounds) {
                        for prism in self.prisms.of(id) {
                            if let Some((mask, far)) = sweep.mask(prism) {
                                buffers.queue.push(Event::new(far, Kind::Mask, buffers.masks.len() as u32, 0));
                                buffers.masks.push(mask);
                            }
                        }
                    }
                }
            }
        }
        counters
    }
}

impl Horizon {
    /// Whether a box of this frame is wholly below the horizon (`None`: a
    /// box that cannot be hidden).
    fn hides_frame(&self, frame: Option<Frame>) -> bool {
        frame.is_some_and(|f| self.hides(f.x_lo, f.x_hi, f.y_hi))
    }
}

/// Whether the closed box holds the point (in `f64`, no rounding of the eye).
fn contains(b: &Aabb, p: DVec3) -> bool {
    let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
    p.cmpge(lo).all() && p.cmple(hi).all()
}

/// An upper bound of the pixels a visible box can show (module docs, §3.6).
fn area_bound(
    view: &View,
    sweep: &Sweep,
    horizon: &Horizon,
    b: &Aabb,
    frame: Option<Frame>,
) -> f64 {
    let cam = view.camera();
    let basis = view.basis();
    let (tx, ty) = cam.half_tangents();
    let [w, h] = cam.viewport.map(f64::from);
    let whole = w * h;
    if !view.region().is_point() {
        // A region's views see a box at other pixels: no tighter bound.
        return whole;
    }
    // Pixel coordinates of a direction, when it points ahead of the camera.
    let pixel = |v: DVec3| -> Option<(f64, f64)> {
        let z = v.dot(basis.forward);
        (z > DEPTH_EPSILON * v.length()).then(|| {
            (
                (v.dot(basis.right) / (z * tx) + 1.0) * 0.5 * w,
                (1.0 - v.dot(basis.up) / (z * ty)) * 0.5 * h,
            )
        })
    };
    // Pixel centres (i + 0.5, j + 0.5) inside the rectangle around the points.
    let centres = |points: &mut dyn Iterator<Item = Option<(f64, f64)>>| -> f64 {
        let (mut x0, mut y0, mut x1, mut y1) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for p in points {
            let Some((x, y)) = p else { return whole };
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
        }
        let span = |lo: f64, hi: f64, n: f64| {
            let first = (lo - 0.5 - PIXEL_SLACK).ceil().max(0.0);
            let last = (hi - 0.5 + PIXEL_SLACK).floor().min(n - 1.0);
            (last - first + 1.0).max(0.0)
        };
        span(x0, x1, w) * span(y0, y1, h)
    };
    let eye = view.eye();
    let mut bound = centres(&mut b.corners().iter().map(|c| pixel(c.as_dvec3() - eye)));
    if let Some(f) = frame {
        if let Some(open) = horizon.opening(f.x_lo, f.x_hi, f.y_hi) {
            let (x0, x1) = (open.x_lo.max(f.x_lo), open.x_hi.min(f.x_hi));
            let (y0, y1) = (open.floor.max(f.y_lo), f.y_hi);
            let above = centres(
                &mut [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
                    .into_iter()
                    .map(|(x, y)| pixel(sweep.direction(x, y))),
            );
            bound = bound.min(above);
        }
    }
    bound
}

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use rand::{Rng, SeedableRng};

    use super::*;

    /// The frame by projecting all eight corners, as the paper draws it.
    fn frame_of_corners(s: &Sweep, b: &Aabb) -> Option<Frame> {
        let mut f = Frame {
            x_lo: f64::INFINITY,
            x_hi: f64::NEG_INFINITY,
            y_lo: f64::INFINITY,
            y_hi: f64::NEG_INFINITY,
        };
        for c in b.corners() {
            let rel = c.as_dvec3() - s.eye;
            let t = rel.dot(s.d);
            if t.partial_cmp(&(DEPTH_EPSILON * rel.abs().max_element())) != Some(Ordering::Greater)
            {
                return None;
            }
            let (x, y) = (rel.dot(s.r) / t, rel.y / t);
            (f.x_lo, f.x_hi) = (f.x_lo.min(x), f.x_hi.max(x));
            (f.y_lo, f.y_hi) = (f.y_lo.min(y), f.y_hi.max(y));
        }
        Some(f)
    }

    #[test]
    fn events_keep_their_fields_and_order_by_depth_kind_and_index_alone() {
        let kinds = [Kind::Cell, Kind::Object, Kind::Dynamic, Kind::Mask];
        let depths = [f64::NEG_INFINITY, -1.0, -0.0, 0.0, 1e-300, 2.5, 2.5, 1e300, f64::INFINITY];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let events: Vec<(f64, Kind, u32, PlaneMask)> = (0..400)
            .map(|_| {
                (
                    depths[rng.random_range(0..depths.len())],
                    kinds[rng.random_range(0..4)],
                    rng.random_range(0..4u32) * (u32::MAX / 3),
                    rng.random(),
                )
            })
            .collect();
        for &(d, k, i, p) in &events {
            let e = Event::new(d, k, i, p);
            assert_eq!((e.kind(), e.index(), e.planes()), (k, i, p));
        }
        for &(d1, k1, i1, p1) in &events {
            for &(d2, k2, i2, p2) in &events {
                // The heap pops the greatest: the nearest first.
                let want = (d2.total_cmp(&d1), k2.cmp(&k1), i2.cmp(&i1));
                let want = want.0.then(want.1).then(want.2);
                let got = Event::new(d1, k1, i1, p1).cmp(&Event::new(d2, k2, i2, p2));
                if (k1, i1) != (k2, i2) || d1.total_cmp(&d2).is_ne() {
                    assert_eq!(got, want, "{d1} {k1:?} {i1} vs {d2} {k2:?} {i2}");
                }
            }
        }
    }

    #[test]
    fn a_frame_from_the_footprint_is_the_frame_of_all_eight_corners() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut next = || rng.random_range(-0.5..0.5);
        let mut framed = 0;
        for _ in 0..5000 {
            let a = next() * std::f64::consts::TAU;
            let d = DVec3::new(a.cos(), 0.0, a.sin());
            let sweep = Sweep {
                eye: DVec3::new(next(), next(), next()) * 200.0,
                d,
                r: DVec3::new(-d.z, 0.0, d.x),
                clamped: true,
                x0: -1.0,
                x1: 1.0,
                occludes: true,
                shrink: 0.0,
                clamp_from: 0.0,
                behind: 0.0,
                apex_window: (-1.0, 1.0),
            };
            let c = Vec3::new(next() as f32, next() as f32, next() as f32) * 400.0;
            let h = Vec3::new(next() as f32, next() as f32, next() as f32).abs() * 60.0;
            let b = Aabb::new(c - h, c + h);
            let (got, want) = (sweep.frame(&b), frame_of_corners(&sweep, &b));
            assert_eq!(got.is_some(), want.is_some(), "{b:?} from {:?}", sweep.eye);
            if let (Some(g), Some(w)) = (got, want) {
                framed += 1;
                for (g, w) in [
                    (g.x_lo, w.x_lo),
                    (g.x_hi, w.x_hi),
                    (g.y_lo, w.y_lo),
                    (g.y_hi, w.y_hi),
                ] {
                    assert!(g == w, "{g} != {w} for {b:?}");
                }
            }
        }
        assert!(
            framed > 1000,
            "only {framed} boxes were in front of the eye"
        );
    }
}
