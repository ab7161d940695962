//! `ddo`: directional discretized occluders (Bernardini, El-Sana,
//! Klosowski 2000) for scenes of many small triangles, where no single
//! polygon hides much (CAD assemblies, scans).
//!
//! The bake ([`bake`], §3) builds an octree over the static triangles and
//! marks, for each face of each node and each viewspace region
//! ([`regions`]), whether the face is a valid occluder from every eye of
//! the region: whether the scene's opaque triangles between those eyes and
//! the face hide all of it ([`validity`], whose doc says why that holds and
//! why rounding cannot break it).
//!
//! At run time (§4, Fig. 7) the octree is walked front to back (the eye's
//! octant first, then by the eye's side of each splitting plane). A node
//! outside the frustum is dropped; one the occlusion map hides is
//! dropped; a visible leaf reports its objects (each one whose box touches
//! the frustum). When a node is done, each of its faces that the node lies
//! between the eye and (the eye at least [`CLIP`] node sizes away) and
//! whose mask has the eye's region is added to a map.
//!
//! **The screen map** (`map=screen`, the default). Faces valid from the
//! eye are drawn, at their own depth, into the conservative depth buffer
//! of [`crate::cull::depth`] at the viewport's pixel centres, and nodes
//! (and, in a visible leaf, each object's part in the leaf) are tested by
//! their outline at their nearest depth. A face valid from the eye has the
//! bake's opaque triangles in front of it along every ray from the eye
//! through it, which is all the buffer's rule asks of a polygon (its
//! module doc is the argument, roundings included): a box is hidden only
//! where every pixel centre it covers is covered by such a face nearer
//! than all of it, so truth's nearest surface there is nearer still. The
//! depth test needs no front-to-back order, so faces wait for nothing; a
//! box reaching the near plane is never hidden, and a face is clipped to
//! beyond it. Sampling at pixel centres as truth does closes the seams
//! between neighbouring faces, of one plane or of several, that the
//! coordinate-plane maps below leave open; docs/ddo.md measures both.
//! With `cell=n` the buffer's cells are `n × n` pixels (`cell=2x3`: two
//! across, three down), each written only where one polygon covers all of
//! its centres: the same argument, fewer cells to write and test, usually
//! less hidden (seams open again, up to a cell wide).
//!
//! **Solid occluders** ([`solid`], screen map only). The bake also finds
//! rectangles proved to lie inside closed opaque surfaces, valid from any
//! eye outside the surface's box; they are drawn like faces, at their own
//! depth, only when the whole box lies beyond the near plane (so the
//! triangle that hides a rectangle is not clipped away). Those of large
//! surfaces (a body's skin) are drawn before anything is tested; those of
//! one object's small closed part once that object is found visible: one
//! hidden lies behind what is drawn already and would add nothing. A
//! rectangle hides only what lies past its plane from the eye, so one
//! past whose plane no other object's box reaches (the far half of a
//! closed body with nothing outside it) is not drawn; a large surface's
//! are drawn only within the screen rectangle of the other objects'
//! boxes, and of a part's cross-sections only the one the view shows
//! largest. Drawing less can only leave more visible. With
//! `traversal=objects` the octree is not walked: the objects in the
//! frustum, nearest box first, are tested by their boxes against the
//! solids drawn so far. The depth test needs no order, so the order only
//! decides how much is hidden, never whether a hidden box is truly hidden.
//!
//! **The maps' planes** (§4.2, `map=exact|grid`). The paper projects onto
//! the coordinate plane most facing the view (`planes=best`): points are
//! projected from the eye onto `z = 1`, `z` being the distance along that
//! axis, and a face perpendicular to the plane projects to a trapezoid, of
//! which the largest axis-aligned rectangle inside is added. By default
//! (`planes=all`) there is a map per coordinate plane and direction, each
//! taking the faces parallel to it as exact rectangles, and a node is
//! hidden when one map hides it (or, with `splits`, when each quarter of
//! its cone of directions is hidden by some map). Only points at a depth
//! of at least a small positive share of the scene's size are projected:
//! a node reaching nearer (beside or behind the plane through the eye, or
//! across the near plane) is never hidden by that map, and an occluder
//! face is cut to its part beyond that depth.
//!
//! **Why a hidden node is hidden.** A node is tested after every node that
//! added an occluder: those precede it in a front-to-back order, so along
//! any ray from the eye the node's points come after the ray crosses the
//! splitting plane between them, hence after the occluder face (the face
//! lies on the eye's side of that plane). A point whose projection lies
//! in an occluder's rectangle lies on a ray through that occluder face, so
//! behind the opaque triangles that the bake proved to hide the face. When
//! the eye lies exactly on a splitting plane, rays within that plane have
//! no such order: faces added inside that node's subtree wait until the
//! node is done. The hiding triangles lie between the face and the plane
//! `t = H < 2s` of the face's frame, so along the ray at least `1 − 2s/h`
//! of the way to the face (the eye `h ≥ 2s` away); a face is only used
//! when that share of its nearest view depth is beyond the near plane, so
//! no triangle the near plane clips away is relied on.

mod bake;
mod map;
mod octree;
mod regions;
mod solid;
mod validity;

use std::cmp::Ordering;
use std::sync::Arc;

use glam::{DVec2, DVec3};

pub use bake::bake;
pub use map::{CellGrid, OcclusionMap, Rect, RectUnion};
pub use octree::{Node, Octree, OctreeParams};
pub use regions::Regions;
pub use solid::{Beyond, Solid, SolidRect};
pub use validity::CLIP;

use super::{
    CullCounters, CullError, CullMethod, Culler, InFrustum, MethodEntry, MethodError,
    MethodOptions, Occludees, Preparation, Ranged, View, VisibleSet,
};
use super::depth::{CellRect, CellSize, DepthBuffer, Footprint, Kernel, Scratch, Screen};
use crate::geom::{ALL_PLANES, Aabb, Plane, PlaneMask, Side, ordered_bits};
use super::subtree::frustum_cull_subtree;
use crate::scene::{BakeCache, Scene};
use crate::spatial::KdTree;

/// `regions=32|64`: which of the baked masks is used.
const REGIONS: &str = "regions";

/// `map=screen|exact|grid`: the occlusion map's form: a depth buffer at
/// the viewport's pixel centres, or rectangles on coordinate planes
/// ([`map`]).
const MAP: &str = "map";

/// Cells along each side of the grid map.
const CELLS: Ranged<usize> = Ranged {
    key: "cells",
    noun: "a whole number",
    default: 256,
    min: 8,
    max: 1024,
};

