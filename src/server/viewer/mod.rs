//! The web viewer (`GET /`, `GET /viewer`, `GET /viewer/{file}`): a thin
//! client in the browser, served from files built into the binary, so a
//! server needs nothing beside it and no page ever reaches the network.
//!
//! The page (`static/`) walks a scene, holds a session over the WebSocket
//! (`x-pvs` frames with stats), fetches each object's triangles the first
//! time it is in the set (`POST /scenes/{id}/meshes`) and draws them with
//! three.js (pinned, vendored with its licence: `static/THREE-LICENSE`).
//! `docs/viewer.md` says what it shows and how tests drive it.

use axum::extract::Path;
use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};

use super::error::ApiError;

/// One file of the page.
struct Asset {
    name: &'static str,
    content_type: &'static str,
    bytes: &'static [u8],
}

const INDEX: Asset = Asset {
    name: "index.html",
    content_type: "text/html; charset=utf-8",
    bytes: include_bytes!("static/index.html"),
};

/// The page's files. three.js's name carries its version, so it may be
/// cached for good; the page's own files are asked again each load.
const ASSETS: [Asset; 5] = [
    INDEX,
    Asset {
        name: "viewer.js",
        content_type: "text/javascript; charset=utf-8",
        bytes: include_bytes!("static/viewer.js"),
    },
    Asset {
        name: "protocol.js",
        content_type: "text/javascript; charset=utf-8",
        bytes: include_bytes!("static/protocol.js"),
    },
    Asset {
        name: "viewer.css",
        content_type: "text/css; charset=utf-8",
        bytes: include_bytes!("static/viewer.css"),
    },
    Asset {
        name: THREE,
        content_type: "text/javascript; charset=utf-8",
        bytes: include_bytes!("static/three-0.170.0.module.min.js"),
    },
];

/// The vendored three.js, named by its version.
const THREE: &str = "three-0.170.0.module.min.js";

/// `GET /` and `GET /viewer`: the page (its query picks scene, method,
/// options, walkthrough).
pub async fn page() -> Response {
    serve(&INDEX)
}

/// `GET /viewer/{file}`: the page's scripts, style and three.js.
pub async fn asset(Path(file): Path<String>) -> Result<Response, ApiError> {
    ASSETS
        .iter()
        .find(|a| a.name == file)
        .map(serve)
        .ok_or(ApiError::NoRoute {
            method: "GET".into(),
            path: format!("/viewer/{file}"),
        })
}

fn serve(a: &Asset) -> Response {
    let cache = if a.name == THREE {
        "public, max-age=31536000, immutable"
    } else {
        "no-cache"
    };
    (
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static(a.content_type),
            ),
            (header::CACHE_CONTROL, HeaderValue::from_static(cache)),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
        ],
        a.bytes,
    )
        .into_response()
}
