//! The handlers, one per route of DESIGN's HTTP API.
//!
//! Every cull goes through the one dispatch (`SceneMethods::cull`), which
//! runs it where its method says: inline, on the blocking pool, or on a
//! device's queue. The handlers know no method's insides.

use std::collections::BTreeMap;
use std::sync::Arc;

use axum::Json;
use axum::extract::{OriginalUri, Path, State};
use axum::http::{HeaderMap, Method, StatusCode, header};
use axum::response::{IntoResponse, Response};
use pvsd_proto::json::{
    AutoInfo, Bounds, FrameResponse, JoinRequest, MoveRequest, ObjectInfo, RankedMethod,
    ReloadReport, SceneInfo, SessionCreated, SessionRequest, Stats, UserJoined, ViewRequest,
    VisibleResponse, WalkthroughCreated, WalkthroughInfo,
};
use pvsd_proto::xpvs as binary;

use super::error::ApiError;
use super::extract::{RawBody, parse};
use super::route::RouteKey;
use super::session::Session;
use super::state::AppState;
use super::wire::{self, BoundsExt, MoveRequestExt, ViewRequestExt, Views, method_spec};
use crate::cull::ranking::FrameCost;
use crate::cull::view::gather;
use crate::cull::{ClientCache, CullJob, Culler, MethodSpec, SceneMethods};
use crate::geom::Region;
use crate::scene::MoveError;

/// `GET /healthz`: 200 while the server runs.
pub async fn healthz() -> &'static str {
    "ok"
}

/// `GET /healthz/live`: 200 while the process serves, loading and
/// draining included; an orchestrator restarts a replica that stops
/// answering it.
pub async fn live() -> &'static str {
    "live"
}

/// `GET /healthz/ready`: 200 once every configured scene is loaded (with
/// its bakes and ranking); 503 `not_ready` while loading and while
/// draining, so that load balancers send it nothing new.
pub async fn ready(State(state): State<AppState>) -> Result<&'static str, ApiError> {
    state.readiness().check()?;
    Ok("ready")
}

/// `GET /scenes`: every scene with its size, bounds and methods.
pub async fn scenes(State(state): State<AppState>) -> Json<Vec<SceneInfo>> {
    Json(
        state
            .scenes()
            .iter()
            .map(|m| {
                let s = m.scene();
                SceneInfo {
                    id: s.id.clone(),
                    objects: s.objects().len(),
                    triangles: s.triangle_count(),
                    bounds: (!s.bounds().is_empty()).then(|| Bounds::new(s.to_world(&s.bounds()))),
                    up: s.up().to_array(),
                    methods: m.names().into_iter().map(String::from).collect(),
                    unsupported: m
                        .unsupported()
                        .iter()
                        .map(|u| (u.method.to_string(), u.reason.clone()))
                        .collect(),
                    options: method_options(&state, m),
                    auto: auto_info(m),
                }
            })
            .collect(),
    )
}

/// The option keys of each method `m` supports, and `auto`'s.
fn method_options(state: &AppState, m: &SceneMethods) -> BTreeMap<String, Vec<String>> {
    let names = m.names();
    let keys = |k: &[&str]| k.iter().map(|s| s.to_string()).collect();
    state
        .registry()
        .entries()
        .iter()
        .filter(|e| names.contains(&e.name))
        .map(|e| (e.name.to_string(), keys(e.options)))
        .chain([("auto".to_string(), keys(&FrameCost::KEYS))])
        .collect()
}

/// What `auto` answers with on a scene, and the ranking behind it.
fn auto_info(m: &SceneMethods) -> AutoInfo {
    let cost = m.frame_cost();
    let ranking = m.ranking();
    AutoInfo {
        choice: m.auto_choice(cost).to_string(),
        status: if ranking.is_some() {
            "measured"
        } else {
            "unmeasured"
        }
        .to_string(),
        cost_per_triangle_ns: cost.per_triangle_ns,
        cost_per_byte_ns: cost.per_byte_ns,
        walks: ranking.map_or_else(Vec::new, |r| r.walks.clone()),
        frames: ranking.map_or(0, |r| r.frames),
        ranking: ranking.map_or_else(Vec::new, |r| {
            r.ranked(cost)
                .into_iter()
                .map(|(x, frame_cost_us)| RankedMethod {
                    method: x.method.clone(),
                    mean_cull_us: x.mean_cull_us,
                    median_cull_us: x.median_cull_us,
                    mean_pvs: x.mean_pvs,
                    mean_pvs_triangles: x.mean_pvs_triangles,
                    mean_pvs_bytes: x.mean_pvs_bytes(),
                    frame_cost_us,
                })
                .collect()
        }),
    }
}

