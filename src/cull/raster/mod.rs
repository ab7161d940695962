//! `raster`: conservative software occlusion culling on the CPU. A depth
//! buffer at the request's viewport is drawn from real surfaces, and the
//! kd-tree is walked front to back, its nodes and objects tested by their
//! boxes against the buffer as it fills — the hierarchical depth test of
//! Greene et al., on a CPU buffer as in Masked Occlusion Culling
//! (Hasselgren, Andersson & Akenine-Möller 2016), with what a visibility
//! server has that a game does not: polygons merged offline, a kd-tree, and
//! last frame's answer.
//!
//! - [`crate::cull::depth`]: the buffer itself (shared with `ddo`): polygons
//!   drawn where they cover every pixel centre of a cell, boxes tested by
//!   their outline at their nearest depth, AVX2 and plain loops bit for
//!   bit alike (option `simd=false` runs the plain ones);
//! - [`surfaces`]: each object's opaque triangles merged into convex
//!   polygons, built once per scene;
//! - [`proxies`]: for closed objects made of many small polygons, boxes
//!   inside their solid (found on a voxel grid, kept in the bake cache),
//!   whose faces hide what the object's skin hides where no single polygon
//!   of it is large enough to fill a cell (option `proxies=false` leaves
//!   them out).
//!
//! **Per frame.** First the buffer is offered what is likely to hide the
//! most: the objects a session's last frame found visible (the first of
//! the two passes of modern GPU culling). Then the walk: near child
//! first, a node outside the frustum or hidden is dropped with its
//! subtree; in a leaf, each object's part in the cell is tested, and an
//! object found visible is added to the answer and offered, so that what
//! it hides farther on is culled — the second pass. (Drawing the scene's
//! large occluders first, as the object-space methods pick them, was
//! measured slower on every scene: the walk draws them when it reaches
//! them.) Avatars and movable objects are tested last, against the whole
//! buffer.
//!
//! **Drawn when a test needs it.** An offered object waits by its box; a
//! box tested and not hidden names a cell of its outline still open, and
//! the offered objects whose boxes cover that cell and may be nearer are
//! split into their clusters, and those clusters drawn (nearest first,
//! surfaces at least `min_size` pixels across and `min_width` cells
//! wide, up to `budget` a frame), until the cell closes or nothing
//! offered covers it. A cluster not drawn can change the test only in the
//! cells it covers, so each test answers as if everything offered so far
//! were drawn (the budget aside), and what hides nothing tested is never
//! drawn: an object offered last, or off to the side of everything behind
//! it, costs a footprint. Offers are found by screen bins ([`offers`]);
//! an object of at most [`EAGER_CLUSTERS`] clusters is drawn at once.
//!
//! **Why it never drops a visible object.** The buffer's rule
//! ([`crate::cull::depth`]) hides a box only behind drawn polygons that
//! cover every pixel centre it could win, and each polygon drawn here is a
//! union of one opaque object's own triangles (see-through triangles are
//! never drawn), taken as far from the eye as its thickness allows (four
//! `f32` ulps of its coordinates: the merge keeps corners within two of
//! the plane), or the face of a proxy inside a closed object, drawn only
//! when the eye is outside the object's box and the box beyond the near
//! plane: then the object's own surface lies in front of the proxy at
//! every pixel centre the face covers ([`proxies`] gives the argument). What is drawn, and in which order, changes only how much is
//! culled.

mod offers;
mod proxies;
mod surfaces;

use std::sync::Arc;

use offers::{Offer, Offers, WHOLE};
use proxies::Proxies;
use surfaces::{Outside, Surfaces};

use super::depth::{CellRect, CellSize, DepthBuffer, Drawn, Footprint, Kernel, Scratch, Screen};
use super::occlusion::Visibility;
use super::occlusion::hierarchy;
use super::pool::BufferPool;
use super::{
    CullCounters, CullError, CullMethod, Culler, InFrustum, MethodEntry, MethodError,
    MethodOptions, Occludees, Preparation, Ranged, View, VisibleSet,
};
use crate::geom::{ALL_PLANES, Aabb, PlaneMask, Side};
use crate::scene::{BakeCache, Scene};
use crate::spatial::{KdTree, NodeKind};

