//! A real pvsd server on a real socket, and what clients of sessions need:
//! views as JSON, delta application, and an `application/x-pvs` decoder
//! written from `proto/wire-format.md` alone (not the server's codec).

use std::collections::BTreeSet;
use std::net::SocketAddr;

use pvsd::geom::Camera;
use pvsd::server::{AppState, Limits};
use pvsd_proto::json::{FrameResponse, SessionCreated};
use serde_json::{Value, json};

/// A server running until dropped.
pub struct Server {
    /// Where it listens.
    pub addr: SocketAddr,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
}

impl Server {
    /// Serves `state` on a fresh loopback port.
    pub async fn start(state: AppState) -> Server {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        tokio::spawn(pvsd::server::run(listener, state, async {
            stopped.await.ok();
        }));
        Server {
            addr,
            stop: Some(stop),
        }
    }

    /// Serves `scenes` with `limits`.
    pub async fn with(scenes: Vec<std::sync::Arc<pvsd::scene::Scene>>, limits: Limits) -> Server {
        Server::start(AppState::new(scenes, limits).unwrap()).await
    }

    /// `http://addr/path`.
    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }

    /// The value of the `/metrics` sample named `sample` (name and labels,
    /// as Prometheus prints them), 0 when it is not there yet.
    pub async fn metric(&self, c: &reqwest::Client, sample: &str) -> f64 {
        let text = c
            .get(self.url("/metrics"))
            .send()
            .await
            .unwrap()
            .text()
            .await
            .unwrap();
        text.lines()
            .find_map(|l| l.strip_prefix(sample)?.strip_prefix(' '))
            .map_or(0.0, |v| v.parse().unwrap())
    }

    /// `ws://addr/path`.
    pub fn ws_url(&self, path: &str) -> String {
        format!("ws://{}{path}", self.addr)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
    }
}

/// `POST /sessions` with `body`; the new session's id.
pub async fn new_session(client: &reqwest::Client, s: &Server, body: Value) -> String {
    let res = client
        .post(s.url("/sessions"))
        .json(&body)
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 201);
    res.json::<SessionCreated>().await.unwrap().session
}

/// A camera as a view body.
pub fn view_json(c: &Camera) -> Value {
    json!({
        "eye": c.eye.to_array(),
        "forward": c.forward.to_array(),
        "up": c.up.to_array(),
        "fov_y_deg": c.fov_y_deg,
        "aspect": c.aspect,
        "near": c.near,
        "far": c.far,
        "viewport": c.viewport,
    })
}

/// What a client holds, rebuilt from frames.
#[derive(Default)]
pub struct Held {
    /// The set after the last frame applied.
    pub ids: BTreeSet<u32>,
    /// The last frame applied.
    pub frame: Option<u64>,
}

impl Held {
    /// Applies a frame, checking it is a delta against what is held.
    pub fn apply(&mut self, f: &FrameResponse) {
        match f.base {
            None => self.ids.clear(),
            Some(b) => assert_eq!(
                Some(b),
                self.frame,
                "frame {} is a delta against {b}, the client holds {:?}",
                f.frame,
                self.frame
            ),
        }
        for id in &f.removed {
            assert!(
                self.ids.remove(id),
                "frame {} removes {id}, not held",
                f.frame
            );
        }
        for id in &f.added {
            assert!(self.ids.insert(*id), "frame {} adds {id}, held", f.frame);
        }
        self.frame = Some(f.frame);
    }

    /// The held ids, ascending.
    pub fn sorted(&self) -> Vec<u32> {
        self.ids.iter().copied().collect()
    }
}

/// An `application/x-pvs` decoder from the spec, independent of the server's.
pub mod xpvs {
    use pvsd_proto::json::FrameResponse;

    fn varint(b: &[u8], at: &mut usize) -> u64 {
        let mut v = 0u64;
        let mut shift = 0;
        loop {
            let byte = b[*at];
            *at += 1;
            v |= u64::from(byte & 0x7f) << shift;
            if byte & 0x80 == 0 {
                return v;
            }
            shift += 7;
        }
    }

    fn ids(b: &[u8], at: &mut usize) -> Vec<u32> {
        let n = varint(b, at);
        let mut out = Vec::new();
        let mut prev: Option<u64> = None;
        for _ in 0..n {
            let gap = varint(b, at);
            let id = match prev {
                None => gap,
                Some(p) => p + 1 + gap,
            };
            out.push(u32::try_from(id).unwrap());
            prev = Some(id);
        }
        out
    }

    /// A `V` message: the ids.
    pub fn visible(b: &[u8]) -> Vec<u32> {
        assert_eq!(b[0], b'V');
        let mut at = 1;
        let out = ids(b, &mut at);
        assert_eq!(at, b.len(), "trailing bytes");
        out
    }

    /// An `F` message: the frame.
    pub fn frame(b: &[u8]) -> FrameResponse {
        assert_eq!(b[0], b'F');
        let flags = b[1];
        assert_eq!(flags & !3, 0, "unknown flags");
        let mut at = 2;
        let frame = varint(b, &mut at);
        let base = (flags & 1 != 0).then(|| varint(b, &mut at));
        let added = ids(b, &mut at);
        let removed = ids(b, &mut at);
        let users_visible = (flags & 2 != 0).then(|| {
            let n = varint(b, &mut at);
            (0..n)
                .map(|_| {
                    let len = varint(b, &mut at) as usize;
                    let s = String::from_utf8(b[at..at + len].to_vec()).unwrap();
                    at += len;
                    s
                })
                .collect()
        });
        assert_eq!(at, b.len(), "trailing bytes");
        FrameResponse {
            frame,
            base,
            added,
            removed,
            users_visible,
            stats: None,
        }
    }
}