/// `planes=all|best`: a map per coordinate plane and direction, each
/// taking the faces parallel to it, or only the plane most facing the view
/// (the paper's), taking every face.
const PLANES: &str = "planes";

/// `traversal=octree|objects`: the paper's front-to-back octree walk, or
/// (with the screen map) the objects in the frustum nearest first, each
/// tested by its box against the solid occluders ([`solid`]) of the
/// objects found visible before it; the octree faces are not drawn.
const TRAVERSAL: &str = "traversal";

/// Pixels per cell of the screen map, square (`cell=2`) or across × down
/// (`cell=2x3`): 1 by default. Coarser cells are fewer to write and test,
/// and usually hide less: a cell is written only where one polygon covers
/// all of its pixel centres, so each section loses a rim and neighbouring
/// skin rectangles leave seams. Taller cells cost less for what they hide
/// (a draw's cost follows its rows): docs/ddo.md measures the trade at
/// 1024×768.
const CELL: Ranged<CellSize> = Ranged {
    key: "cell",
    noun: "a whole number of pixels a side (2) or across x down (2x3), each",
    default: CellSize::square(1),
    min: CellSize::square(1),
    max: CellSize::square(8),
};

const OPTIONS: [&str; 7] = [REGIONS, MAP, CELLS.key, PLANES, SPLITS.key, TRAVERSAL, CELL.key];

/// Projected depths below this share of the scene's size (plus the eye's
/// distance from its origin) are not projected: far above the rounding of
/// the depth itself, so a projected coordinate is off by at most ~10⁻¹⁰ of
/// its size, which the map's slack covers.
const DEPTH_FLOOR: f64 = 1e-6;

/// A direction is carried to another map only when its component along
/// that map's axis is at least this share of its length (within ~89.9999°).
const DIRECTION_FLOOR: f64 = 1e-6;

/// How many times a node's cone of directions is quartered when no one
/// map hides it whole (by default never: measured, it costs more than it
/// hides).
const SPLITS: Ranged<u32> = Ranged {
    key: "splits",
    noun: "a whole number",
    default: 0,
    min: 0,
    max: 4,
};

/// When the frustum reaches the map plane's horizon, the map spans this
/// window (±89° from the axis); rectangles leaving it are never hidden.
const WIDE_WINDOW: f64 = 64.0;

/// A face is used only when its triangles are beyond the near plane by
/// this share of the near distance (plus the scene-size floor).
const NEAR_SLACK: f64 = 1e-6;

/// The method's registry entry; the table checks the 32-region masks, the
/// plane maps, the objects traversal and coarser screen cells too.
pub const ENTRY: MethodEntry = MethodEntry {
    name: "ddo",
    purpose: "directional discretized occluders baked into an octree (Bernardini et al.): dense CAD models",
    options: &OPTIONS,
    checked_with: &[
        "regions=32",
        "map=exact",
        "map=grid:cells=16",
        "map=exact:splits=2",
        "traversal=objects",
        "traversal=objects:cell=2",
        "traversal=objects:cell=2x3",
    ],
    regions: Some("its octree faces are proven occluders from direction regions of single eyes, not shrunk for a ball of eyes, and its occlusion map is drawn on one camera's plane"),
    build,
};

fn build(p: &Preparation<'_>) -> Result<Arc<dyn Culler>, String> {
    // DDO masks only where they pay (DESIGN "Scenes"): a height field of
    // closed solids on a ground is horizon's, which hides with its prisms
    // at a fraction of a bake's cost.
    if p.prisms().is_ok() {
        return Err("the scene is a height field of solids on a ground: horizon's prisms serve it, DDO masks would not pay".into());
    }
    let scene = p.scene().clone();
    let params = p.context().ddo_octree;
    let tree = match &p.context().bake_dir {
        Some(dir) => bake::bake_cached(&scene, params, &BakeCache::new(dir))?,
        None => bake(&scene, params)?,
    };
    Ok(Arc::new(DdoCulling::new(scene, tree, p.kd_tree())))
}

/// Octree traversal against an occlusion map of baked DDOs.
pub struct DdoCulling {
    scene: Arc<Scene>,
    tree: Octree,
    /// The scene's kd-tree: `traversal=objects` finds the objects in the
    /// frustum with it, as `frustum` does.
    kd: Arc<KdTree>,
    /// Bounds every coordinate of the octree's cube.
    radius: f64,
    /// Per node, the `f32` box that holds it (rounding outwards costs
    /// more than reading it).
    bounds: Vec<Aabb>,
    /// Solids drawn before anything is tested: the large ones and those
    /// of several objects (indices into the octree's solids), each with
    /// the box around every other object's. A solid is drawn only on
    /// that box's screen rectangle, where every object it can hide lies
    /// (a skin's rim, with nothing inside behind it, is not drawn); the
    /// walk's nodes reaching past it are not helped there.
    first_solids: Vec<(u32, Aabb)>,
    /// Per object, its own small solids: drawn once it is found visible
    /// (one hidden hides nothing that is not hidden already).
    object_solids: Vec<Vec<u32>>,
    /// How far a solid's rectangle may stray from its plane by rounding.
    margin: f64,
    /// Per object, its box: read in order of depth, where the objects'
    /// own records lie apart.
    boxes: Vec<Aabb>,
    /// Per large solid and rectangle, the sides of its plane an object
    /// reaches into: a rectangle with nothing beyond it from the eye (the
    /// far half of a closed body with nothing outside it) is not drawn
    /// (none for a part: its [`Shown`] records hold their own).
    beyond: Vec<Vec<Beyond>>,
    /// Per part's solid, its rectangles' [`Shown`], largest first: a part
    /// draws the one a view shows largest (none for a large solid).
    shown: Vec<Vec<Shown>>,
}

impl DdoCulling {
    /// The method for `scene` with its baked octree and its kd-tree.
    pub fn new(scene: Arc<Scene>, tree: Octree, kd: Arc<KdTree>) -> DdoCulling {
        let radius = tree.nodes().first().map_or(0.0, |root| {
            root.min.abs().max(root.max().abs()).length()
        });
        let bounds = tree.nodes().iter().map(Node::bounds).collect();
        let boxes: Vec<Aabb> = scene.objects().iter().map(|o| o.bounds).collect();
        let mut first_solids = Vec::new();
        let mut object_solids = vec![Vec::new(); scene.objects().len()];
        for (k, s) in tree.solids().iter().enumerate() {
            match s.object {
                Some(o) if !s.large => object_solids[o as usize].push(k as u32),
                own => {
                    let mut others = Aabb::EMPTY;
                    for (o, b) in boxes.iter().enumerate() {
                        if own != Some(o as u32) {
                            others.merge(b);
                        }
                    }
                    first_solids.push((k as u32, others));
                }
            }
        }
        let margin = validity::margin(scene.bounds().extent().max_element() as f64);
        // A large solid draws all its rectangles that have something
        // beyond them; a part chooses one, its `Beyond` kept in its `shown`.
        let (beyond, shown) = tree
            .solids()
            .iter()
            .zip(solid::beyond(tree.solids(), &boxes))
            .map(|(s, beyond)| if s.large { (beyond, Vec::new()) } else { (Vec::new(), Shown::largest_first(&s.rects, &beyond)) })
            .unzip();
        DdoCulling {
            boxes,
            beyond,
            shown,
            scene,
            tree,
            kd,
            radius,
            bounds,
            first_solids,
            object_solids,
            margin,
        }
    }