/// The method's registry entry.
pub const ENTRY: MethodEntry = MethodEntry {
    name: "raster",
    purpose: "a conservative depth buffer on the CPU (SIMD) drawn from visible surfaces as a front-to-back walk finds them: general scenes",
    options: &OPTIONS,
    checked_with: &["cell=1", "simd=false:splits=0", "min_size=0:min_width=0:budget=64"],
    regions: Some("its depth buffer is drawn at the request's viewport for one camera: the views of a region cover other pixels"),
    build,
};

/// Pixels per cell side: 2 by default, a quarter of the cells to fill
/// for a little less culled (docs/raster.md measures both).
const CELL: Ranged<usize> = Ranged {
    key: "cell",
    noun: "a whole number of pixels",
    default: 2,
    min: 1,
    max: 8,
};

/// A visible object's surfaces narrower than this on screen (pixels,
/// across their bounding sphere) are not drawn: they would fill few cells
/// for the cost of setting them up (docs/raster.md measures 4 to 32).
const MIN_SIZE: Ranged<f64> = Ranged {
    key: "min_size",
    noun: "a number of pixels",
    default: 16.0,
    min: 0.0,
    max: 1e6,
};

/// A visible object's surfaces narrower than this on screen (cells, across
/// their width) are not drawn: a cell is written only where one polygon
/// covers all of it, so a sliver a cell or two wide writes a cell or none
/// per row it raises (docs/raster.md measures 0 to 3 cells).
const MIN_WIDTH: Ranged<f64> = Ranged {
    key: "min_width",
    noun: "a number of cells",
    default: 1.0,
    min: 0.0,
    max: 1e6,
};

/// An object's box not hidden whole is halved, and its halves tried, up
/// to this many times: a long box's nearest depth is far nearer than most
/// of it. A kd node's box is halved at most [`NODE_SPLITS`] times.
const SPLITS: Ranged<u32> = Ranged {
    key: "splits",
    noun: "a whole number",
    default: 6,
    min: 0,
    max: 6,
};

/// At most this many halvings of a kd node's box: a node not hidden is
/// walked into, and its children and objects are tested on their own,
/// so halving it further costs more than it culls (docs/raster.md).
const NODE_SPLITS: u32 = 2;

/// Most polygons drawn per frame: a bound on a frame's work where much is
/// near the eye (what is not drawn only hides less).
const BUDGET: Ranged<u32> = Ranged {
    key: "budget",
    noun: "a whole number of polygons",
    default: 1_000_000,
    min: 0,
    max: 1_000_000,
};

const OPTIONS: [&str; 7] = [
    CELL.key,
    MIN_SIZE.key,
    MIN_WIDTH.key,
    SPLITS.key,
    BUDGET.key,
    "simd",
    "proxies",
];

fn build(p: &Preparation<'_>) -> Result<Arc<dyn Culler>, String> {
    let scene = p.scene().clone();
    let started = std::time::Instant::now();
    let cache = p.context().bake_dir.as_ref().map(BakeCache::new);
    let proxies = Proxies::build_cached(&scene, cache.as_ref());
    let surfaces = Surfaces::build(&scene, &proxies);
    tracing::info!(
        scene = %scene.id,
        polygons = surfaces.len(),
        proxies = proxies.len(),
        ms = started.elapsed().as_millis() as u64,
        "merged raster surfaces"
    );
    if surfaces.len() == 0 {
        return Err("the scene has no opaque surface to draw".into());
    }
    let b = scene.bounds();
    let radius = b.min.abs().max(b.max.abs()).as_dvec3().length();
    Ok(Arc::new(RasterCulling {
        tree: p.kd_tree(),
        scene,
        surfaces,
        radius,
        pool: Arc::new(CanvasPool(BufferPool::new(POOLED))),
    }))
}

/// The method for one scene.
pub struct RasterCulling {
    scene: Arc<Scene>,
    tree: Arc<KdTree>,
    surfaces: Surfaces,
    /// Bounds every scene-local coordinate.
    radius: f64,
    pool: Arc<CanvasPool>,
}

