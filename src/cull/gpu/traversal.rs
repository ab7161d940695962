//! One view's walk through the grid hierarchy (Tai & Hsu §3.2–3.4), as a
//! [`QuerySource`] the device runs pass by pass.
//!
//! Nodes are visited in *parallel units* (§3.3): the units form a stack,
//! the root's unit first; a visited unit's visible nodes give their
//! children to four new units by eye-siding number (3, 2, 1, 0 visited in
//! that order: front to back), and a visible voxel gives its objects to a
//! unit of their own, visited next. A node's box includes the movable
//! objects below it ([`Movers`]); an opened node gives the movers it keeps
//! to that unit too. A mover found visible is in the answer but never
//! drawn into depth: it may move, so it hides nothing. The nodes of a unit are sent for
//! occlusion queries together, at most `batch` per pass (§3.3's multipass
//! queries); before each pass the objects found visible so far are drawn
//! into depth, nearest units first.
//!
//! 2-tier frustum culling (§3.2): nodes above depth `tier` are tested
//! against the frustum on the CPU and, when they touch it, opened without a
//! query; deeper nodes and all objects go to queries, which clip against
//! the frustum themselves. The *near-face test*: a box reaching the near
//! plane is never queried (its faces may be clipped away while it holds the
//! eye's view); it is visible when it touches the frustum.
//!
//! Why a query cannot drop a visible object. The depth buffer holds only
//! real opaque surfaces: triangles of objects found visible and occluder
//! polygons merged from one object's own triangles (see-through triangles
//! are never drawn), each pulled in by 1/16 pixel at every edge where the
//! surface ends or folds away as seen from the eye (`shaders/scene.vert`
//! decides, `shaders/erode.frag` pulls in: the rasterizer snaps vertices to
//! a subpixel grid, and without it a surface could cover a pixel centre
//! that ground truth, in `f64`, leaves uncovered). An edge the surface runs
//! on across is left whole: truth's inclusive edges cover its pixel
//! centres from one side or the other, and so does the rasterizer. So at every pixel the depth buffer lies at
//! or behind the nearest surface ground truth sees there. Where truth sees an object, the ray
//! through that pixel's centre enters the object's box no later than it
//! meets the object, so a query of the box passes the depth test there
//! (the test is `≥` in reversed depth). The box sent is enlarged so that
//! rounding cannot undo this: by [`SCENE_ULPS`] ulps of the scene's largest
//! coordinate (vertices are `f32`), by [`DEPTH_SLACK`] of its farthest
//! depth (the `f32` depth pipeline), and by [`PIXEL_DILATION`] of a pixel
//! at that depth (the rasterizer snaps vertices to 1/256 pixel, so a box
//! edge through a pixel centre could otherwise miss it).

use std::ops::Range;

use glam::{DMat4, DVec3, DVec4, Mat4, Vec3};

use super::grid::Grid;
use super::movers::Movers;
use super::vulkan::{Mask, QuerySource, Setup};
use crate::cull::{Occludees, View, VisibleSet};
use crate::geom::Aabb;
use crate::scene::Scene;

/// Enlargement of a queried box, in ulps of the scene's largest coordinate.
pub const SCENE_ULPS: f64 = 16.0;

/// Enlargement of a queried box, as a share of its farthest depth.
pub const DEPTH_SLACK: f64 = 4e-6;

/// Enlargement of a queried box, in pixels at its farthest depth.
pub const PIXEL_DILATION: f64 = 1.0 / 32.0;

/// A box whose nearest point is within this share of the near plane's
/// distance reaches the near plane (the near-face test).
const NEAR_SLACK: f64 = 1e-6;

