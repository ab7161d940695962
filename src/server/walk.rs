//! `GET /scenes/{id}/walk`: a path through a scene for clients to replay.
//!
//! The same deterministic walks `pvsd eval --walk` measures methods on
//! (`crate::eval::walk`): a street walk at eye height along open space, a
//! wandering one, an orbit, unrelated views. The web viewer starts where
//! the walk starts and replays it on request; scripted tests and the example
//! client walk it. `step` resamples the path to even steps (speed / frame
//! rate), so "a 60-second street walk at 10 m/s and 30 frames a second" is
//! `frames=1800&step=0.333`.

use axum::Json;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, State};
use pvsd_proto::json::{WalkResponse, WalkView};
use serde::Deserialize;

use super::error::ApiError;
use super::state::AppState;
use crate::eval::{WalkKind, WalkParams, resample, walk};

/// Most views one walk answers.
const MAX_FRAMES: usize = 10_000;
/// Most cameras a resampled walk is cut from: its own steps are at least
/// 0.5 m, so this covers 50 km.
const MAX_PATH: usize = 100_000;

/// The query.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WalkQuery {
    /// `street` (default), `random`, `orbit` or `views`.
    kind: Option<String>,
    /// How many views (default 600, at most 10,000).
    frames: Option<usize>,
    /// The same seed gives the same walk (default 1).
    seed: Option<u64>,
    /// Metres between views (default: the walk's own, 0.5–2 m).
    step: Option<f64>,
}

/// `GET /scenes/{id}/walk`.
pub async fn scene_walk(
    State(state): State<AppState>,
    Path(id): Path<String>,
    query: Result<Query<WalkQuery>, QueryRejection>,
) -> Result<Json<WalkResponse>, ApiError> {
    let methods = state.scene(&id)?;
    let Query(q) = query.map_err(|e| ApiError::InvalidQuery(e.body_text()))?;
    let kind: WalkKind = q
        .kind
        .as_deref()
        .unwrap_or("street")
        .parse()
        .map_err(|e: String| ApiError::InvalidQuery(format!("kind: {e}")))?;
    let frames = q.frames.unwrap_or(600);
    if !(1..=MAX_FRAMES).contains(&frames) {
        return Err(ApiError::InvalidQuery(format!(
            "frames: {frames} is not in 1..={MAX_FRAMES}"
        )));
    }
    if let Some(step) = q.step {
        if !(step.is_finite() && step > 0.0 && step <= 100.0) {
            return Err(ApiError::InvalidQuery(format!(
                "step: {step} is not a distance in (0, 100] metres"
            )));
        }
    }
    let params = WalkParams {
        kind,
        // A resampled walk is cut from a path long enough for it.
        frames: q.step.map_or(frames, |s| {
            ((frames as f64 * s / 0.5).ceil() as usize + 2).min(MAX_PATH)
        }),
        seed: q.seed.unwrap_or(1),
        ..WalkParams::default()
    };
    let cameras = tokio::task::spawn_blocking(move || {
        let path = walk(methods.scene(), &params)?;
        Ok::<_, ApiError>(match q.step {
            Some(step) => resample(&path, step, frames),
            None => path,
        })
    })
    .await
    .map_err(|e| ApiError::Internal(format!("the walk failed: {e}")))??;
    Ok(Json(WalkResponse {
        kind: kind.name().to_string(),
        step: q.step,
        views: cameras
            .iter()
            .map(|c| WalkView {
                eye: c.eye.to_array(),
                forward: c.forward.normalize_or_zero().to_array(),
                up: c.up.to_array(),
                fov_y_deg: c.fov_y_deg,
                near: c.near,
                far: c.far,
            })
            .collect(),
    }))
}