    /// Draws solid `k`, within cells `within`, when its whole box lies
    /// beyond the near plane ([`solid`]'s doc says why it hides from such
    /// an eye then): a large one's rectangles (its cover, in the order the
    /// bake chose), a part's one the view shows largest.
    fn draw_solid(&self, k: u32, within: CellRect, view: &View, screen: &Screen, canvas: &mut Canvas, floor: f64) {
        let s = &self.tree.solids()[k as usize];
        let needed = view.camera().near * (1.0 + NEAR_SLACK) + floor;
        if nearest_depth(view, s.lo, s.hi).partial_cmp(&needed).is_none_or(Ordering::is_lt) {
            return;
        }
        let eye = view.eye();
        let draw = |r: &SolidRect, canvas: &mut Canvas| {
            let plane = Plane {
                normal: r.normal,
                d: r.d,
            };
            screen.draw_within(&r.corners, &plane, self.margin, within, &mut canvas.buffer, &mut canvas.scratch);
        };
        if s.large {
            for (r, beyond) in s.rects.iter().zip(&self.beyond[k as usize]) {
                if beyond.from(r, eye) {
                    draw(r, canvas);
                }
            }
            return;
        }
        if let Some(r) = Shown::largest_seen(&self.shown[k as usize], &s.rects, eye) {
            draw(r, canvas);
        }
    }

    /// `traversal=objects`: each object in the frustum, nearest first,
    /// tested by its box; one found visible has its own solids drawn.
    fn cull_objects(&self, view: &View, screen: &Screen, floor: f64, state: &mut DdoState, out: &mut VisibleSet) -> CullCounters {
        state.in_frustum.clear();
        // (The kd-tree holds the static objects, movable ones left to the
        // dispatch as for every method; a scene of none has no root.)
        if !self.kd.nodes().is_empty() {
            frustum_cull_subtree(&self.kd, &self.scene, view.frustum(), 0, ALL_PLANES, &mut state.in_frustum, None);
        }
        state.order.clear();
        for &id in state.in_frustum.ids() {
            let b = &self.boxes[id as usize];
            let depth = nearest_depth(view, b.min.as_dvec3(), b.max.as_dvec3());
            state.order.push((ordered_bits(depth) & !u64::from(u32::MAX)) | u64::from(id));
        }
        state.order.sort_unstable();
        let canvas = state.canvas.as_mut().expect("objects are tested on the screen map");
        for id in state.order.iter().map(|&key| key as u32) {
            if !screen_hides(screen, &mut canvas.buffer, &self.boxes[id as usize]) {
                out.push(id);
                for &k in &self.object_solids[id as usize] {
                    self.draw_solid(k, screen.everywhere(), view, screen, canvas, floor);
                }
            }
        }
        CullCounters {
            nodes_tested: state.order.len() as u64,
            in_frustum: InFrustum::Unknown,
        }
    }

    /// The octree and its masks.
    pub fn octree(&self) -> &Octree {
        &self.tree
    }
}

/// What a view can show of a solid's rectangle, for choosing a part's
/// largest on screen: all the choice reads of it, side by side in one
/// record, as the rectangles themselves lie apart.
#[derive(Clone, Copy, Debug)]
struct Shown {
    /// Its index among the solid's rectangles.
    rect: u32,
    beyond: Beyond,
    /// Its area times its normal.
    across: DVec3,
    centre: DVec3,
    /// The most any eye sees of it, as the choice measures it (shown
    /// area squared): `|across|²`.
    most: f64,
}

impl Shown {
    /// Of each of `rects` (with its [`Beyond`]), the largest first.
    fn largest_first(rects: &[SolidRect], beyond: &[Beyond]) -> Vec<Shown> {
        debug_assert_eq!(rects.len(), beyond.len(), "a Beyond per rectangle");
        let mut shown: Vec<Shown> = rects
            .iter()
            .zip(beyond)
            .enumerate()
            .map(|(k, (r, &beyond))| {
                let across = r.normal * r.area();
                Shown {
                    rect: k as u32,
                    beyond,
                    across,
                    centre: r.centre(),
                    most: across.length_squared(),
                }
            })
            .collect();
        shown.sort_by(|a, b| b.most.total_cmp(&a.most).then(a.rect.cmp(&b.rect)));
        shown
    }

    /// Of `rects` (with their `shown`, largest first), the one `eye` sees
    /// largest among those with something beyond them from it: by shown
    /// area squared, `area² · cos²`, no square root. Between two seen
    /// within rounding of each other it may pick either: the choice only
    /// decides how much is hidden.
    fn largest_seen<'a>(shown: &[Shown], rects: &'a [SolidRect], eye: DVec3) -> Option<&'a SolidRect> {
        // The best seen as a fraction `num / den`, compared across
        // (no division on the way).
        let (mut num, mut den, mut best) = (0.0, 1.0, None);
        for shown in shown {
            // None shows more than its whole area: once the largest left
            // are smaller than the best seen, none of them can beat it.
            if shown.most * den <= num {
                break;
            }
            let to_eye = eye - shown.centre;
            let across = shown.across.dot(to_eye);
            let (n, d) = (across * across, to_eye.length_squared());
            // The eye lies on the normal's side where `across` is positive.
            if n * den > num * d && shown.beyond.past(across > 0.0) {
                (num, den, best) = (n, d, Some(shown.rect));
            }
        }
        best.map(|k| &rects[k as usize])
    }
}