/// What a view's walk is asked to do.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    /// Most queries per pass.
    pub batch: usize,
    /// Nodes above this depth are frustum-tested on the CPU, not queried.
    pub tier: u32,
    /// A box is hidden when it shows at most this many pixels (0: none).
    pub threshold: u64,
    /// The importance mask, if any.
    pub mask: Option<Mask>,
    /// Whether units that follow join a pass with room left (fewer
    /// passes; later units do not see the depth of earlier ones).
    pub merge: bool,
    /// Triangles drawn into depth before the first query (occluder
    /// proxies lying on the scene's surfaces), if any.
    pub proxies: Option<Range<u32>>,
    /// Whether the objects found visible are drawn into depth.
    pub draw_visible: bool,
}

/// What a query or a test is about.
#[derive(Clone, Copy, Debug)]
enum Item {
    Node(u32),
    Object(u32),
    /// A movable object, by its index in [`Movers`].
    Mover(u32),
    Occludee(u32),
}

/// One view's walk. It borrows the view's answer and occludees and fills
/// them as passes come back.
pub struct Traversal<'a> {
    grid: &'a Grid,
    movers: &'a Movers,
    scene: &'a Scene,
    view: &'a View,
    settings: Settings,
    setup: Setup,
    /// `clip_from_view` in `f64`, for the near-face test's depths.
    forward: DVec3,
    near: f64,
    /// Enlargement independent of the box ([`SCENE_ULPS`]).
    scene_slack: f64,
    /// World size of a pixel at unit depth.
    pixel: f64,
    out: &'a mut VisibleSet,
    occludees: &'a mut Occludees,
    occludees_done: bool,
    /// Units still to visit; the top is next.
    stack: Vec<Vec<Item>>,
    /// The visited unit's items waiting for a query, and their boxes.
    pending: Vec<(Item, [Vec3; 2])>,
    cursor: usize,
    /// The items of the pass in flight.
    sent: Vec<Item>,
    /// The visited unit's visible nodes, and whether a query said so.
    open: Vec<(u32, bool)>,
    /// Objects found visible and not drawn yet.
    undrawn: Vec<u32>,
    /// Boxes tested, on the CPU or the device.
    pub tested: u64,
    /// Queries sent.
    pub queries: u64,
}