/// What one frame draws into and keeps track with; lent by the pool, so
/// that a stateless request allocates nothing once the server is warm.
struct Canvas {
    buffer: DepthBuffer,
    scratch: Scratch,
    /// Per object, the frame that last offered its surfaces.
    offered: Vec<u32>,
    frame: u32,
    stack: Vec<(u32, PlaneMask)>,
    /// Visible objects and clusters offered and not drawn yet.
    offers: Offers,
    /// The offers a test is about to draw, nearest first.
    due: Vec<u32>,
    /// Clusters of an object drawn at once.
    fresh: Vec<Offer>,
    /// How many times a box that is not hidden whole is halved and tried again.
    splits: u32,
    /// Polygons this frame may still draw.
    budget: u32,
    /// Surfaces smaller than this on screen (pixels across) are not drawn.
    min_size: f64,
    /// Surfaces narrower than this on screen (pixels, not cells) are not drawn.
    min_width: f64,
    /// Whether closed objects' proxies are drawn.
    proxies: bool,
}

impl Canvas {
    fn new(kernel: Kernel) -> Canvas {
        Canvas {
            buffer: DepthBuffer::new(kernel),
            scratch: Scratch::default(),
            offered: Vec::new(),
            frame: 0,
            stack: Vec::new(),
            offers: Offers::default(),
            due: Vec::new(),
            fresh: Vec::new(),
            splits: 0,
            budget: 0,
            min_size: 0.0,
            min_width: 0.0,
            proxies: true,
        }
    }

    /// Starts a frame over `objects` objects.
    fn begin(&mut self, objects: usize, (cols, rows): (usize, usize), state: &RasterState) {
        (self.splits, self.budget, self.proxies) = (state.splits, state.budget, state.proxies);
        (self.min_size, self.min_width) = (state.min_size, state.min_width * state.cell as f64);
        self.buffer.reset(cols, rows);
        self.offers.reset((cols, rows));
        self.offered.resize(objects, 0);
        self.frame = self.frame.wrapping_add(1);
        if self.frame == 0 {
            self.offered.fill(0);
            self.frame = 1;
        }
    }

    fn heap_bytes(&self) -> usize {
        self.buffer.heap_bytes()
            + self.offered.capacity() * 4
            + self.stack.capacity() * 8
            + self.offers.heap_bytes()
            + self.due.capacity() * 4
            + self.fresh.capacity() * std::mem::size_of::<Offer>()
    }
}

/// Objects of at most this many clusters are drawn when found visible,
/// not offered to wait: waiting would cost each failing test a look at
/// them, about what drawing them costs (the generated CAD body's 400
/// parts on its orbit: 7.8 ms a frame at 2, 7.7 at 8; docs/raster.md).
const EAGER_CLUSTERS: usize = 8;

/// Canvases of clients that are gone, lent to new ones: a stateless
/// request would otherwise allocate, and fault in, a whole buffer.
struct CanvasPool(BufferPool<Canvas>);

/// Most canvases a pool keeps (about a busy server's concurrent stateless
/// requests); more are freed.
const POOLED: usize = 16;

impl CanvasPool {
    fn take(&self, kernel: Kernel) -> Canvas {
        let mut canvas = self.0.take().unwrap_or_else(|| Canvas::new(kernel));
        canvas.buffer.set_kernel(kernel);
        canvas
    }

    fn put(&self, canvas: Canvas) {
        self.0.put(canvas);
    }
}

/// A client's state: options, last frame's answer, and a canvas.
pub struct RasterState {
    cell: usize,
    min_size: f64,
    min_width: f64,
    splits: u32,
    budget: u32,
    proxies: bool,
    kernel: Kernel,
    /// The objects last frame found visible (empty before the first).
    last: Vec<u32>,
    /// Lent by the pool on the first frame, given back when dropped.
    canvas: Option<Canvas>,
    pool: Arc<CanvasPool>,
}

impl Drop for RasterState {
    fn drop(&mut self) {
        if let Some(canvas) = self.canvas.take() {
            self.pool.put(canvas);
        }
    }
}