/// A client's state: its options and the buffers of one traversal.
pub struct DdoState {
    regions: Regions,
    /// Only the plane most facing the view has a map (the paper's choice).
    best_plane: bool,
    /// How often a node's cone is quartered ([`SPLITS`]).
    splits: u32,
    /// One map per coordinate plane and direction ([`MapPlane::index`]).
    maps: [OcclusionMap; 6],
    /// The frame each object was last reported in.
    seen: Vec<u32>,
    frame: u32,
    /// Occluder rectangles (with their map) waiting for a node the eye's
    /// planes cut to end.
    pending: Vec<(usize, Rect)>,
    /// With `map=screen` (the default): a depth buffer at the viewport's
    /// pixel centres, in place of `maps`.
    canvas: Option<Canvas>,
    /// `traversal=objects`.
    by_object: bool,
    /// With `traversal=objects`: the objects in the frustum, and those
    /// nearest first, as sort keys: the top half of the [`ordered_bits`]
    /// of the box's nearest depth (a millionth of it: nearer ties only
    /// decide how much is hidden), the object below.
    in_frustum: VisibleSet,
    order: Vec<u64>,
}

/// A depth buffer at pixel centres (in cells of `cell` of them) and the
/// buffers its drawing reuses.
struct Canvas {
    buffer: DepthBuffer,
    scratch: Scratch,
    /// Pixels per cell ([`CELL`]).
    cell: CellSize,
}

impl CullMethod for DdoCulling {
    type State = DdoState;

    fn name(&self) -> &'static str {
        "ddo"
    }

    fn new_state(&self, options: &MethodOptions) -> Result<DdoState, MethodError> {
        let r = options.reader("ddo", &OPTIONS);
        let regions = match r.choice(REGIONS, &["64", "32"])? {
            "32" => Regions::R32,
            _ => Regions::R64,
        };
        let best_plane = r.choice(PLANES, &["all", "best"])? == "best";
        let splits = r.ranged(&SPLITS)?;
        let cells = r.ranged(&CELLS)?;
        let form = r.choice(MAP, &["screen", "exact", "grid"])?;
        let grid = form == "grid";
        let by_object = r.choice(TRAVERSAL, &["octree", "objects"])? == "objects";
        let cell = r.ranged(&CELL)?;
        r.finish()?;
        if by_object && form != "screen" {
            return Err(MethodError::InvalidOption {
                method: "ddo".into(),
                option: TRAVERSAL.into(),
                value: "objects".into(),
                expected: "octree with map=exact or map=grid: objects are tested on the screen map only".into(),
            });
        }
        // Each map's own options say nothing to the others.
        let (foreign, expected): (&[&str], _) = if form == "screen" {
            (
                &[PLANES, CELLS.key, SPLITS.key],
                "nothing with map=screen: it shapes the coordinate-plane maps of map=exact or map=grid",
            )
        } else {
            (&[CELL.key], "nothing with map=exact or map=grid: it sizes the cells of map=screen")
        };
        if let Some((key, value)) = options.iter().find(|(k, _)| foreign.contains(k)) {
            return Err(MethodError::InvalidOption {
                method: "ddo".into(),
                option: key.into(),
                value: value.into(),
                expected: expected.into(),
            });
        }
        let canvas = (form == "screen").then(|| Canvas {
            buffer: DepthBuffer::new(Kernel::detect()),
            scratch: Scratch::default(),
            cell,
        });
        let map = || {
            if grid {
                OcclusionMap::Grid(CellGrid::new(cells))
            } else {
                OcclusionMap::Exact(RectUnion::default())
            }
        };
        Ok(DdoState {
            regions,
            best_plane,
            splits,
            maps: std::array::from_fn(|_| map()),
            seen: vec![0; self.scene.objects().len()],
            frame: 0,
            pending: Vec::new(),
            canvas,
            by_object,
            in_frustum: VisibleSet::new(),
            order: Vec::new(),
        })
    }

    fn is_conservative(&self, _: &DdoState) -> bool {
        true
    }

    fn state_bytes(&self, state: &DdoState) -> usize {
        std::mem::size_of::<DdoState>()
            + state.maps.iter().map(OcclusionMap::heap_bytes).sum::<usize>()
            + state.seen.capacity() * 4
            + state.pending.capacity() * std::mem::size_of::<(usize, Rect)>()
            + state.canvas.as_ref().map_or(0, |c| c.buffer.heap_bytes())
            + state.order.capacity() * std::mem::size_of::<u64>()
            + state.in_frustum.heap_bytes()
    }

    fn cull(
        &self,
        view: &View,
        state: &mut DdoState,
        out: &mut VisibleSet,
        _: &mut Occludees,
    ) -> Result<CullCounters, CullError> {
        state.frame = state.frame.wrapping_add(1);
        if state.frame == 0 {
            state.seen.fill(0);
            state.frame = 1;
        }
        let projection = Projection::of(view, &self.scene);
        let content = self.scene.bounds();
        if state.canvas.is_none() {
            for (m, map) in state.maps.iter_mut().enumerate() {
                map.reset(projection.window(MapPlane::of_index(m), view, &content));
            }
        }
        state.pending.clear();
        let screen = state.canvas.as_mut().map(|canvas| {
            let screen = Screen::new(view, canvas.cell, self.radius, canvas.buffer.kernel());
            let (cols, rows) = screen.cells();
            canvas.buffer.reset(cols, rows);
            for (k, others) in &self.first_solids {
                if others.is_empty() {
                    continue; // no other object for it to hide
                }
                let within = match screen.footprint(others) {
                    Footprint::Nothing => continue,
                    Footprint::Near => screen.everywhere(),
                    Footprint::Cells(cells, _) => cells,
                };
                self.draw_solid(*k, within, view, &screen, canvas, projection.floor);
            }
            screen
        });
        if let (Some(screen), true) = (screen, state.by_object) {
            return Ok(self.cull_objects(view, &screen, projection.floor, state, out));
        }
        let mut walk = Walk {
            screen,
            culling: self,
            view,
            projection,
            state,
            out,
            tested: 0,
            deferring: 0,
        };
        walk.visit(0, ALL_PLANES);
        Ok(CullCounters {
            nodes_tested: walk.tested,
            in_frustum: InFrustum::Unknown,
        })
    }
}

/// The nearest view depth of the box `[lo, hi]`: at its corner most
/// against the view.
fn nearest_depth(view: &View, lo: DVec3, hi: DVec3) -> f64 {
    let (eye, forward) = (view.eye(), view.basis().forward);
    (0..3)
        .map(|i| (if forward[i] >= 0.0 { lo[i] } else { hi[i] } - eye[i]) * forward[i])
        .sum()
}

/// Whether `buffer` hides all of box `b`: it covers no pixel centre, or
/// every centre it covers holds an occluder nearer than all of it.
fn screen_hides(screen: &Screen, buffer: &mut DepthBuffer, b: &Aabb) -> bool {
    match screen.footprint(b) {
        Footprint::Near => false,
        Footprint::Nothing => true,
        Footprint::Cells(rect, w) => buffer.hides(rect, w),
    }
}

