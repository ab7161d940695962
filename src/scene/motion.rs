//! Objects that move (Tai & Hsu §3.1's dynamic objects): where each movable
//! object is now.
//!
//! A scene file marks an object movable with `extras.movable` (as `pvsd gen
//! crowd` does). Such an object never enters a method's static structures
//! (kd-tree, occluders, prisms, grid): built once at load, they would go
//! stale when it moves. Instead every cull tests its current box as a
//! dynamic occludee, as it does a walkthrough's avatars: it may be seen,
//! and it hides nothing. Moving one is O(1): its box is replaced, and the
//! next cull of every client sees it there.

use std::sync::RwLock;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{DMat4, DVec3};

use crate::geom::Aabb;

/// Why an object was not moved.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MoveError {
    /// No object has this id.
    #[error("the scene has no object '{0}'")]
    Unknown(String),
    /// The object is part of the static scene.
    #[error(
        "object {0} is static: only objects the scene file marks movable \
         (extras.movable) can move, since every method's static structures hold the others"
    )]
    Static(u32),
    /// The transform has a NaN, an infinity or no inverse's worth of scale.
    #[error("the transform {0}")]
    Transform(String),
}

/// One movable object.
#[derive(Clone, Debug)]
struct Mover {
    id: u32,
    /// The inverse of the world transform it was loaded with.
    unloaded: DMat4,
    /// Its box as loaded, world coordinates.
    world: (DVec3, DVec3),
}

/// Where the movable objects of one scene are now.
#[derive(Debug, Default)]
pub struct Motion {
    /// Ascending ids.
    movers: Vec<Mover>,
    /// Current boxes, scene-local, one per mover.
    current: RwLock<Vec<Aabb>>,
    /// Per mover, what carries its loaded triangles (world) to where it is
    /// now: identity until it moves. Only clients that draw it read this.
    carried: RwLock<Vec<DMat4>>,
    /// How many moves there have been: a method that keeps its own
    /// structure of the movers rebuilds it when this changes.
    version: AtomicU64,
}

impl Clone for Motion {
    fn clone(&self) -> Self {
        Motion {
            movers: self.movers.clone(),
            current: RwLock::new(self.boxes()),
            carried: RwLock::new(
                self.carried
                    .read()
                    .unwrap_or_else(|p| p.into_inner())
                    .clone(),
            ),
            version: AtomicU64::new(self.version()),
        }
    }
}

impl Motion {
    /// Movers from `(id, loaded world transform, loaded box)` (ascending
    /// ids, boxes scene-local) around `origin`.
    pub(crate) fn new(movers: Vec<(u32, DMat4, Aabb)>, origin: DVec3) -> Motion {
        let current = movers.iter().map(|m| m.2).collect();
        let carried = vec![DMat4::IDENTITY; movers.len()];
        let movers = movers
            .into_iter()
            .map(|(id, loaded, b)| Mover {
                id,
                unloaded: loaded.inverse(),
                world: (b.min.as_dvec3() + origin, b.max.as_dvec3() + origin),
            })
            .collect();
        Motion {
            movers,
            current: RwLock::new(current),
            carried: RwLock::new(carried),
            version: AtomicU64::new(0),
        }
    }

    /// How many moves there have been.
    pub fn version(&self) -> u64 {
        self.version.load(Ordering::Acquire)
    }