impl<'a> Traversal<'a> {
    /// A walk of `grid` (with `movers` placed in it) for `view`, answering
    /// into `out` and `occludees`.
    pub fn new(
        grid: &'a Grid,
        movers: &'a Movers,
        scene: &'a Scene,
        view: &'a View,
        settings: Settings,
        out: &'a mut VisibleSet,
        occludees: &'a mut Occludees,
    ) -> Traversal<'a> {
        let camera = view.camera();
        let basis = view.basis();
        let (tx, ty) = camera.half_tangents();
        let (near, far) = (camera.near, camera.far);
        // Rows of the rotation: eye-relative scene axes to right, up, forward.
        let rotation = DMat4::from_cols(
            DVec4::new(basis.right.x, basis.up.x, basis.forward.x, 0.0),
            DVec4::new(basis.right.y, basis.up.y, basis.forward.y, 0.0),
            DVec4::new(basis.right.z, basis.up.z, basis.forward.z, 0.0),
            DVec4::W,
        );
        // Vulkan's y points down the screen; depth is reversed: 1 at the
        // near plane, 0 at the far plane, w the view depth.
        let a = near * far / (far - near);
        let b = -near / (far - near);
        let projection = DMat4::from_cols(
            DVec4::new(1.0 / tx, 0.0, 0.0, 0.0),
            DVec4::new(0.0, -1.0 / ty, 0.0, 0.0),
            DVec4::new(0.0, 0.0, b, 1.0),
            DVec4::new(0.0, 0.0, a, 0.0),
        );
        let clip_from_view: Mat4 = (projection * rotation).as_mat4();
        let bounds = scene.bounds();
        let magnitude = if bounds.is_empty() {
            0.0
        } else {
            bounds.min.abs().max(bounds.max.abs()).max_element() as f64
        };
        let [w, h] = camera.viewport;
        let pixel = (2.0 * tx / w as f64).max(2.0 * ty / h as f64);
        let mut stack = Vec::new();
        if !grid.nodes().is_empty() {
            stack.push(vec![Item::Node(0)]);
        }
        Traversal {
            grid,
            movers,
            scene,
            view,
            setup: Setup {
                clip_from_view,
                eye: view.eye(),
                extent: camera.viewport,
                mask: settings.mask,
            },
            settings,
            forward: basis.forward,
            near,
            scene_slack: SCENE_ULPS * f32::EPSILON as f64 * magnitude,
            pixel,
            out,
            occludees,
            occludees_done: false,
            stack,
            pending: Vec::new(),
            cursor: 0,
            sent: Vec::new(),
            open: Vec::new(),
            undrawn: Vec::new(),
            tested: 0,
            queries: 0,
        }
    }

    /// The item's box, scene-local.
    fn bounds(&self, item: Item) -> Aabb {
        match item {
            Item::Node(n) => self.movers.bounds(self.grid, n),
            Item::Object(id) => self.scene.objects()[id as usize].bounds,
            Item::Mover(i) => self.movers.bounds_of(i),
            Item::Occludee(i) => self.occludees.boxes()[i as usize],
        }
    }

    /// Tests one item: visible without a query (near-face, or a node above
    /// the tier that touches the frustum), hidden, or queued for a query.
    fn classify(&mut self, item: Item) {
        let b = self.bounds(item);
        if b.is_empty() {
            return;
        }
        self.tested += 1;
        let frustum = self.view.frustum();
        if let Item::Node(n) = item
            && self.grid.nodes()[n as usize].depth < self.settings.tier
        {
            if frustum.intersects(&b) {
                self.open.push((n, false));
            }
            return;
        }
        let eye = self.view.eye();
        let (lo, hi) = (b.min.as_dvec3() - eye, b.max.as_dvec3() - eye);
        let depth = |p: DVec3| p.dot(self.forward);
        let corners = [0, 1, 2, 3, 4, 5, 6, 7].map(|i| {
            DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            )
        });
        let nearest = corners.iter().map(|&c| depth(c)).fold(f64::INFINITY, f64::min);
        let farthest = corners.iter().map(|&c| depth(c)).fold(f64::NEG_INFINITY, f64::max);
        let far = farthest.max(self.near);
        let slack = self.scene_slack + far * (DEPTH_SLACK + PIXEL_DILATION * self.pixel);
        if nearest - slack <= self.near * (1.0 + NEAR_SLACK) {
            // The near-face test: never queried; visible if in the frustum.
            if frustum.intersects(&b) {
                self.visible(item, false);
            }
            return;
        }
        // An object or avatar outside the frustum costs a CPU test, not a
        // query (the device would clip it away, more slowly).
        if !matches!(item, Item::Node(_)) && !frustum.intersects(&b) {
            return;
        }
        let enlarged = [
            (lo - DVec3::splat(slack)).as_vec3(),
            (hi + DVec3::splat(slack)).as_vec3(),
        ];
        self.pending.push((item, enlarged));
    }

    /// Sorts the pending queries nearest first, so that with one query a
    /// pass the nearest is drawn before the next is asked.
    fn sort_pending(&mut self) {
        self.pending.sort_by(|a, b| {
            let d = |p: &(Item, [Vec3; 2])| {
                let (lo, hi) = (p.1[0].as_dvec3(), p.1[1].as_dvec3());
                DVec3::ZERO.clamp(lo, hi).length_squared()
            };
            d(a).total_cmp(&d(b))
        });
    }

    /// Records an item found visible.
    fn visible(&mut self, item: Item, by_query: bool) {
        match item {
            Item::Node(n) => self.open.push((n, by_query)),
            Item::Object(id) => {
                self.out.push(id);
                if self.settings.draw_visible {
                    self.undrawn.push(id);
                }
            }
            // A mover is never drawn: it may move, so it hides nothing.
            Item::Mover(i) => self.out.push(self.movers.id(i)),
            Item::Occludee(_) => {}
        }
    }

    /// Opens the visited unit's visible nodes: voxels give a unit of their
    /// objects, inner nodes their children to four units by eye-siding.
    fn open_unit(&mut self) {
        let grid = self.grid;
        let eye = self.view.eye();
        let mut units: [Vec<Item>; 4] = Default::default();
        let mut objects = Vec::new();
        let open = std::mem::take(&mut self.open);
        for &(n, by_query) in &open {
            let node = &grid.nodes()[n as usize];
            objects.extend(self.movers.kept(n).iter().map(|&i| Item::Mover(i)));
            if node.children.is_empty() {
                // A voxel of one object (and no mover) has the object's
                // box: its query answered for the object.
                if by_query && node.objects.len() == 1 && self.movers.kept(n).is_empty() {
                    self.visible(Item::Object(node.objects[0]), true);
                } else {
                    objects.extend(node.objects.iter().map(|&id| Item::Object(id)));
                }
                continue;
            }
            for &c in &node.children {
                let siding = grid.eye_siding(node, &grid.nodes()[c as usize], eye);
                units[siding].push(Item::Node(c));
            }
        }
        self.open = open;
        self.open.clear();
        // Pushed last-first: 3-eye-siding on top, then the objects above all.
        for unit in units.into_iter().filter(|u| !u.is_empty()) {
            self.stack.push(unit);
        }
        if !objects.is_empty() {
            self.stack.push(objects);
        }
    }
}

