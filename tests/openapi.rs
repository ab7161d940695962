//! The OpenAPI document says what the router does: every documented
//! operation is served, its example fits the documented request and is
//! answered with a documented status, and the answer fits the documented
//! schema.
//!
//! The document is generated from `pvsd_proto`'s types
//! (`pvsd_proto::openapi`); `proto/openapi.json` is its committed copy,
//! which pvsd-proto's own test keeps equal to it.

mod common;

use axum::body::Body;
use axum::http::Request;
use common::city_scene;
use http_body_util::BodyExt;
use pvsd::server::{AppState, Limits, app, route_table};
use serde_json::Value;
use tower::ServiceExt;

fn spec() -> Value {
    serde_json::from_str(&pvsd_proto::openapi::to_json()).unwrap()
}

fn resolve<'a>(spec: &'a Value, v: &'a Value) -> &'a Value {
    match v.get("$ref").and_then(Value::as_str) {
        Some(r) => resolve(
            spec,
            spec.pointer(r.trim_start_matches('#'))
                .unwrap_or_else(|| panic!("dangling {r}")),
        ),
        None => v,
    }
}

/// Checks `value` against the subset of JSON Schema the document uses
/// (what utoipa emits for the proto types).
fn conforms(spec: &Value, schema: &Value, value: &Value, at: &str) -> Result<(), String> {
    let schema = resolve(spec, schema);
    if let Some(options) = schema.get("oneOf").and_then(Value::as_array) {
        let fits = options
            .iter()
            .filter(|s| conforms(spec, s, value, at).is_ok())
            .count();
        return if fits == 1 {
            Ok(())
        } else {
            Err(format!("{at}: fits {fits} of oneOf"))
        };
    }
    for part in schema
        .get("allOf")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
    {
        conforms(spec, part, value, at)?;
    }
    let types: Vec<&str> = match schema.get("type") {
        Some(Value::String(t)) => vec![t.as_str()],
        Some(Value::Array(ts)) => ts.iter().filter_map(Value::as_str).collect(),
        _ => vec![],
    };
    let kind = match value {
        Value::Null => "null",
        Value::Bool(_) => "boolean",
        Value::Number(n) if n.is_u64() || n.is_i64() => "integer",
        Value::Number(_) => "number",
        Value::String(_) => "string",
        Value::Array(_) => "array",
        Value::Object(_) => "object",
    };
    if !types.is_empty()
        && !types
            .iter()
            .any(|t| *t == kind || (*t == "number" && kind == "integer"))
    {
        return Err(format!("{at}: {kind} is not {types:?}"));
    }
    if let (Some(e), Some(s)) = (schema.get("enum").and_then(Value::as_array), value.as_str()) {
        if !e.iter().any(|x| x == s) {
            return Err(format!("{at}: '{s}' not in enum"));
        }
    }
    if let Value::Object(map) = value {
        for r in schema
            .get("required")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            let r = r.as_str().unwrap();
            if !map.contains_key(r) {
                return Err(format!("{at}: missing required '{r}'"));
            }
        }
        let props = schema.get("properties").and_then(Value::as_object);
        let additional = schema.get("additionalProperties");
        for (k, v) in map {
            match (props.and_then(|p| p.get(k)), additional) {
                (Some(s), _) => conforms(spec, s, v, &format!("{at}.{k}"))?,
                (None, Some(Value::Bool(false))) => {
                    return Err(format!("{at}: '{k}' is not allowed"));
                }
                (None, Some(s @ Value::Object(_))) => conforms(spec, s, v, &format!("{at}.{k}"))?,
                // Answers say every field they send.
                (None, _) if props.is_some() => {
                    return Err(format!("{at}: '{k}' is not documented"));
                }
                (None, _) => {}
            }
        }
    }
    if let Value::Array(items) = value {
        let len = items.len() as u64;
        if let Some(min) = schema.get("minItems").and_then(Value::as_u64) {
            if len < min {
                return Err(format!("{at}: {len} items, fewer than {min}"));
            }
        }
        if let Some(max) = schema.get("maxItems").and_then(Value::as_u64) {
            if len > max {
                return Err(format!("{at}: {len} items, more than {max}"));
            }
        }
        if let Some(s) = schema.get("items") {
            for (i, v) in items.iter().enumerate() {
                conforms(spec, s, v, &format!("{at}[{i}]"))?;
            }
        }
    }
    Ok(())
}

