//! What every request shares: the scenes with their methods, the metrics and
//! the limits. Cheap to clone (an `Arc`); read-only once built, so requests
//! never lock each other out.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use super::error::ApiError;
use super::metrics::Metrics;
use crate::cull::SceneMethods;
use crate::scene::Scene;

/// Limits applied to every request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest accepted request body, bytes.
    pub body_bytes: usize,
    /// Longest a request may take before it is answered with 503 `timeout`.
    pub request_timeout: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        // A view is ~300 bytes; 64 KiB leaves room for options without
        // letting a client make the server buffer megabytes.
        Limits {
            body_bytes: 64 * 1024,
            request_timeout: Duration::from_secs(10),
        }
    }
}

/// The state handlers see.
#[derive(Clone)]
pub struct AppState {
    inner: Arc<Shared>,
}

struct Shared {
    /// Scenes by id, each with the methods it supports.
    scenes: BTreeMap<String, Arc<SceneMethods>>,
    /// Counters and histograms behind `/metrics`.
    metrics: Metrics,
    /// Body size and time limits.
    limits: Limits,
}

/// Two scenes with one id: ids must name one scene each.
#[derive(Debug, thiserror::Error)]
#[error("two scenes are called '{0}' (a scene's id is its file stem)")]
pub struct DuplicateScene(pub String);

impl AppState {
    /// State over these scenes; prepares each scene's methods.
    pub fn new(scenes: Vec<Arc<Scene>>, limits: Limits) -> Result<AppState, DuplicateScene> {
        let mut map = BTreeMap::new();
        for scene in scenes {
            let id = scene.id.clone();
            if map
                .insert(id.clone(), Arc::new(SceneMethods::prepare(scene)))
                .is_some()
            {
                return Err(DuplicateScene(id));
            }
        }
        let metrics = Metrics::new();
        metrics.set_scenes(map.len());
        Ok(AppState {
            inner: Arc::new(Shared {
                scenes: map,
                metrics,
                limits,
            }),
        })
    }

    /// Every scene, by id.
    pub fn scenes(&self) -> impl Iterator<Item = &Arc<SceneMethods>> {
        self.inner.scenes.values()
    }

    /// The scene `id`, or `unknown_scene` listing the loaded ones.
    pub fn scene(&self, id: &str) -> Result<&Arc<SceneMethods>, ApiError> {
        self.inner
            .scenes
            .get(id)
            .ok_or_else(|| ApiError::UnknownScene {
                id: id.to_string(),
                loaded: self.inner.scenes.keys().cloned().collect(),
            })
    }

    /// The metrics.
    pub fn metrics(&self) -> &Metrics {
        &self.inner.metrics
    }

    /// The limits.
    pub fn limits(&self) -> Limits {
        self.inner.limits
    }
}