/// `GET /scenes/{id}/objects`: what each id means.
pub async fn objects(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<Vec<ObjectInfo>>, ApiError> {
    let methods = state.scene(&id)?;
    let s = methods.scene();
    Ok(Json(
        s.objects().iter().map(|o| object_info(s, o.id)).collect(),
    ))
}

/// `PUT /scenes/{id}/objects/{oid}`: moves a movable object (admin only).
pub async fn move_object(
    State(state): State<AppState>,
    Path((id, oid)): Path<(String, String)>,
    headers: HeaderMap,
    RawBody(body): RawBody,
) -> Result<Json<ObjectInfo>, ApiError> {
    // Refused before anything else is read: an unauthorized client learns
    // nothing about the scene.
    authorize(&state, &headers)?;
    let methods = state.scene(&id)?;
    let scene = methods.scene();
    // An id that is no number names no object.
    let oid: u32 = oid
        .parse()
        .map_err(|_| ApiError::Move(MoveError::Unknown(oid.clone())))?;
    let req: MoveRequest = parse(&body, state.limits().json)?;
    let to = req.transform()?;
    scene
        .motion()
        .place(oid, to, scene.origin, scene.objects().len())?;
    Ok(Json(object_info(scene, oid)))
}

/// Checks the request's admin token (`Authorization: Bearer …`).
fn authorize(state: &AppState, headers: &HeaderMap) -> Result<(), ApiError> {
    let authorization = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok());
    state.authorize_admin(authorization)
}

/// `POST /admin/reload`: reads every scene file again and swaps in those
/// that changed (admin only; `SIGHUP` does the same).
pub async fn reload(
    State(state): State<AppState>,
    headers: HeaderMap,
) -> Result<Json<ReloadReport>, ApiError> {
    authorize(&state, &headers)?;
    let report = tokio::task::spawn_blocking(move || state.reload())
        .await
        .map_err(|e| ApiError::Internal(format!("the reload failed: {e}")))?;
    Ok(Json(report))
}

/// One entry of `GET /scenes/{id}/objects`, at the object's current box.
fn object_info(scene: &crate::scene::Scene, id: u32) -> ObjectInfo {
    let o = &scene.objects()[id as usize];
    let bounds = scene.current_bounds(id).unwrap_or(o.bounds);
    ObjectInfo {
        id,
        name: o.name.clone(),
        bounds: (!bounds.is_empty()).then(|| Bounds::new(scene.to_world(&bounds))),
    }
}

/// Whether the client asked for `application/x-pvs` (`Accept`).
pub fn wants_binary(headers: &HeaderMap) -> bool {
    headers
        .get_all(header::ACCEPT)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .any(|v| v.contains(binary::CONTENT_TYPE))
}

fn binary_body(bytes: Vec<u8>) -> Response {
    ([(header::CONTENT_TYPE, binary::CONTENT_TYPE)], bytes).into_response()
}

fn json_body(bytes: Vec<u8>) -> Response {
    ([(header::CONTENT_TYPE, "application/json")], bytes).into_response()
}

/// `POST /scenes/{id}/visible`: the potentially visible set of one view
/// (JSON with stats, or the ids alone as `application/x-pvs`).
pub async fn visible(
    State(state): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    RawBody(body): RawBody,
) -> Result<Response, ApiError> {
    let methods = state.scene(&id)?;
    let req: ViewRequest = parse(&body, state.limits().json)?;
    req.check_stateless()?;
    let spec = req.method_spec()?;
    let views = req.views(methods.scene(), Region::POINT)?;
    let (method, cache) = prepare_client(&methods, &spec, views.has_region()).await?;
    let job = views_job(&methods, &*method, &views, cache);
    let culled = methods.cull(&method, job).await?;
    let (out, stats) = (culled.job.out, culled.stats);
    state.metrics().observe_cull(&id, &stats);
    if wants_binary(&headers) {
        return Ok(binary_body(binary::encode_visible(out.ids())));
    }
    let mut stats: Stats = stats.into();
    views.echo(&mut stats);
    let answer = VisibleResponse {
        visible: out.ids().to_vec(),
        areas: out.areas(),
        stats,
    };
    Ok(json_body(answer.to_json()))
}

/// A client's method and cache. A method released while unused is built
/// again on the blocking pool, since that can take seconds, which the
/// other requests on this async worker must not wait for.
async fn prepare_client(
    methods: &Arc<SceneMethods>,
    spec: &MethodSpec,
    regions: bool,
) -> Result<(Arc<dyn Culler>, ClientCache), ApiError> {
    if methods.is_resident_for(spec, regions) {
        return Ok(methods.prepare_client_for(spec, regions)?);
    }
    let (methods, spec) = (methods.clone(), spec.clone());
    tokio::task::spawn_blocking(move || methods.prepare_client_for(&spec, regions))
        .await
        .map_err(|e| ApiError::Internal(format!("building a method failed: {e}")))?
        .map_err(ApiError::from)
}