    /// The movable objects' ids, ascending.
    pub fn ids(&self) -> impl Iterator<Item = u32> + '_ {
        self.movers.iter().map(|m| m.id)
    }

    /// How many objects can move.
    pub fn len(&self) -> usize {
        self.movers.len()
    }

    /// Whether none can.
    pub fn is_empty(&self) -> bool {
        self.movers.is_empty()
    }

    /// Their current boxes (scene-local), in the order of [`Motion::ids`].
    pub fn boxes(&self) -> Vec<Aabb> {
        self.current
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Calls `f` with the current boxes (no copy; moves wait meanwhile).
    pub fn with_boxes<R>(&self, f: impl FnOnce(&[Aabb]) -> R) -> R {
        f(&self.current.read().unwrap_or_else(|p| p.into_inner()))
    }

    /// The current box of movable object `id`, if it is one.
    pub fn bounds_of(&self, id: u32) -> Option<Aabb> {
        let i = self.movers.binary_search_by_key(&id, |m| m.id).ok()?;
        Some(self.current.read().unwrap_or_else(|p| p.into_inner())[i])
    }

    /// What carries movable object `id`'s loaded triangles (world
    /// coordinates) to where it is now; `None` when it is not movable.
    pub fn carry_of(&self, id: u32) -> Option<DMat4> {
        let i = self.movers.binary_search_by_key(&id, |m| m.id).ok()?;
        Some(self.carried.read().unwrap_or_else(|p| p.into_inner())[i])
    }

    /// Places movable object `id` at world transform `to` (what its node's
    /// world matrix would be in the file): its new box encloses its loaded
    /// box carried from the loaded transform to `to`. `origin` is the
    /// scene's; `objects` how many the scene has. Returns the new box.
    pub fn place(
        &self,
        id: u32,
        to: DMat4,
        origin: DVec3,
        objects: usize,
    ) -> Result<Aabb, MoveError> {
        let Ok(i) = self.movers.binary_search_by_key(&id, |m| m.id) else {
            return Err(if (id as usize) < objects {
                MoveError::Static(id)
            } else {
                MoveError::Unknown(id.to_string())
            });
        };
        if !to.is_finite() {
            return Err(MoveError::Transform("is not finite".into()));
        }
        let det = to.determinant();
        if !det.is_normal() {
            return Err(MoveError::Transform(format!(
                "has no inverse (determinant {det:e}): a scale is zero"
            )));
        }
        let m = &self.movers[i];
        let carry = to * m.unloaded;
        let (lo, hi) = m.world;
        let (mut min, mut max) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for c in 0..8 {
            let corner = DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            );
            let p = carry.transform_point3(corner);
            min = min.min(p);
            max = max.max(p);
        }
        let local = Aabb::enclosing(min - origin, max - origin);
        if !local.min.is_finite() || !local.max.is_finite() {
            return Err(MoveError::Transform(
                "moves the object beyond f32's range".into(),
            ));
        }
        self.carried.write().unwrap_or_else(|p| p.into_inner())[i] = carry;
        self.current.write().unwrap_or_else(|p| p.into_inner())[i] = local;
        self.version.fetch_add(1, Ordering::AcqRel);
        Ok(local)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mover_carries_its_box_and_statics_stay() {
        let b = Aabb::enclosing(DVec3::new(9.0, 0.0, 9.0), DVec3::new(11.0, 2.0, 11.0));
        let loaded = DMat4::from_translation(DVec3::new(10.0, 0.0, 10.0));
        let m = Motion::new(vec![(3, loaded, b)], DVec3::ZERO);
        let to = DMat4::from_translation(DVec3::new(-5.0, 1.0, 0.0));
        let moved = m.place(3, to, DVec3::ZERO, 10).unwrap();
        assert_eq!(moved.min.as_dvec3(), DVec3::new(-6.0, 1.0, -1.0));
        assert_eq!(moved.max.as_dvec3(), DVec3::new(-4.0, 3.0, 1.0));
        assert_eq!(m.bounds_of(3), Some(moved));
        assert_eq!(
            m.carry_of(3)
                .unwrap()
                .transform_point3(DVec3::new(10.0, 0.0, 10.0)),
            DVec3::new(-5.0, 1.0, 0.0)
        );
        assert_eq!(m.carry_of(2), None);
        assert_eq!(m.place(2, to, DVec3::ZERO, 10), Err(MoveError::Static(2)));
        assert_eq!(
            m.place(10, to, DVec3::ZERO, 10),
            Err(MoveError::Unknown("10".into()))
        );
        let nan = DMat4::from_translation(DVec3::new(f64::NAN, 0.0, 0.0));
        assert!(matches!(
            m.place(3, nan, DVec3::ZERO, 10),
            Err(MoveError::Transform(_))
        ));
        let flat = DMat4::from_scale(DVec3::new(1.0, 0.0, 1.0));
        assert!(matches!(
            m.place(3, flat, DVec3::ZERO, 10),
            Err(MoveError::Transform(_))
        ));
        assert_eq!(m.bounds_of(3), Some(moved), "a refused move moves nothing");
    }
}
