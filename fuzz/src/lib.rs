//! What the fuzz targets share: one small server state (a generated city
//! of 20 buildings with one session) and a runtime to drive it, built once
//! per fuzzing process; and the check every error answer must pass.

use std::sync::{Arc, OnceLock};

use pvsd::cull::{MethodContext, Registry};
use pvsd::scene::generate::{CityOptions, city};
use pvsd::scene::{Scene, load_slice};
use pvsd::server::{AppState, Limits, SessionLimits};
use pvsd_proto::error::ErrorBody;

/// The admin token of the fuzzed server.
pub const TOKEN: &str = "fuzz-admin-token";

/// The shared server.
pub struct Fixture {
    /// A runtime to run handlers on (one thread: each run is sequential).
    pub runtime: tokio::runtime::Runtime,
    /// The state, its scene called `city`.
    pub state: AppState,
    /// Its router.
    pub router: axum::Router,
    /// A session of frustum culling on it.
    pub session: String,
}

/// The fixture, built on first use.
pub fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        // Few sessions: bodies that make sessions evict old ones instead of
        // growing the fuzzer's memory.
        let limits = Limits {
            sessions: SessionLimits {
                max_sessions: 64,
                ..SessionLimits::default()
            },
            ..Limits::default()
        };
        // No Vulkan device: the routes are fuzzed, not the driver (whose
        // allocations LeakSanitizer would report as ours).
        let state = AppState::with_methods(
            vec![scene()],
            limits,
            &Registry::standard(),
            &MethodContext::default(),
        )
        .unwrap()
        .with_admin_token(Some(TOKEN.into()));
        let router = pvsd::server::app(state.clone());
        let mut fixture = Fixture {
            runtime,
            state,
            router,
            session: String::new(),
        };
        let (status, body) = fixture.call(
            "POST",
            "/sessions",
            br#"{"scene":"city","method":"frustum"}"#,
            None,
        );
        assert_eq!(status, 201);
        let created: serde_json::Value = serde_json::from_slice(&body).unwrap();
        fixture.session = created["session"].as_str().unwrap().to_string();
        fixture
    })
}

impl Fixture {
    /// One request through the server's router: its status and body.
    pub fn call(
        &self,
        method: &str,
        path: &str,
        body: &[u8],
        authorization: Option<&str>,
    ) -> (u16, Vec<u8>) {
        use http_body_util::BodyExt;
        use tower::ServiceExt;
        let mut req = axum::http::Request::builder().method(method).uri(path);
        if let Some(a) = authorization {
            req = req.header("authorization", a);
        }
        let req = req.body(axum::body::Body::from(body.to_vec())).unwrap();
        self.runtime.block_on(async {
            let res = self.router.clone().oneshot(req).await.unwrap();
            let status = res.status().as_u16();
            let bytes = res.into_body().collect().await.unwrap().to_bytes();
            (status, bytes.to_vec())
        })
    }
}

/// The fuzzed scene: a small city.
pub fn scene() -> Arc<Scene> {
    let glb = city(&CityOptions {
        buildings: 20,
        seed: 1,
        ..CityOptions::default()
    })
    .to_glb();
    Arc::new(load_slice("city", &glb, None, std::path::Path::new("city.glb")).unwrap())
}

/// Checks an error answer: `{"error": {"code", "message"}}`, a code the
/// protocol names, a status that is a client's fault (4xx) — bad input
/// must never be a server error.
pub fn check_refusal(status: u16, body: &[u8]) {
    let parsed: ErrorBody = serde_json::from_slice(body).unwrap_or_else(|e| {
        panic!(
            "a {status} answer is not an error body ({e}): {}",
            String::from_utf8_lossy(body)
        )
    });
    assert!(
        (400..500).contains(&status),
        "bad input answered {status}: {}",
        parsed.error.message
    );
    assert!(!parsed.error.message.is_empty());
}
