//! The in-memory scene: objects with stable ids, boxes and triangles.
//!
//! Only what visibility needs is kept: positions (as triangles), which
//! triangle ranges are see-through (DESIGN "Accuracy"), a name per object and
//! the occluder hint a file may carry. No materials, normals or textures.

use std::ops::Range;

use glam::{DMat4, DVec3, Vec3};

use super::Motion;
use crate::geom::Aabb;

/// One object: a mesh-bearing node instance of the scene file.
#[derive(Clone, Debug, PartialEq)]
pub struct Object {
    /// Stable id: the instance's position in the pre-order walk of the file (DESIGN "Scenes").
    pub id: u32,
    /// The node's name, else its mesh's name, else `object_<id>`.
    pub name: String,
    /// Box of the object's triangles, scene-local coordinates; empty when it has none.
    pub bounds: Aabb,
    /// The object's triangles: a range of [`Scene::triangles`].
    pub triangles: Range<u32>,
    /// Sub-ranges of `triangles` that are see-through: seen, never hiding.
    pub see_through: Vec<Range<u32>>,
    /// The file's `extras.occluder` flag, when it has one (walls, floors, facades).
    pub occluder_hint: Option<bool>,
    /// The file's `extras.movable` flag: the object may be moved while
    /// served, so it stays out of every method's static structures and is
    /// culled at its current box ([`Motion`]).
    pub movable: bool,
}

impl Object {
    /// How many triangles the object has.
    pub fn triangle_count(&self) -> u32 {
        self.triangles.end - self.triangles.start
    }

    /// Whether the object belongs in a method's static structures: it has
    /// a box (it can show a pixel) and cannot move.
    pub fn is_static(&self) -> bool {
        !self.bounds.is_empty() && !self.movable
    }

    /// The object's triangle ranges that are not see-through: what hides
    /// what lies behind it.
    pub fn opaque_ranges(&self) -> Vec<Range<u32>> {
        let mut out = Vec::new();
        let mut at = self.triangles.start;
        for r in &self.see_through {
            if r.start > at {
                out.push(at..r.start);
            }
            at = at.max(r.end);
        }
        if at < self.triangles.end {
            out.push(at..self.triangles.end);
        }
        out
    }
}

/// A scene held by pvsd: objects and their triangles around an `f64` origin.
///
/// World coordinates are `origin + local`; every `f32` in the scene is local.
/// The origin is the centre of the world bounds rounded to whole units, so a
/// scene far from the world origin keeps `f32` precision near its own centre.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Identifier: the file stem (`city1k.glb` → `city1k`).
    pub id: String,
    /// World position of the local origin.
    pub origin: DVec3,
    pub(crate) objects: Vec<Object>,
    pub(crate) triangles: Vec<[Vec3; 3]>,
    pub(crate) bounds: Aabb,
    pub(crate) motion: Motion,
    /// A hash of the file it was loaded from (and its buffers); `None` for
    /// a scene built in memory. Bakes of the scene are named by it.
    pub(crate) source_hash: Option<u128>,
}

impl Scene {
    /// Every object, indexed by id.
    pub fn objects(&self) -> &[Object] {
        &self.objects
    }

    /// A hash of the file the scene was loaded from, with its buffers
    /// (xxh3, 128 bits); `None` for a scene built in memory.
    pub fn source_hash(&self) -> Option<u128> {
        self.source_hash
    }

    /// Where the movable objects are now.
    pub fn motion(&self) -> &Motion {
        &self.motion
    }

    /// The current box of object `id`: where it was loaded, or where it
    /// was moved to.
    pub fn current_bounds(&self, id: u32) -> Option<Aabb> {
        let o = self.objects.get(id as usize)?;
        if o.movable {
            self.motion.bounds_of(id)
        } else {
            Some(o.bounds)
        }
    }

    /// Every triangle (scene-local); objects own contiguous ranges.
    pub fn triangles(&self) -> &[[Vec3; 3]] {
        &self.triangles
    }

    /// The triangles of one object.
    pub fn object_triangles(&self, object: &Object) -> &[[Vec3; 3]] {
        &self.triangles[object.triangles.start as usize..object.triangles.end as usize]
    }

    /// Box of all objects, scene-local.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// A scene-local box in world coordinates.
    pub fn to_world(&self, b: &Aabb) -> (DVec3, DVec3) {
        (
            self.origin + b.min.as_dvec3(),
            self.origin + b.max.as_dvec3(),
        )
    }

    /// The up axis of every pvsd scene (glTF's +Y).
    pub fn up(&self) -> Vec3 {
        Vec3::Y
    }

    /// The total triangle count.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }
}

/// Builds a [`Scene`] from world-space `f64` triangles, choosing its origin.
///
/// Triangles are kept in `f64` until [`SceneBuilder::finish`], which picks the
/// origin from their bounds and only then rounds them to `f32`.
#[derive(Debug)]
pub struct SceneBuilder {
    id: String,
    objects: Vec<PendingObject>,
}