/// `POST {path}` with `{"scene": "city"}`; the new resource's id.
async fn created(state: &AppState, path: &str, field: &str) -> String {
    let req = Request::builder()
        .method("POST")
        .uri(path)
        .body(Body::from(r#"{"scene":"city"}"#))
        .unwrap();
    let res = app(state.clone()).oneshot(req).await.unwrap();
    let bytes = res.into_body().collect().await.unwrap().to_bytes();
    let v: Value = serde_json::from_slice(&bytes).unwrap();
    v[field].as_str().unwrap().to_string()
}

#[test]
fn the_document_lists_exactly_the_routes() {
    let spec = spec();
    let mut documented: Vec<(String, String)> = spec["paths"]
        .as_object()
        .unwrap()
        .iter()
        .flat_map(|(path, item)| {
            item.as_object()
                .unwrap()
                .keys()
                .map(move |m| (m.to_uppercase(), path.clone()))
        })
        .collect();
    let mut routed: Vec<(String, String)> = route_table()
        .into_iter()
        .map(|(m, p)| (m.to_string(), p.to_string()))
        .collect();
    documented.sort();
    routed.sort();
    assert_eq!(documented, routed);
}

#[tokio::test]
async fn every_documented_operation_is_served_as_documented() {
    let spec = spec();
    let state = AppState::new(vec![city_scene(100, 1, [0.0; 3])], Limits::default()).unwrap();
    let mut operations = 0;
    for (path, item) in spec["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            operations += 1;
            // Each operation on a session or walkthrough gets a fresh one.
            let mut uri = path
                .replace("{id}", "city")
                .replace("{oid}", "0")
                .replace("{file}", "viewer.js");
            if uri.contains("{sid}") {
                uri = uri.replace("{sid}", &created(&state, "/sessions", "session").await);
            }
            if uri.contains("{wid}") {
                let wid = created(&state, "/walkthroughs", "walkthrough").await;
                uri = uri.replace("{wid}", &wid);
            }
            let example = op.pointer("/requestBody/content/application~1json/example");
            if let Some(e) = example {
                let schema = &op["requestBody"]["content"]["application/json"]["schema"];
                conforms(&spec, schema, e, &format!("{method} {path} example")).unwrap();
            }
            let body = example.map_or_else(Body::empty, |e| Body::from(e.to_string()));
            let req = Request::builder()
                .method(method.to_uppercase().as_str())
                .uri(&uri)
                .body(body)
                .unwrap();
            let res = app(state.clone()).oneshot(req).await.unwrap();
            let status = res.status().as_u16().to_string();
            let response = op["responses"]
                .get(&status)
                .unwrap_or_else(|| panic!("{method} {path}: undocumented status {status}"));
            let response = resolve(&spec, response);
            let bytes = res.into_body().collect().await.unwrap().to_bytes();
            if let Some(schema) = response.pointer("/content/application~1json/schema") {
                let value: Value = serde_json::from_slice(&bytes).unwrap();
                conforms(&spec, schema, &value, &format!("{method} {path}")).unwrap();
            }
        }
    }
    assert_eq!(operations, route_table().len());
}

#[tokio::test]
async fn errors_fit_the_error_schema() {
    let spec = spec();
    let state = AppState::new(vec![city_scene(10, 1, [0.0; 3])], Limits::default()).unwrap();
    for (method, uri, body) in [
        (
            "POST",
            "/scenes/city/visible",
            "{\"eye\":[0,NaN,0],\"forward\":[1,0,0]}",
        ),
        ("POST", "/scenes/x/visible", "{}"),
        ("GET", "/scenes/x/objects", ""),
        ("GET", "/nowhere", ""),
        ("POST", "/sessions/ffff/frames", "{}"),
        ("GET", "/sessions/ffff/ws", ""),
        ("GET", "/walkthroughs/x", ""),
        (
            "POST",
            "/sessions",
            "{\"scene\":\"city\",\"method\":\"ddo\"}",
        ),
    ] {
        let req = Request::builder()
            .method(method)
            .uri(uri)
            .body(Body::from(body))
            .unwrap();
        let res = app(state.clone()).oneshot(req).await.unwrap();
        let value: Value =
            serde_json::from_slice(&res.into_body().collect().await.unwrap().to_bytes()).unwrap();
        conforms(&spec, &spec["components"]["schemas"]["Error"], &value, uri).unwrap();
    }
}

#[test]
fn the_checker_can_fail() {
    let spec = spec();
    let stats = &spec["components"]["schemas"]["Stats"];
    let bad = serde_json::json!({"method": "frustum", "cull_us": 1.0, "nodes_tested": 1, "in_frustum": 1});
    assert!(
        conforms(&spec, stats, &bad, "stats")
            .unwrap_err()
            .contains("visible")
    );
    let extra = serde_json::json!({"method": "f", "cull_us": 1, "nodes_tested": 1, "in_frustum": 1, "visible": 1, "x": 1});
    assert!(conforms(&spec, stats, &extra, "stats").is_err());
    let fell = serde_json::json!({"method": "frustum", "cull_us": 1.0, "nodes_tested": 1,
        "in_frustum": null, "visible": 1, "fallback": "frustum", "fallback_reason": "device lost"});
    conforms(&spec, stats, &fell, "stats").unwrap();
    let bad_fallback = serde_json::json!({"method": "f", "cull_us": 1, "nodes_tested": 1,
        "in_frustum": 1, "visible": 1, "fallback": null});
    assert!(conforms(&spec, stats, &bad_fallback, "stats").is_err());
    let schemas = &spec["components"]["schemas"];
    let short = serde_json::json!({"min": [0, 0], "max": [1, 1, 1]});
    assert!(
        conforms(&spec, &schemas["Bounds"], &short, "bounds")
            .unwrap_err()
            .contains("fewer than 3")
    );
    let view = serde_json::json!({"eye": [0, 1, 0], "forward": [1, 0, 0], "fov": 60});
    assert!(
        conforms(&spec, &schemas["View"], &view, "view")
            .unwrap_err()
            .contains("'fov' is not allowed")
    );
    let scene = serde_json::json!({"id": "c", "objects": 1, "triangles": 1, "bounds": null,
        "up": [0, 1, 0], "methods": [], "unsupported": {"horizon": 3}});
    assert!(conforms(&spec, &schemas["SceneInfo"], &scene, "scene").is_err());
}