impl QuerySource for Traversal<'_> {
    fn setup(&self) -> Setup {
        self.setup
    }

    fn next_pass(&mut self, draws: &mut Vec<Range<u32>>, boxes: &mut Vec<[Vec3; 2]>) -> bool {
        loop {
            if self.cursor < self.pending.len() {
                let end = (self.cursor + self.settings.batch).min(self.pending.len());
                for &(item, b) in &self.pending[self.cursor..end] {
                    self.sent.push(item);
                    boxes.push(b);
                }
                self.cursor = end;
                self.queries += boxes.len() as u64;
                draws.extend(self.settings.proxies.take());
                for id in self.undrawn.drain(..) {
                    draws.extend(self.scene.objects()[id as usize].opaque_ranges());
                }
                return true;
            }
            self.pending.clear();
            self.cursor = 0;
            if !self.open.is_empty() {
                self.open_unit();
            }
            if let Some(unit) = self.stack.pop() {
                for item in unit {
                    self.classify(item);
                }
                // Later units join the pass while it has room.
                while self.settings.merge
                    && self.pending.len() < self.settings.batch
                    && let Some(unit) = self.stack.pop()
                {
                    for item in unit {
                        self.classify(item);
                    }
                }
                self.sort_pending();
                continue;
            }
            if !self.occludees_done {
                // Last, with every visible object drawn: the avatars, and
                // movers no node keeps.
                self.occludees_done = true;
                let shown: Vec<Item> = (0..self.occludees.boxes().len())
                    .filter(|&i| self.occludees.visible()[i])
                    .map(|i| Item::Occludee(i as u32))
                    .chain(self.movers.loose().iter().map(|&i| Item::Mover(i)))
                    .collect();
                for item in shown {
                    self.classify(item);
                }
                continue;
            }
            return false;
        }
    }

    fn answer(&mut self, counts: &[u64]) {
        let sent = std::mem::take(&mut self.sent);
        debug_assert_eq!(sent.len(), counts.len());
        for (&item, &count) in sent.iter().zip(counts) {
            let shown = count > self.settings.threshold;
            match item {
                Item::Occludee(i) if !shown => self.occludees.hide(i as usize),
                _ if shown => self.visible(item, true),
                _ => {}
            }
        }
        self.sent = sent;
        self.sent.clear();
    }
}