impl RasterCulling {
    /// Offers the surfaces of object `id` (once a frame) for drawing: the
    /// object waits in the canvas, by its box, until a box behind it is
    /// tested ([`RasterCulling::hides_drawing`]); then its clusters do.
    fn offer_object(&self, view: &View, screen: &Screen, id: u32, canvas: &mut Canvas) {
        if canvas.offered[id as usize] == canvas.frame {
            return;
        }
        canvas.offered[id as usize] = canvas.frame;
        let bounds = &self.scene.objects()[id as usize].bounds;
        let (side, crossed) = view.frustum().classify(bounds, ALL_PLANES);
        let footprint = screen.footprint(bounds);
        let (rect, w) = match footprint {
            Footprint::Nothing => return,
            Footprint::Near => (screen.everywhere(), f32::INFINITY),
            Footprint::Cells(rect, w) => (rect, w),
        };
        if side == Side::Outside {
            return;
        }
        // Seen from outside its box, all of it beyond the near plane, a
        // closed object's faces turned away lie behind those turned
        // towards the eye, and its proxies behind its faces.
        // (Decided on the box's own corners, the near plane moved by the
        // rounding slack, not on its rounded centre and extent.)
        let outside = bounds.distance_to(view.eye()) > 0.0 && footprint != Footprint::Near;
        let away = match self.surfaces.outside(id) {
            Outside::Front if outside => -1.0,
            Outside::Back if outside => 1.0,
            _ => 0.0,
        };
        let object = Offer {
            object: id,
            cluster: WHOLE,
            scale: 0.0,
            crossed,
            away,
            outside,
            rect,
            w,
            distance: 0.0,
        };
        if self.surfaces.clusters_of(id).len() > EAGER_CLUSTERS {
            canvas.offers.add(object);
            return;
        }
        // A small object is drawn at once: waiting would cost each test
        // that passes it about as much as drawing it.
        let mut fresh = std::mem::take(&mut canvas.fresh);
        fresh.clear();
        self.offer_clusters(view, screen, &object, canvas.min_size, canvas.proxies, &mut fresh);
        fresh.sort_unstable_by(|a, b| a.distance.total_cmp(&b.distance));
        for p in &fresh {
            self.draw_cluster(view, screen, p, canvas);
        }
        canvas.fresh = fresh;
    }

    /// Into `out`, the clusters of an offered object: each on view with a
    /// surface at least `min_size` pixels across (and its proxies' only
    /// when `proxies`).
    fn offer_clusters(
        &self,
        view: &View,
        screen: &Screen,
        object: &Offer,
        min_size: f64,
        proxies: bool,
        out: &mut Vec<Offer>,
    ) {
        for (i, cluster) in self.surfaces.clusters_of(object.object).iter().enumerate() {
            if cluster.inner && !(object.outside && proxies) {
                continue;
            }
            let scale = screen.pixels_per_unit(&cluster.bounds);
            if 2.0 * cluster.largest * scale < min_size {
                continue;
            }
            // Only the planes the object's box crosses can cut its clusters;
            // tested before the footprint, which costs more and is wanted
            // for fewer (most of a part reaching out of the view is off it).
            let (side, crossed) = view.frustum().classify(&cluster.bounds, object.crossed);
            if side == Side::Outside {
                continue;
            }
            let (rect, w) = match screen.footprint(&cluster.bounds) {
                Footprint::Nothing => continue,
                Footprint::Near => (screen.everywhere(), f32::INFINITY),
                Footprint::Cells(rect, w) => (rect, w),
            };
            out.push(Offer {
                cluster: i as u32,
                scale,
                crossed,
                // Proxies' normals point out of their boxes.
                away: if cluster.inner { -1.0 } else { object.away },
                rect,
                w,
                distance: cluster.bounds.distance_to(view.eye()),
                ..*object
            });
        }
    }