#[derive(Debug)]
struct PendingObject {
    name: String,
    occluder_hint: Option<bool>,
    /// The world transform of a movable object.
    movable: Option<DMat4>,
    triangles: Vec<[DVec3; 3]>,
    see_through: Vec<Range<u32>>,
}

impl SceneBuilder {
    /// An empty scene named `id`.
    pub fn new(id: impl Into<String>) -> Self {
        SceneBuilder {
            id: id.into(),
            objects: Vec::new(),
        }
    }

    /// How many objects were begun: the id the next one gets.
    pub fn object_count(&self) -> usize {
        self.objects.len()
    }

    /// Starts the next object (its id is the number of objects before it).
    pub fn begin_object(&mut self, name: impl Into<String>, occluder_hint: Option<bool>) -> u32 {
        self.objects.push(PendingObject {
            name: name.into(),
            occluder_hint,
            movable: None,
            triangles: Vec::new(),
            see_through: Vec::new(),
        });
        (self.objects.len() - 1) as u32
    }

    /// Marks the current object movable; `world` is the transform its
    /// triangles were placed with (its node's world matrix).
    ///
    /// # Panics
    /// If no object was begun.
    pub fn set_movable(&mut self, world: DMat4) {
        self.objects
            .last_mut()
            .expect("begin_object before set_movable")
            .movable = Some(world);
    }

    /// Adds world-space triangles to the current object.
    ///
    /// # Panics
    /// If no object was begun.
    pub fn add_triangles(
        &mut self,
        triangles: impl IntoIterator<Item = [DVec3; 3]>,
        see_through: bool,
    ) {
        let obj = self
            .objects
            .last_mut()
            .expect("begin_object before add_triangles");
        let start = obj.triangles.len() as u32;
        obj.triangles.extend(triangles);
        let end = obj.triangles.len() as u32;
        if see_through && end > start {
            obj.see_through.push(start..end);
        }
    }

    /// The finished scene.
    pub fn finish(self) -> Scene {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for t in self.objects.iter().flat_map(|o| &o.triangles) {
            for v in t {
                lo = lo.min(*v);
                hi = hi.max(*v);
            }
        }
        let origin = if lo.x <= hi.x {
            ((lo + hi) * 0.5).round()
        } else {
            DVec3::ZERO
        };
        let total: usize = self.objects.iter().map(|o| o.triangles.len()).sum();
        let mut triangles = Vec::with_capacity(total);
        let mut objects = Vec::with_capacity(self.objects.len());
        let mut bounds = Aabb::EMPTY;
        let mut movers = Vec::new();
        for (id, o) in self.objects.into_iter().enumerate() {
            let start = triangles.len() as u32;
            let mut b = Aabb::EMPTY;
            for t in &o.triangles {
                let local = t.map(|v| (v - origin).as_vec3());
                local.iter().for_each(|&v| b.grow(v));
                triangles.push(local);
            }
            bounds.merge(&b);
            // A movable object without triangles shows nothing wherever it
            // is, and one whose transform has no inverse cannot be carried.
            let movable = o
                .movable
                .filter(|m| !b.is_empty() && m.determinant().is_normal());
            if let Some(world) = movable {
                movers.push((id as u32, world, b));
            }
            objects.push(Object {
                id: id as u32,
                name: o.name,
                bounds: b,
                triangles: start..triangles.len() as u32,
                see_through: o
                    .see_through
                    .into_iter()
                    .map(|r| r.start + start..r.end + start)
                    .collect(),
                occluder_hint: o.occluder_hint,
                movable: movable.is_some(),
            });
        }
        Scene {
            id: self.id,
            origin,
            objects,
            triangles,
            bounds,
            motion: Motion::new(movers, origin),
            source_hash: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origin_is_rounded_centre_and_ids_count_up() {
        let mut b = SceneBuilder::new("t");
        let off = DVec3::splat(1e7);
        assert_eq!(b.begin_object("a", None), 0);
        b.add_triangles([[off, off + DVec3::X, off + DVec3::Y]], false);
        assert_eq!(b.begin_object("b", Some(true)), 1);
        b.add_triangles(
            [[
                off + DVec3::splat(4.0),
                off + DVec3::splat(5.0),
                off + DVec3::Z,
            ]],
            true,
        );
        let s = b.finish();
        assert_eq!(s.origin, DVec3::new(1e7 + 3.0, 1e7 + 3.0, 1e7 + 3.0));
        assert_eq!(s.objects()[1].see_through, vec![1..2]);
        assert_eq!(s.objects()[1].bounds.max, Vec3::splat(2.0));
        assert_eq!(s.objects()[0].bounds.min, Vec3::splat(-3.0));
    }

    #[test]
    fn empty_object_has_empty_bounds() {
        let mut b = SceneBuilder::new("t");
        b.begin_object("nothing", None);
        let s = b.finish();
        assert!(s.objects()[0].bounds.is_empty());
        assert!(s.bounds().is_empty());
        assert_eq!(s.origin, DVec3::ZERO);
    }
}
