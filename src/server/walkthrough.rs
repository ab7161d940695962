//! Multi-user walkthroughs: several sessions in one scene, each user an
//! avatar that the others' frames test as a dynamic occludee
//! ([`crate::cull::Occludees`]), with the same method.
//!
//! An avatar is a box 0.5 × 1.8 × 0.5 m: from 1.7 m below the eye (the
//! feet of a walker whose eye is at 1.7 m) to 0.1 m above it (the head).
//! Avatars are seen, never hide anything: a conservative method stays so.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use glam::DVec3;
use moka::sync::Cache;
use pvsd_proto::json::{Pose, UserInfo, WalkthroughInfo};

use rand::Rng;

use super::error::ApiError;
use super::route::RouteKey;
use crate::cull::{MethodSpec, SceneMethods};
use crate::geom::{Aabb, Camera, Region};

/// Half the avatar's width and depth, metres.
pub const AVATAR_HALF_WIDTH: f64 = 0.25;
/// How far the avatar reaches below the eye, metres.
pub const AVATAR_BELOW_EYE: f64 = 1.7;
/// How far the avatar reaches above the eye, metres.
pub const AVATAR_ABOVE_EYE: f64 = 0.1;

/// The avatar of a user whose eye is at `eye` (world), in the scene's local
/// coordinates (relative to `origin`), rounded outwards to `f32`.
pub fn avatar(eye: DVec3, origin: DVec3) -> Aabb {
    avatar_within(eye, 0.0, origin, f64::NEG_INFINITY)
}

/// The box holding the avatar of a user whose eye is anywhere within
/// `radius` of `eye` ([`avatar`] grown by `radius` on every side), but
/// never grown below `floor` (local; the scene's lowest point): no body
/// stands below everything there is to stand on, and a box reaching below
/// the ground could never be proven hidden by the horizon.
pub fn avatar_within(eye: DVec3, radius: f64, origin: DVec3, floor: f64) -> Aabb {
    let e = eye - origin;
    let feet = e.y - AVATAR_BELOW_EYE;
    let mut lo = e - DVec3::new(AVATAR_HALF_WIDTH, AVATAR_BELOW_EYE, AVATAR_HALF_WIDTH) - radius;
    lo.y = (feet - radius).max(floor.min(feet));
    let hi = e + DVec3::new(AVATAR_HALF_WIDTH, AVATAR_ABOVE_EYE, AVATAR_HALF_WIDTH) + radius;
    Aabb::enclosing(lo, hi)
}

/// A walkthrough: a scene, a method and the users in it.
pub struct Walkthrough {
    /// Its id (minted on `route`).
    pub id: String,
    /// The routing key of its id, which its users' sessions are minted on
    /// so that their frames reach the replica that holds it.
    pub route: RouteKey,
    /// The scene.
    pub scene: Arc<SceneMethods>,
    /// The method (with options) every user's session gets.
    pub spec: MethodSpec,
    /// The method's resolved name.
    pub method: &'static str,
    /// The region its users' frames get when they give none.
    pub region: Region,
    users: Mutex<BTreeMap<String, Presence>>,
}

#[derive(Default)]
struct Presence {
    pose: Option<Camera>,
    /// How far from its pose's eye the user may be (its frames' radius).
    radius: f64,
    frames: u64,
}

/// One user of a walkthrough, as its session holds it.
#[derive(Clone)]
pub struct User {
    /// The walkthrough.
    pub walkthrough: Arc<Walkthrough>,
    /// The user's id.
    pub id: String,
}

impl Walkthrough {
    fn new(
        id: String,
        route: RouteKey,
        scene: Arc<SceneMethods>,
        spec: MethodSpec,
        method: &'static str,
        region: Region,
    ) -> Walkthrough {
        Walkthrough {
            id,
            route,
            scene,
            spec,
            method,
            region,
            users: Mutex::new(BTreeMap::new()),
        }
    }

    /// Adds a user with no pose yet.
    pub fn join(self: &Arc<Self>) -> User {
        // Shown to the other users (`users_visible`), so no session's id.
        let id = format!("{:032x}", rand::rng().random::<u128>());
        self.lock().insert(id.clone(), Presence::default());
        User {
            walkthrough: self.clone(),
            id,
        }
    }