    /// Whether the buffer hides `rect` at inverse depth `w` once the
    /// offered clusters that can make a difference are drawn: while some
    /// cell of `rect` is open, those whose box covers that cell and may be
    /// nearer than `w` are drawn, nearest first. A cluster drawn later
    /// can still hide `rect` only where it covers an open cell, so the
    /// answer is the one drawing every offered cluster at once would give,
    /// for drawing only what a test needs.
    fn hides_drawing(&self, view: &View, screen: &Screen, rect: CellRect, w: f32, canvas: &mut Canvas) -> bool {
        if canvas.offers.is_empty() {
            return canvas.buffer.hides(rect, w);
        }
        let mut due = std::mem::take(&mut canvas.due);
        let hidden = loop {
            let Some(cell) = canvas.buffer.open_cell(rect, w) else {
                break true;
            };
            canvas.offers.covering(cell, w, &mut due);
            if due.is_empty() {
                break false;
            }
            // Objects are split into their clusters first.
            if due.iter().any(|&i| canvas.offers.get(i).cluster == WHOLE) {
                let mut fresh = std::mem::take(&mut canvas.fresh);
                for &i in &due {
                    if canvas.offers.get(i).cluster == WHOLE {
                        let object = canvas.offers.take(i);
                        fresh.clear();
                        self.offer_clusters(view, screen, &object, canvas.min_size, canvas.proxies, &mut fresh);
                        for &cluster in &fresh {
                            canvas.offers.add(cluster);
                        }
                    }
                }
                canvas.fresh = fresh;
                continue;
            }
            due.sort_unstable_by(|&a, &b| {
                let (a, b) = (canvas.offers.get(a), canvas.offers.get(b));
                a.distance.total_cmp(&b.distance)
            });
            for &i in &due {
                let cluster = canvas.offers.take(i);
                self.draw_cluster(view, screen, &cluster, canvas);
                if canvas.buffer.cell_above(cell, w) {
                    break;
                }
            }
        };
        canvas.due = due;
        hidden
    }

    /// Draws the surfaces of one offered cluster, up to the frame's budget.
    fn draw_cluster(&self, view: &View, screen: &Screen, p: &Offer, canvas: &mut Canvas) {
        // Drawing fewer surfaces only hides less: skip clusters and
        // surfaces hidden already, too small or off the view, and back
        // faces of closed objects. Whole, not halved: a cluster not
        // hidden whole has each of its polygons tested on its own anyway.
        if canvas.budget == 0 || canvas.buffer.hides(p.rect, p.w) {
            return;
        }
        let (eye, planes) = (view.eye(), view.frustum().planes());
        let (min_size, min_width) = (canvas.min_size, canvas.min_width);
        let cluster = &self.surfaces.clusters_of(p.object)[p.cluster as usize];
        for s in self.surfaces.of_cluster(cluster) {
            // Largest first: the first too small at the cluster's nearest
            // depth ends it.
            if 2.0 * s.radius * p.scale < min_size {
                break;
            }
            // Only the planes the cluster's box crosses can have the
            // surface outside.
            if p.away * s.plane.signed_distance(eye) > 0.0
                || planes.iter().enumerate().any(|(k, plane)| {
                    p.crossed & (1 << k) != 0 && plane.signed_distance(s.centre) < -s.radius
                })
                || {
                    let across = screen.pixels_across(s.centre, s.radius);
                    across < min_size || across * s.breadth < min_width
                }
            {
                continue;
            }
            let drawn = screen.draw(
                self.surfaces.corners(s),
                &s.plane,
                s.thickness,
                &mut canvas.buffer,
                &mut canvas.scratch,
            );
            if drawn == Drawn::Raised {
                canvas.budget -= 1;
                if canvas.budget == 0 {
                    return;
                }
            }
        }
    }

    /// What the buffer says of a box.
    fn visibility(&self, view: &View, screen: &Screen, b: &Aabb, splits: u32, canvas: &mut Canvas) -> Visibility {
        if self.hidden(view, screen, b, splits, canvas) {
            Visibility::Invisible
        } else {
            Visibility::Partial
        }
    }

    /// Whether the buffer hides all of `b`: its outline at its nearest
    /// depth, or else each of its halves (along its longest side, down to
    /// `splits` times), whose nearest depths are farther. An outline not
    /// hidden first has the offered clusters that may hide it drawn.
    fn hidden(&self, view: &View, screen: &Screen, b: &Aabb, splits: u32, canvas: &mut Canvas) -> bool {
        let whole = match screen.footprint(b) {
            Footprint::Near => false,
            Footprint::Nothing => return true,
            Footprint::Cells(rect, w) => self.hides_drawing(view, screen, rect, w, canvas),
        };
        whole
            || (splits > 0 && {
                let axis = b.longest_axis();
                let mid = (b.min[axis] + b.max[axis]) * 0.5;
                let (mut lo, mut hi) = (*b, *b);
                (lo.max[axis], hi.min[axis]) = (mid, mid);
                self.hidden(view, screen, &lo, splits - 1, canvas)
                    && self.hidden(view, screen, &hi, splits - 1, canvas)
            })
    }

