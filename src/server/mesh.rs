//! The geometry routes: objects' triangles for thin clients that draw only
//! what is visible (`application/x-pvs-mesh`, `proto/mesh-format.md`).
//!
//! - `GET /scenes/{id}/objects/{oid}/mesh`: one object.
//! - `POST /scenes/{id}/meshes` `{"ids": [...]}`: many in one message, in
//!   the order asked (a repeated id once, at its first place), for a
//!   client catching up with a frame's `added`.
//!
//! Answers carry a strong `ETag` (a hash of the bytes) and
//! `Cache-Control: no-cache`: a cache keeps them but asks again, and a
//! `GET` with a matching `If-None-Match` gets `304` and no body. The bytes
//! change when a reload changes the scene file or a movable object moves,
//! so a client never draws geometry the server no longer culls with.

use std::sync::Arc;

use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use pvsd_proto::json::MeshesRequest;
use pvsd_proto::mesh::{self, MeshRef};

use super::error::ApiError;
use super::extract::{RawBody, parse};
use super::state::AppState;
use crate::cull::SceneMethods;
use crate::scene::{IndexedMesh, MoveError, Scene};

/// `GET /scenes/{id}/objects/{oid}/mesh`.
pub async fn object_mesh(
    State(state): State<AppState>,
    Path((id, oid)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let methods = state.scene(&id)?;
    let oid = oid
        .parse()
        .map_err(|_| ApiError::Move(MoveError::Unknown(oid.clone())))?;
    known(methods.scene(), oid)?;
    let (bytes, tag) = encoded(methods, vec![oid]).await?;
    let matched = headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|t| t.trim() == tag || t.trim() == "*");
    if matched {
        return Ok((StatusCode::NOT_MODIFIED, cache_headers(&tag)).into_response());
    }
    Ok(answer(bytes, &tag))
}

/// `POST /scenes/{id}/meshes`.
pub async fn meshes(
    State(state): State<AppState>,
    Path(id): Path<String>,
    RawBody(body): RawBody,
) -> Result<Response, ApiError> {
    let methods = state.scene(&id)?;
    let req: MeshesRequest = parse(&body, state.limits().json)?;
    for &oid in &req.ids {
        known(methods.scene(), oid)?;
    }
    // Each object once, at its first place: an answer is never more than
    // the scene's own meshes, however the ids repeat.
    let mut seen = std::collections::HashSet::new();
    let ids: Vec<u32> = req.ids.into_iter().filter(|&i| seen.insert(i)).collect();
    let (bytes, tag) = encoded(methods, ids).await?;
    Ok(answer(bytes, &tag))
}

/// The message of objects `ids` of the scene and its tag, made on the
/// blocking pool: a big object, or a thousand, take milliseconds.
async fn encoded(methods: Arc<SceneMethods>, ids: Vec<u32>) -> Result<(Vec<u8>, String), ApiError> {
    tokio::task::spawn_blocking(move || {
        let bytes = encode(methods.scene(), &ids);
        let tag = etag(&bytes);
        (bytes, tag)
    })
    .await
    .map_err(|e| ApiError::Internal(format!("encoding meshes failed: {e}")))
}

/// Refuses an id `scene` has no object for.
fn known(scene: &Scene, oid: u32) -> Result<(), ApiError> {
    if (oid as usize) < scene.objects().len() {
        Ok(())
    } else {
        Err(ApiError::Move(MoveError::Unknown(oid.to_string())))
    }
}

/// The message of objects `ids` (each known to `scene`).
fn encode(scene: &Scene, ids: &[u32]) -> Vec<u8> {
    let objects = scene.objects();
    let built: Vec<IndexedMesh> = ids
        .iter()
        .map(|&i| IndexedMesh::of(scene, &objects[i as usize]))
        .collect();
    let refs: Vec<MeshRef<'_>> = ids
        .iter()
        .zip(&built)
        .map(|(&id, m)| MeshRef {
            id,
            movable: objects[id as usize].movable,
            positions: &m.positions,
            indices: &m.indices,
            opaque: m.opaque,
        })
        .collect();
    mesh::encode(scene.origin.to_array(), &refs)
}

/// A strong entity tag: the bytes' 128-bit hash.
fn etag(bytes: &[u8]) -> String {
    format!("\"{:032x}\"", xxhash_rust::xxh3::xxh3_128(bytes))
}

fn cache_headers(tag: &str) -> [(header::HeaderName, HeaderValue); 2] {
    [
        (
            header::ETAG,
            HeaderValue::from_str(tag).expect("hex in quotes"),
        ),
        (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
    ]
}

fn answer(bytes: Vec<u8>, tag: &str) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static(mesh::CONTENT_TYPE),
        )],
        cache_headers(tag),
        bytes,
    )
        .into_response()
}