    /// Its users and their last poses.
    pub fn info(&self) -> WalkthroughInfo {
        WalkthroughInfo {
            walkthrough: self.id.clone(),
            scene: self.scene.scene().id.clone(),
            method: self.method.to_string(),
            users: self
                .lock()
                .iter()
                .map(|(id, p)| UserInfo {
                    user: id.clone(),
                    pose: p.pose.map(|c| Pose {
                        eye: c.eye.to_array(),
                        forward: c.forward.to_array(),
                        up: c.up.to_array(),
                    }),
                    frames: p.frames,
                })
                .collect(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, Presence>> {
        // A panic while holding this lock cannot leave the map half-changed
        // (each change is one insert or field write), so a poisoned lock is
        // still good.
        self.users.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl User {
    /// Records the user's new camera; returns every other user that has a
    /// pose, with its avatar (local coordinates), by user id.
    ///
    /// The user may stand anywhere within `radius` of the camera's eye (a
    /// client that keeps a region answer while it moves): each avatar is
    /// grown by its own user's radius, down to `floor` at most
    /// ([`avatar_within`]), so a view that sees any place its user may be
    /// reports it.
    pub fn moved(
        &self,
        camera: &Camera,
        radius: f64,
        origin: &DVec3,
        floor: f64,
    ) -> Vec<(String, Aabb)> {
        let mut users = self.walkthrough.lock();
        if let Some(me) = users.get_mut(&self.id) {
            me.pose = Some(*camera);
            me.radius = radius;
            me.frames += 1;
        }
        users
            .iter()
            .filter(|(id, _)| **id != self.id)
            .filter_map(|(id, p)| {
                p.pose
                    .map(|c| (id.clone(), avatar_within(c.eye, p.radius, *origin, floor)))
            })
            .collect()
    }

    /// Leaves the walkthrough (the session was deleted or expired).
    pub fn leave(&self) {
        self.walkthrough.lock().remove(&self.id);
    }
}

/// Every walkthrough; one idle (no user's frame, no lookup) past the
/// session time limit is dropped.
pub struct Walkthroughs {
    live: Cache<String, Arc<Walkthrough>>,
}

impl Walkthroughs {
    /// An empty store of at most `max` walkthroughs, dropped after `idle`.
    pub fn new(max: u64, idle: Duration) -> Walkthroughs {
        Walkthroughs {
            live: Cache::builder()
                .eviction_policy(moka::policy::EvictionPolicy::lru())
                .max_capacity(max)
                .time_to_idle(idle)
                .build(),
        }
    }

    /// A new walkthrough of `scene` with `spec`, its id minted on `route`.
    pub fn create(
        &self,
        route: &RouteKey,
        scene: Arc<SceneMethods>,
        spec: MethodSpec,
        method: &'static str,
        region: Region,
    ) -> Arc<Walkthrough> {
        let w = Arc::new(Walkthrough::new(
            route.mint(),
            route.clone(),
            scene,
            spec,
            method,
            region,
        ));
        self.live.insert(w.id.clone(), w.clone());
        w
    }

    /// The walkthrough `id` as it is, or, when this replica does not hold
    /// it (it was lost with another replica, or expired), a new one under
    /// the same id, of `scene` with `spec`: users rejoining a lost
    /// walkthrough all reach the replica its id routes to, and meet again
    /// there. Also whether it was made now. 404 `unknown_walkthrough` for
    /// an id no replica could have minted.
    pub fn get_or_recreate(
        &self,
        id: &str,
        scene: Arc<SceneMethods>,
        spec: MethodSpec,
        method: &'static str,
        region: Region,
    ) -> Result<(Arc<Walkthrough>, bool), ApiError> {
        let route =
            RouteKey::of_id(id).ok_or_else(|| ApiError::UnknownWalkthrough(id.to_string()))?;
        let entry = self.live.entry(id.to_string()).or_insert_with(|| {
            tracing::info!(walkthrough = %id, "a lost walkthrough made again as its users rejoin");
            Arc::new(Walkthrough::new(
                id.to_string(),
                route,
                scene,
                spec,
                method,
                region,
            ))
        });
        Ok((entry.value().clone(), entry.is_fresh()))
    }

    /// The walkthrough `id`, now used.
    pub fn get(&self, id: &str) -> Result<Arc<Walkthrough>, ApiError> {
        self.live
            .get(id)
            .ok_or_else(|| ApiError::UnknownWalkthrough(id.to_string()))
    }

    /// Live walkthroughs.
    pub fn count(&self) -> u64 {
        self.live.run_pending_tasks();
        self.live.entry_count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn avatar_holds_the_body_even_far_from_the_origin() {
        for origin in [DVec3::ZERO, DVec3::splat(1e7)] {
            let eye = origin + DVec3::new(10.3, 1.7, -4.1);
            let b = avatar(eye, origin);
            let e = eye - origin;
            assert!(f64::from(b.min.y) <= e.y - AVATAR_BELOW_EYE);
            assert!(f64::from(b.max.y) >= e.y + AVATAR_ABOVE_EYE);
            assert!(f64::from(b.min.x) <= e.x - AVATAR_HALF_WIDTH);
            assert!(f64::from(b.max.z) >= e.z + AVATAR_HALF_WIDTH);
            assert!((b.max.y - b.min.y - 1.8).abs() < 1e-5);
        }
    }
}