    /// The walk: front to back, nodes and objects tested against the
    /// buffer, visible objects added and offered for drawing as they are
    /// found.
    fn walk(&self, view: &View, screen: &Screen, canvas: &mut Canvas, out: &mut VisibleSet) -> u64 {
        let (nodes, objects) = (self.tree.nodes(), self.scene.objects());
        let eye = view.eye();
        let mut tested = 0u64;
        let mut stack = std::mem::take(&mut canvas.stack);
        stack.clear();
        if !nodes.is_empty() {
            stack.push((0, ALL_PLANES));
        }
        while let Some((i, mask)) = stack.pop() {
            let node = &nodes[i as usize];
            tested += 1;
            let (side, mask) = view.frustum().classify(&node.bounds, mask);
            if side == Side::Outside
                || self.hidden(view, screen, &node.bounds, canvas.splits.min(NODE_SPLITS), canvas)
            {
                continue;
            }
            match node.kind {
                NodeKind::Inner {
                    axis,
                    split,
                    children,
                    ..
                } => {
                    // Near child on top of the stack.
                    let below = eye[axis as usize] < split as f64;
                    let (near, far) = if below {
                        (children[0], children[1])
                    } else {
                        (children[1], children[0])
                    };
                    stack.push((far, mask));
                    stack.push((near, mask));
                }
                NodeKind::Leaf => {
                    for &id in self.tree.node_refs(node) {
                        if out.contains(id) {
                            continue;
                        }
                        let part = objects[id as usize].bounds.clipped(&node.cell);
                        if view.frustum().classify_exact(&part, mask).0 != Side::Outside
                            && self.visibility(view, screen, &part, canvas.splits, canvas)
                                != Visibility::Invisible
                        {
                            out.push(id);
                            self.offer_object(view, screen, id, canvas);
                        }
                    }
                }
            }
        }
        canvas.stack = stack;
        tested
    }
}

impl CullMethod for RasterCulling {
    type State = RasterState;

    fn name(&self) -> &'static str {
        "raster"
    }

    fn new_state(&self, options: &MethodOptions) -> Result<Self::State, MethodError> {
        let r = options.reader("raster", &OPTIONS);
        let cell = r.ranged(&CELL)?;
        let min_size = r.ranged(&MIN_SIZE)?;
        let min_width = r.ranged(&MIN_WIDTH)?;
        let splits = r.ranged(&SPLITS)?;
        let budget = r.ranged(&BUDGET)?;
        let proxies = r.flag("proxies", true)?;
        let kernel = if r.flag("simd", true)? {
            Kernel::detect()
        } else {
            Kernel::Scalar
        };
        r.finish()?;
        Ok(RasterState {
            cell,
            min_size,
            min_width,
            splits,
            budget,
            proxies,
            kernel,
            last: Vec::new(),
            canvas: None,
            pool: self.pool.clone(),
        })
    }

    fn is_conservative(&self, _: &Self::State) -> bool {
        true
    }

    fn cull(
        &self,
        view: &View,
        state: &mut Self::State,
        out: &mut VisibleSet,
        occludees: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        let screen = Screen::new(view, CellSize::square(state.cell), self.radius, state.kernel);
        let mut canvas = state.canvas.take().unwrap_or_else(|| state.pool.take(state.kernel));
        canvas.begin(self.scene.objects().len(), screen.cells(), state);
        let canvas = state.canvas.insert(canvas);
        let last = &mut state.last;

        // What likely hides the most, first: last frame's visible objects.
        for &id in last.iter() {
            self.offer_object(view, &screen, id, canvas);
        }

        let tested = self.walk(view, &screen, canvas, out);
        hierarchy::test_occludees(occludees, &mut |_, b| {
            self.visibility(view, &screen, b, canvas.splits, canvas)
        });
        last.clear();
        last.extend_from_slice(out.ids());
        Ok(CullCounters {
            nodes_tested: tested,
            in_frustum: InFrustum::Unknown,
        })
    }

    fn state_bytes(&self, state: &Self::State) -> usize {
        std::mem::size_of::<Self::State>()
            + state.last.capacity() * 4
            + state.canvas.as_ref().map_or(0, Canvas::heap_bytes)
    }
}