/// The job for a request's views: one traversal for views near one
/// another when the method answers for regions ([`gather`]).
fn views_job(
    methods: &SceneMethods,
    method: &dyn Culler,
    views: &Views,
    cache: ClientCache,
) -> CullJob {
    let regions = methods.answers_regions(method.name());
    let (view, also) = gather(&views.views, regions, methods.scene());
    let mut job = CullJob::new(view, cache);
    job.also = also;
    job
}

/// The scene and method spec of a `SessionRequest` body (sessions and
/// walkthroughs are made from the same body).
fn scene_and_spec(
    state: &AppState,
    body: &[u8],
) -> Result<(Arc<SceneMethods>, MethodSpec, Region), ApiError> {
    let req: SessionRequest = parse(body, state.limits().json)?;
    let methods = state.scene(&req.scene)?;
    let spec = method_spec(req.method.as_deref(), &req.options)?;
    let region = wire::region(req.radius, req.angle, Region::POINT)?;
    Ok((methods, spec, region))
}

/// `POST /sessions`: a session of one scene and method, its id minted on
/// the request's routing key ([`RouteKey::of_request`]).
pub async fn create_session(
    State(state): State<AppState>,
    headers: HeaderMap,
    RawBody(body): RawBody,
) -> Result<(StatusCode, Json<SessionCreated>), ApiError> {
    let route = RouteKey::of_request(&headers)?;
    let (methods, spec, region) = scene_and_spec(&state, &body)?;
    let (method, cache) = prepare_client(&methods, &spec, !region.is_point()).await?;
    let name = method.name().to_string();
    let session = state
        .sessions()
        .insert(Session::new(&route, methods, method, cache, None).with_region(region));
    Ok((
        StatusCode::CREATED,
        Json(SessionCreated {
            session: session.id.clone(),
            method: name,
        }),
    ))
}

/// Answers one frame of session `sid` from a view body (`with_stats`: the
/// cull's stats in the frame): shared by `POST /sessions/{sid}/frames` and
/// the WebSocket.
pub async fn answer_frame(
    state: &AppState,
    sid: &str,
    body: &[u8],
    with_stats: bool,
) -> Result<FrameResponse, ApiError> {
    let session = on_current_scene(state, state.sessions().get(sid)?).await?;
    let req: ViewRequest = parse(body, state.limits().json)?;
    req.check_frame()?;
    let scene = &session.scene;
    let views = req.views(scene.scene(), session.region)?;
    let regions = scene.answers_regions(session.method.name());
    if views.has_region() && !regions {
        scene.check_regions(session.method.name())?;
    }
    let pose = (*views.views[0].camera(), views.radius);
    let job_views = gather(&views.views, regions, scene.scene());
    let answered = session.frame(job_views, pose, req.base).await?;
    if let Some(user) = &session.user {
        // Keeps the walkthrough alive while its users walk.
        let _ = state.walkthroughs().get(&user.walkthrough.id);
    }
    if let Some(bytes) = answered.resized {
        state.sessions().resized(&session, bytes);
    }
    state
        .metrics()
        .observe_cull(&session.scene.scene().id, &answered.stats);
    let mut frame = answered.frame;
    if with_stats {
        let mut stats: Stats = answered.stats.into();
        views.echo(&mut stats);
        frame.stats = Some(stats);
    }
    Ok(frame)
}

/// The session, moved to its scene's current version if a reload
/// replaced the one it was made on.
async fn on_current_scene(
    state: &AppState,
    session: Arc<Session>,
) -> Result<Arc<Session>, ApiError> {
    let current = state.scene(&session.scene.scene().id)?;
    if Arc::ptr_eq(&current, &session.scene) {
        return Ok(session);
    }
    let regions = !session.region.is_point();
    let (method, cache) = prepare_client(&current, &session.spec(), regions).await?;
    let moved = session.rebound(current, method, cache).await;
    state.sessions().replace(&session, moved)
}

/// `POST /sessions/{sid}/frames`: the change since the frame the client holds.
pub async fn frames(
    State(state): State<AppState>,
    Path(sid): Path<String>,
    headers: HeaderMap,
    RawBody(body): RawBody,
) -> Result<Response, ApiError> {
    let frame = answer_frame(&state, &sid, &body, false).await?;
    Ok(if wants_binary(&headers) {
        binary_body(binary::encode_frame(&frame))
    } else {
        json_body(frame.to_json())
    })
}

/// `DELETE /sessions/{sid}`: ends a session (and its user's part in a walkthrough).
pub async fn delete_session(
    State(state): State<AppState>,
    Path(sid): Path<String>,
) -> Result<StatusCode, ApiError> {
    state.sessions().remove(&sid)?;
    Ok(StatusCode::NO_CONTENT)
}