/// A map's plane: perpendicular to `axis`, looked at along `sign`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct MapPlane {
    axis: usize,
    /// +1 or −1.
    sign: i8,
}

impl MapPlane {
    /// The plane of map `m` (`2 × axis + (sign > 0)`).
    fn of_index(m: usize) -> MapPlane {
        MapPlane {
            axis: m / 2,
            sign: if m % 2 == 1 { 1 } else { -1 },
        }
    }

    /// Its map's index.
    fn index(self) -> usize {
        2 * self.axis + usize::from(self.sign > 0)
    }

    /// The two axes of its map.
    fn map_axes(self) -> (usize, usize) {
        ((self.axis + 1) % 3, (self.axis + 2) % 3)
    }
}

/// Perspective projection from the eye onto coordinate planes.
#[derive(Clone, Copy, Debug)]
struct Projection {
    eye: DVec3,
    /// The plane most facing the view (the paper's single map).
    best: MapPlane,
    /// Depths below this are not projected.
    floor: f64,
}

impl Projection {
    fn of(view: &View, scene: &Scene) -> Projection {
        let f = view.basis().forward;
        let axis = f.abs().max_position();
        let eye = view.eye();
        Projection {
            eye,
            best: MapPlane {
                axis,
                sign: if f[axis] >= 0.0 { 1 } else { -1 },
            },
            floor: DEPTH_FLOOR * (scene.bounds().extent().length() as f64 + eye.length()) + 1e-30,
        }
    }

    /// The depth of `p` along `plane`'s axis.
    fn depth(&self, plane: MapPlane, p: DVec3) -> f64 {
        f64::from(plane.sign) * (p[plane.axis] - self.eye[plane.axis])
    }

    /// `p` on `plane`'s map, when deep enough.
    fn project(&self, plane: MapPlane, p: DVec3) -> Option<DVec2> {
        let z = self.depth(plane, p);
        if z.partial_cmp(&self.floor).is_none_or(Ordering::is_lt) {
            return None;
        }
        let (a, b) = plane.map_axes();
        Some(DVec2::new(
            (p[a] - self.eye[a]) / z,
            (p[b] - self.eye[b]) / z,
        ))
    }

    /// The window of `plane`'s map: where the scene's box projects, when
    /// all of it is deep enough (the faces and nodes that matter lie
    /// inside it; a rectangle reaching outside is clipped, or not hidden),
    /// else the frustum's projection when every corner of that is deep
    /// enough, else the wide window.
    fn window(&self, plane: MapPlane, view: &View, content: &Aabb) -> Rect {
        let content = content.corners().map(|c| c.as_dvec3());
        let projected = self
            .around(plane, content)
            .or_else(|| self.around(plane, *view.frustum().corners()));
        match projected {
            Some(r) => {
                let pad = (r.hi - r.lo) * 1e-3 + DVec2::splat(1e-9);
                Rect {
                    lo: r.lo - pad,
                    hi: r.hi + pad,
                }
            }
            None => Rect {
                lo: DVec2::splat(-WIDE_WINDOW),
                hi: DVec2::splat(WIDE_WINDOW),
            },
        }
    }

    /// The rectangle around the projections of `points` on `plane`'s map,
    /// when every one of them is deep enough.
    fn around(&self, plane: MapPlane, points: impl IntoIterator<Item = DVec3>) -> Option<Rect> {
        let mut all = true;
        let r = Rect::around(points.into_iter().map_while(|p| {
            let q = self.project(plane, p);
            all &= q.is_some();
            q
        }));
        all.then_some(r)
    }

    /// The rectangle around the image on `to`'s map of the cone of
    /// directions `r` on `from`'s map, when every direction of it points
    /// into `to`'s half-space (the cone's image is then the convex
    /// quadrilateral of its four edges' images).
    fn reproject(&self, from: MapPlane, r: Rect, to: MapPlane) -> Option<Rect> {
        let (fa, fb) = from.map_axes();
        let (ta, tb) = to.map_axes();
        let mut points = [DVec2::ZERO; 4];
        for (k, p) in points.iter_mut().enumerate() {
            let mut d = DVec3::ZERO;
            d[from.axis] = f64::from(from.sign);
            d[fa] = if k & 1 == 0 { r.lo.x } else { r.hi.x };
            d[fb] = if k & 2 == 0 { r.lo.y } else { r.hi.y };
            let z = f64::from(to.sign) * d[to.axis];
            if z.partial_cmp(&(DIRECTION_FLOOR * d.length())).is_none_or(Ordering::is_lt) {
                return None;
            }
            *p = DVec2::new(d[ta] / z, d[tb] / z);
        }
        Some(Rect::around(points))
    }

    /// The rectangle around a node's projection on `plane`, when all of it
    /// is deep enough.
    fn node_rect(&self, plane: MapPlane, node: &Node) -> Option<Rect> {
        let (lo, hi) = (node.min, node.max());
        self.around(
            plane,
            (0..8).map(|k| {
                DVec3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                )
            }),
        )
    }

    /// A rectangle inside the projection on `plane` of the part of a face
    /// (perpendicular to `face_axis` at `w`, spanning `[lo, hi]` on the
    /// other axes) that is deep enough; `None` when nothing of it is.
    fn face_rect(&self, plane: MapPlane, face_axis: usize, w: f64, lo: DVec3, hi: DVec3) -> Option<Rect> {
        let (a, b) = plane.map_axes();
        let e = self.eye;
        if face_axis == plane.axis {
            let z = f64::from(plane.sign) * (w - e[face_axis]);
            if z.partial_cmp(&self.floor).is_none_or(Ordering::is_lt) {
                return None;
            }
            return Some(Rect {
                lo: DVec2::new((lo[a] - e[a]) / z, (lo[b] - e[b]) / z),
                hi: DVec2::new((hi[a] - e[a]) / z, (hi[b] - e[b]) / z),
            });
        }
        // The face spans depth along the plane's axis; along the third
        // axis `j` its projection shrinks with depth: a trapezoid, of which
        // this is the largest axis-aligned rectangle inside.
        let (z0, z1) = {
            let (p, q) = (self.depth(plane, lo), self.depth(plane, hi));
            (p.min(q).max(self.floor), p.max(q))
        };
        if z1.partial_cmp(&z0).is_none_or(Ordering::is_le) {
            return None;
        }
        let j = 3 - plane.axis - face_axis;
        let d = w - e[face_axis];
        let (i_lo, i_hi) = ((d / z0).min(d / z1), (d / z0).max(d / z1));
        let (j0, j1) = (lo[j] - e[j], hi[j] - e[j]);
        let (j_lo, j_hi) = ((j0 / z0).max(j0 / z1), (j1 / z0).min(j1 / z1));
        if j_hi.partial_cmp(&j_lo).is_none_or(Ordering::is_le) {
            return None;
        }
        let mut r = Rect {
            lo: DVec2::ZERO,
            hi: DVec2::ZERO,
        };
        for (slot, axis) in [a, b].into_iter().enumerate() {
            let (l, h) = if axis == face_axis {
                (i_lo, i_hi)
            } else {
                (j_lo, j_hi)
            };
            r.lo[slot] = l;
            r.hi[slot] = h;
        }
        Some(r)
    }
}