/// `POST /walkthroughs`: a walkthrough of one scene and method, its id
/// minted on the request's routing key.
pub async fn create_walkthrough(
    State(state): State<AppState>,
    headers: HeaderMap,
    RawBody(body): RawBody,
) -> Result<(StatusCode, Json<WalkthroughCreated>), ApiError> {
    let route = RouteKey::of_request(&headers)?;
    let (methods, spec, region) = scene_and_spec(&state, &body)?;
    // Refuse a bad method now rather than at the first user.
    let method = prepare_client(&methods, &spec, !region.is_point())
        .await?
        .0
        .name();
    let w = state
        .walkthroughs()
        .create(&route, methods, spec, method, region);
    Ok((
        StatusCode::CREATED,
        Json(WalkthroughCreated {
            walkthrough: w.id.clone(),
            method: method.to_string(),
        }),
    ))
}

/// `POST /walkthroughs/{wid}/users`: a new user, with its own session on
/// the walkthrough's routing key. With a body naming the scene (and the
/// method, as `POST /walkthroughs` takes) a walkthrough this replica does
/// not hold is made again under the same id: users rejoining a walkthrough lost
/// with its replica meet again on the one its id routes to now.
pub async fn join_walkthrough(
    State(state): State<AppState>,
    Path(wid): Path<String>,
    RawBody(body): RawBody,
) -> Result<(StatusCode, Json<UserJoined>), ApiError> {
    let req: JoinRequest = if body.iter().all(u8::is_ascii_whitespace) {
        JoinRequest::default()
    } else {
        parse(&body, state.limits().json)?
    };
    let (w, recreated) = match (state.walkthroughs().get(&wid), &req.scene) {
        (Ok(w), _) => (w, false),
        (Err(unknown), None) => return Err(unknown),
        (Err(_), Some(scene)) => {
            let methods = state.scene(scene)?;
            let spec = method_spec(req.method.as_deref(), &req.options)?;
            let region = wire::region(req.radius, req.angle, Region::POINT)?;
            let method = prepare_client(&methods, &spec, !region.is_point())
                .await?
                .0
                .name();
            state
                .walkthroughs()
                .get_or_recreate(&wid, methods, spec, method, region)?
        }
    };
    let (method, cache) = prepare_client(&w.scene, &w.spec, !w.region.is_point()).await?;
    let user = w.join();
    let user_id = user.id.clone();
    let session = state.sessions().insert(
        Session::new(&w.route, w.scene.clone(), method, cache, Some(user)).with_region(w.region),
    );
    Ok((
        StatusCode::CREATED,
        Json(UserJoined {
            user: user_id,
            session: session.id.clone(),
            recreated,
        }),
    ))
}

/// `GET /walkthroughs/{wid}`: its users and their last poses.
pub async fn walkthrough(
    State(state): State<AppState>,
    Path(wid): Path<String>,
) -> Result<Json<WalkthroughInfo>, ApiError> {
    let w = state.walkthroughs().get(&wid)?;
    // Let expired sessions leave first: the store tells of expiry lazily.
    state.sessions().usage();
    Ok(Json(w.info()))
}

/// `GET /metrics`: Prometheus text.
pub async fn metrics(State(state): State<AppState>) -> impl IntoResponse {
    let (live, bytes) = state.sessions().usage();
    state
        .metrics()
        .set_sessions(live, bytes, state.walkthroughs().count());
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        state.metrics().encode(),
    )
}

/// Any path no route matches.
pub async fn no_route(method: Method, OriginalUri(uri): OriginalUri) -> ApiError {
    ApiError::NoRoute {
        method: method.to_string(),
        path: uri.path().to_string(),
    }
}

/// A route that exists, asked with the wrong HTTP method.
pub async fn method_not_allowed(method: Method, OriginalUri(uri): OriginalUri) -> ApiError {
    ApiError::MethodNotAllowed {
        method: method.to_string(),
        path: uri.path().to_string(),
    }
}

/// For `HandleErrorLayer`: what the timeout layer's error becomes.
pub async fn timed_out(state: AppState, err: tower::BoxError) -> ApiError {
    if err.is::<tower::timeout::error::Elapsed>() {
        ApiError::Timeout {
            ms: state.limits().request_timeout.as_millis() as u64,
        }
    } else {
        ApiError::Internal(err.to_string())
    }
}

/// For `CatchPanicLayer`: a handler that panicked answers 500 `internal`.
pub fn panicked(err: Box<dyn std::any::Any + Send + 'static>) -> axum::response::Response {
    let detail = err
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| err.downcast_ref::<&str>().copied())
        .unwrap_or("a panic with no message");
    ApiError::Internal(format!("handler panicked: {detail}")).into_response()
}