/// One traversal.
struct Walk<'a> {
    /// With `map=screen`, the view against the canvas.
    screen: Option<Screen>,
    /// The method: its octree, node boxes, scene and solids.
    culling: &'a DdoCulling,
    view: &'a View,
    projection: Projection,
    state: &'a mut DdoState,
    out: &'a mut VisibleSet,
    tested: u64,
    /// Nodes cut by a plane through the eye that are being walked.
    deferring: u32,
}

impl Walk<'_> {
    fn visit(&mut self, n: usize, mask: PlaneMask) {
        let node = self.culling.tree.nodes()[n];
        let bounds = self.culling.bounds[n];
        let frustum = self.view.frustum();
        let (side, mask) = if mask == 0 {
            (Side::Inside, 0)
        } else {
            frustum.classify(&bounds, mask)
        };
        if side == Side::Outside {
            return;
        }
        self.tested += 1;
        if self.hidden(&node, &bounds) {
            return;
        }
        if node.is_leaf() {
            for &id in self.culling.tree.objects_of(&node) {
                if self.state.seen[id as usize] == self.state.frame {
                    continue;
                }
                let object = &self.culling.scene.objects()[id as usize].bounds;
                // On a screen map, the object's part in the leaf (every
                // point of it that the leaf holds) is tested too: it may
                // be hidden where the leaf is not, and its other parts
                // are tested in their own leaves.
                let visible = match self.screen {
                    Some(screen) => {
                        let part = object.clipped(&bounds);
                        !part.is_empty()
                            && frustum.intersects(&part)
                            && !self.screen_hides(&screen, &part)
                    }
                    None => {
                        self.state.seen[id as usize] = self.state.frame;
                        frustum.intersects(object)
                    }
                };
                if visible {
                    self.state.seen[id as usize] = self.state.frame;
                    self.out.push(id);
                    if let (Some(screen), Some(canvas)) = (&self.screen, &mut self.state.canvas) {
                        for &k in &self.culling.object_solids[id as usize] {
                            self.culling.draw_solid(k, screen.everywhere(), self.view, screen, canvas, self.projection.floor);
                        }
                    }
                }
            }
        } else {
            let eye = self.view.eye();
            let centre = node.centre();
            let octant = (0..3).fold(0, |k, i| k | (usize::from(eye[i] >= centre[i]) << i));
            let cut = (0..3).any(|i| eye[i] == centre[i]);
            self.deferring += u32::from(cut);
            for k in 0..8 {
                self.visit(node.children as usize + (octant ^ k), mask);
            }
            if cut {
                self.deferring -= 1;
                if self.deferring == 0 {
                    for (m, r) in std::mem::take(&mut self.state.pending) {
                        self.state.maps[m].add(r);
                    }
                }
            }
        }
        self.add_faces(n, &node);
    }

    /// Whether every ray from the eye to the node passes through an
    /// occluder of some map: first the node's own rectangle on each map;
    /// then its rectangle on a plane it projects onto (the view's best,
    /// else another) as a cone of directions, in quarters down to
    /// `splits` levels ([`SPLITS`]), each tested against every map (which
    /// sees it as the rectangle around its four edges' images), so that a
    /// node seen past an edge or a corner of the surfaces in front, partly
    /// through faces of one plane and partly of another, can still be
    /// hidden.
    fn hidden(&mut self, node: &Node, bounds: &Aabb) -> bool {
        if let Some(screen) = self.screen {
            return self.screen_hides(&screen, bounds);
        }
        if self.state.maps.iter().all(OcclusionMap::is_empty) {
            return false;
        }
        for m in 0..6 {
            let map = &mut self.state.maps[m];
            if !map.is_empty()
                && self
                    .projection
                    .node_rect(MapPlane::of_index(m), node)
                    .is_some_and(|r| map.hides(r))
            {
                return true;
            }
        }
        if self.state.splits == 0 {
            return false;
        }
        let best = self.projection.best;
        let base = std::iter::once(best)
            .chain((0..6).map(MapPlane::of_index))
            .find_map(|plane| Some((plane, self.projection.node_rect(plane, node)?)));
        match base {
            Some((plane, r)) => self.quartered(plane, r, 1),
            None => false,
        }
    }

    /// Whether the screen map hides all of box `b`: it covers no pixel
    /// centre, or every centre it covers holds a face nearer than all of
    /// it.
    fn screen_hides(&mut self, screen: &Screen, b: &Aabb) -> bool {
        self.state
            .canvas
            .as_mut()
            .is_some_and(|canvas| screen_hides(screen, &mut canvas.buffer, b))
    }

    /// Whether each quarter of the cone `r` is [`Walk::covered`].
    fn quartered(&mut self, plane: MapPlane, r: Rect, depth: u32) -> bool {
        let mid = (r.lo + r.hi) * 0.5;
        (0..4).all(|q| {
            let (x, y) = (q & 1 == 1, q & 2 == 2);
            let quarter = Rect {
                lo: DVec2::new(if x { mid.x } else { r.lo.x }, if y { mid.y } else { r.lo.y }),
                hi: DVec2::new(if x { r.hi.x } else { mid.x }, if y { r.hi.y } else { mid.y }),
            };
            self.covered(plane, quarter, depth)
        })
    }

    /// Whether every direction of the cone `r` (on `plane`'s map) passes
    /// through an occluder.
    fn covered(&mut self, plane: MapPlane, r: Rect, depth: u32) -> bool {
        for m in 0..6 {
            if self.state.maps[m].is_empty() {
                continue;
            }
            let image = if m == plane.index() {
                Some(r)
            } else {
                self.projection.reproject(plane, r, MapPlane::of_index(m))
            };
            if image.is_some_and(|i| self.state.maps[m].hides(i)) {
                return true;
            }
        }
        depth < self.state.splits && self.quartered(plane, r, depth + 1)
    }

    /// Adds the faces of node `n` that are valid occluders from the eye.
    fn add_faces(&mut self, n: usize, node: &Node) {
        let eye = self.view.eye();
        let (lo, hi) = (node.min, node.max());
        let near = self.view.camera().near;
        let forward = self.view.basis().forward;
        for axis in 0..3 {
            // The face the node lies between the eye and, and the eye's
            // distance from its plane.
            let (side, w, h) = if eye[axis] >= hi[axis] {
                (0, lo[axis], eye[axis] - lo[axis])
            } else if eye[axis] <= lo[axis] {
                (1, hi[axis], hi[axis] - eye[axis])
            } else {
                continue;
            };
            if h.partial_cmp(&(CLIP * node.size)).is_none_or(Ordering::is_lt) {
                continue;
            }
            // Most faces are valid from no region: skip them before
            // finding the eye's.
            let mask = self
                .culling
                .tree
                .mask(n, octree::face_index(axis, side), self.state.regions);
            if mask == 0 {
                continue;
            }
            let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
            let c = node.centre();
            let Some(region) = self
                .state
                .regions
                .region_of((eye[ua] - c[ua]) / h, (eye[va] - c[va]) / h)
            else {
                continue;
            };
            if mask >> region & 1 == 0 {
                continue;
            }
            let (mut face_lo, mut face_hi) = (lo, hi);
            face_lo[axis] = w;
            face_hi[axis] = w;
            // The hiding triangles are at least `1 − 2s/h` of the way to
            // the face: only use it when that is beyond the near plane.
            let nearest = (0..4)
                .map(|k| {
                    let mut p = face_lo;
                    p[ua] = if k & 1 == 0 { lo[ua] } else { hi[ua] };
                    p[va] = if k & 2 == 0 { lo[va] } else { hi[va] };
                    (p - eye).dot(forward)
                })
                .fold(f64::INFINITY, f64::min);
            let share = 1.0 - CLIP * node.size / h;
            let needed = near * (1.0 + NEAR_SLACK) + self.projection.floor;
            if (share * nearest).partial_cmp(&needed).is_none_or(Ordering::is_lt) {
                continue;
            }
            // On the screen map the face is drawn at its own depth, which
            // needs no front-to-back order: it waits for nothing.
            if let (Some(screen), Some(canvas)) = (&self.screen, &mut self.state.canvas) {
                let corners = [(0, 0), (1, 0), (1, 1), (0, 1)].map(|(i, j)| {
                    let mut p = face_lo;
                    p[ua] = if i == 0 { lo[ua] } else { hi[ua] };
                    p[va] = if j == 0 { lo[va] } else { hi[va] };
                    p
                });
                let mut normal = DVec3::ZERO;
                normal[axis] = 1.0;
                let plane = Plane { normal, d: -w };
                screen.draw(&corners, &plane, 0.0, &mut canvas.buffer, &mut canvas.scratch);
                continue;
            }
            let plane = if self.state.best_plane {
                self.projection.best
            } else {
                MapPlane {
                    axis,
                    sign: if side == 1 { 1 } else { -1 },
                }
            };
            if let Some(r) = self.projection.face_rect(plane, axis, w, face_lo, face_hi) {
                if self.deferring > 0 {
                    self.state.pending.push((plane.index(), r));
                } else {
                    self.state.maps[plane.index()].add(r);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Camera;
    use crate::scene::SceneBuilder;

    /// The closed surface of the box `[lo, hi]`, each face an `n × n` grid
    /// whose corners are shared bit for bit with its neighbours; `hole`
    /// leaves out cell `(i, j)` of the `+z` face.
    pub(crate) fn grid_box_triangles(lo: DVec3, hi: DVec3, n: usize, hole: Option<(usize, usize)>) -> Vec<[DVec3; 3]> {
        let at = |axis: usize, i: usize| {
            if i == n {
                hi[axis]
            } else {
                lo[axis] + (hi[axis] - lo[axis]) * i as f64 / n as f64
            }
        };
        let mut tris = Vec::new();
        for axis in 0..3 {
            let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
            for side in 0..2 {
                for i in 0..n {
                    for j in 0..n {
                        if axis == 2 && side == 1 && hole == Some((i, j)) {
                            continue;
                        }
                        let p = |di: usize, dj: usize| {
                            let mut p = DVec3::ZERO;
                            p[axis] = if side == 0 { lo[axis] } else { hi[axis] };
                            p[ua] = at(ua, i + di);
                            p[va] = at(va, j + dj);
                            p
                        };
                        tris.push([p(0, 0), p(1, 0), p(1, 1)]);
                        tris.push([p(0, 0), p(1, 1), p(0, 1)]);
                    }
                }
            }
        }
        tris
    }

    /// [`grid_box_triangles`] added to the object being built.
    pub(crate) fn grid_box(b: &mut SceneBuilder, lo: DVec3, hi: DVec3, n: usize, hole: Option<(usize, usize)>) {
        b.add_triangles(grid_box_triangles(lo, hi, n, hole), false);
    }

    fn boxed_scene(hole: Option<(usize, usize)>) -> Arc<Scene> {
        let mut b = SceneBuilder::new("boxed");
        b.begin_object("shell", None);
        grid_box(&mut b, DVec3::splat(-1.0), DVec3::splat(1.0), 16, hole);
        b.begin_object("inside", None);
        grid_box(&mut b, DVec3::splat(-0.2), DVec3::splat(0.2), 2, None);
        Arc::new(b.finish())
    }

    fn baked(scene: &Arc<Scene>) -> DdoCulling {
        use crate::spatial::KdTreeParams;
        let params = OctreeParams {
            leaf_triangles: 16,
            max_depth: 6,
        };
        let kd = Arc::new(KdTree::build(scene, KdTreeParams::default()));
        DdoCulling::new(scene.clone(), bake(scene, params).expect("a bake"), kd)
    }

    /// `a=1:b=2` as options.
    fn options(text: &str) -> MethodOptions {
        let mut map = MethodOptions::new();
        for kv in text.split(':').filter(|s| !s.is_empty()) {
            let (k, v) = kv.split_once('=').expect("key=value");
            map.insert(k, v);
        }
        map
    }

    /// The objects found visible from `eye` looking at the origin, and
    /// the client state's bytes after the cull.
    fn cull_with_state(method: &DdoCulling, eye: DVec3, options_text: &str) -> (Vec<u32>, usize) {
        let camera = Camera {
            eye,
            forward: -eye,
            ..Camera::default()
        };
        let view = View::new(camera, &method.scene).expect("a view");
        let mut state = method.new_state(&options(options_text)).expect("options");
        let mut out = VisibleSet::new();
        CullMethod::cull(method, &view, &mut state, &mut out, &mut Occludees::default())
            .expect("a cull");
        out.finish();
        (out.ids().to_vec(), method.state_bytes(&state))
    }

    fn cull(method: &DdoCulling, eye: DVec3, options: &str) -> Vec<u32> {
        cull_with_state(method, eye, options).0
    }

    #[test]
    fn a_closed_shell_hides_what_it_holds() {
        let method = baked(&boxed_scene(None));
        for eye in [DVec3::new(0.3, 0.2, 5.0), DVec3::new(-4.0, 1.5, 0.7), DVec3::new(3.5, -1.0, 1.5)] {
            for options in ["", "regions=32", "map=exact", "map=exact:planes=best", "cell=2", "traversal=objects:cell=3", "traversal=objects:cell=2x3"] {
                assert_eq!(cull(&method, eye, options), vec![0], "from {eye} with {options:?}");
            }
            // The grid's seams between faces stay open: it only may hide.
            assert!(cull(&method, eye, "map=grid").contains(&0));
        }
    }

    #[test]
    fn an_eye_on_the_octree_planes_still_gets_every_visible_object() {
        // Rays within a splitting plane through the eye have no front-to-back
        // order (faces found inside such a node wait until it is done):
        // every truth-visible object is kept, with and without a hole.
        for hole in [None, Some((8, 8))] {
            let scene = boxed_scene(hole);
            let method = baked(&scene);
            let centre = method.octree().nodes()[0].centre();
            for eye in [
                DVec3::new(centre.x, centre.y, 5.0),
                DVec3::new(centre.x, 0.03, 4.0),
                DVec3::new(0.05, centre.y, 3.0),
            ] {
                let camera = Camera {
                    eye,
                    forward: -eye,
                    ..Camera::default()
                };
                let truth = crate::truth::Truth::render(&scene, &camera).expect("a camera");
                let visible = truth.visible();
                assert!(!visible.is_empty());
                for options in ["", "map=exact", "map=exact:planes=best", "map=exact:splits=2"] {
                    let got = cull(&method, eye, options);
                    for v in &visible {
                        assert!(got.contains(v), "{v} from {eye} with {options:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn the_screen_map_refuses_the_plane_maps_options_and_they_its_cell() {
        let method = baked(&boxed_scene(None));
        let refusal = |text: &str| method.new_state(&options(text)).err().expect("refused").to_string();
        for text in ["planes=best", "cells=16", "splits=1", "map=screen:splits=2"] {
            let error = refusal(text);
            assert!(error.contains("nothing with map=screen"), "{text}: {error}");
        }
        for text in ["map=exact:cell=2", "map=grid:cell=1"] {
            let error = refusal(text);
            assert!(error.contains("option 'cell'"), "{text}: {error}");
            assert!(error.contains("nothing with map=exact or map=grid"), "{text}: {error}");
        }
        for text in ["cell=0", "cell=9", "cell=1.5", "cell=2x9", "cell=0x2", "cell=2x", "cell=x"] {
            let error = refusal(text);
            assert!(error.contains("from 1 to 8"), "{text}: {error}");
        }
    }

    #[test]
    fn a_coarser_cell_holds_fewer_cells_and_hides_the_same_inside() {
        // The buffer is sized by the screen's cells: a quarter as many
        // with cell=2, a sixth with 2x3, a 64th with cell=8, each
        // answering the same here.
        let method = baked(&boxed_scene(None));
        let eye = DVec3::new(0.3, 0.2, 5.0);
        let sizes: Vec<usize> = ["", "cell=2", "cell=2x3", "cell=8"]
            .iter()
            .map(|text| {
                let (ids, bytes) = cull_with_state(&method, eye, text);
                assert_eq!(ids, vec![0], "{text:?}");
                bytes
            })
            .collect();
        assert!(sizes.windows(2).all(|w| w[0] > w[1]), "{sizes:?}");
    }

    #[test]
    fn a_hole_in_the_shell_shows_what_it_holds() {
        // Cell (8, 8) of the +z face spans [0, 0.125]²: the inner box is
        // seen through it from straight above.
        let method = baked(&boxed_scene(Some((8, 8))));
        let eye = DVec3::new(0.06, 0.06, 5.0);
        for options in ["", "regions=32", "map=exact", "map=exact:planes=best", "map=grid", "cell=2", "traversal=objects:cell=3", "traversal=objects:cell=2x3"] {
            assert_eq!(cull(&method, eye, options), vec![0, 1], "with {options:?}");
        }
        // From the other side the shell is whole.
        assert_eq!(cull(&method, DVec3::new(0.06, 0.06, -5.0), ""), vec![0]);
    }

    #[test]
    fn a_part_draws_the_rectangle_it_shows_largest_as_if_all_were_looked_at() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(15);
        for _ in 0..300 {
            // Rectangles on the three axes' planes, of all sizes, some with
            // nothing beyond them on one side or the other.
            let rects: Vec<SolidRect> = (0..rng.random_range(1..24))
                .map(|_| {
                    let axis = rng.random_range(0..3);
                    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                    let mut c0 = DVec3::ZERO;
                    for a in 0..3 {
                        c0[a] = rng.random_range(-1.0..1.0);
                    }
                    let (mut du, mut dv) = (DVec3::ZERO, DVec3::ZERO);
                    du[u] = rng.random_range(0.01..2.0);
                    dv[v] = rng.random_range(0.01..2.0);
                    let normal = DVec3::AXES[axis];
                    SolidRect {
                        corners: [c0, c0 + du, c0 + du + dv, c0 + dv],
                        normal,
                        d: -normal.dot(c0),
                    }
                })
                .collect();
            let beyond: Vec<Beyond> = rects
                .iter()
                .map(|_| Beyond {
                    positive: rng.random_bool(0.8),
                    negative: rng.random_bool(0.8),
                })
                .collect();
            let shown = Shown::largest_first(&rects, &beyond);
            let eye = DVec3::new(rng.random_range(-6.0..6.0), rng.random_range(-6.0..6.0), rng.random_range(-6.0..6.0));
            // Every rectangle looked at, in order.
            let seen = |r: &SolidRect| {
                let to_eye = eye - r.centre();
                let across = r.area() * r.normal.dot(to_eye);
                across * across / to_eye.length_squared()
            };
            let mut want: Option<&SolidRect> = None;
            for (r, b) in rects.iter().zip(&beyond) {
                if b.from(r, eye) && seen(r) > want.map_or(0.0, seen) {
                    want = Some(r);
                }
            }
            let got = Shown::largest_seen(&shown, &rects, eye);
            assert_eq!(got.map(seen), want.map(seen), "eye {eye}");
        }
    }
}
