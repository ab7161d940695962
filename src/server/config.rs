//! `pvsd serve --config FILE`: the server's settings as TOML.
//!
//! ```toml
//! addr = "127.0.0.1:8080"
//! scenes = ["scenes/city1k.glb", "../shared/scenes/Sponza/Sponza.gltf"]
//! body_limit_bytes = 65536
//! request_timeout_ms = 10000
//! session_idle_s = 300           # a session without a frame this long ends
//! max_sessions = 100000          # past it, the least recently used is evicted
//! session_cache_bytes = 268435456  # sessions' caches and kept frames, in all
//! max_walkthroughs = 10000
//! bake_dir = "bakes"             # baked data cached between runs
//! disabled_methods = ["supporting_planes"]  # listed as unsupported
//! rank_methods = true            # measure each scene's methods for `auto`
//! cost_per_triangle_ns = 2.0     # the prices `auto` ranks with
//! cost_per_byte_ns = 0.0
//! max_connections = 10000        # past it, 503 overloaded
//! header_timeout_ms = 10000      # to send a request's head; idle keep-alive
//! body_timeout_ms = 10000        # to send a request's body (408 after)
//! drain_ms = 0                   # SIGTERM: not ready, serving on this long
//! shutdown_grace_s = 10          # then: time for requests in flight
//! replica = "pvsd-0"             # names the replica (x-pvsd-replica header)
//! ddo_leaf_triangles = 256       # ddo's octree leaves (its own bake each)
//! json_max_depth = 16            # nesting of a JSON body (413 past it)
//! json_max_array = 1024          # items of one JSON array (413 past it)
//! rate_limit_per_s = 200.0       # requests a second per client IP (429
//! rate_limit_burst = 400         #   past it); no key, no limit
//! websocket_messages_per_s = 500.0  # per WebSocket; past it, refused
//! websocket_burst = 100          #   (no key, no limit)
//! admin_token = "…"              # bearer token of routes that change scenes
//! tls_cert = "cert.pem"          # both set: HTTPS (rustls), else HTTP
//! tls_key = "key.pem"
//! ```
//! Every key is optional; flags given on the command line win over the file.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use super::{ConnectionLimits, JsonLimits, Limits, Rate, SessionLimits};
use crate::cull::ranking::{COST_PER_BYTE_NS, COST_PER_TRIANGLE_NS, FrameCost};
use crate::cull::{MethodContext, Registry};
use crate::scene::BakeCache;

/// The file's contents.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ServeConfig {
    /// Address to listen on.
    pub addr: Option<SocketAddr>,
    /// Scene files to load; relative paths are relative to the config file.
    #[serde(default)]
    pub scenes: Vec<PathBuf>,
    /// Largest request body accepted, bytes.
    pub body_limit_bytes: Option<usize>,
    /// Request timeout, milliseconds.
    pub request_timeout_ms: Option<u64>,
    /// Idle time after which a session ends, seconds.
    pub session_idle_s: Option<u64>,
    /// Most live sessions.
    pub max_sessions: Option<u64>,
    /// Most bytes all sessions may hold.
    pub session_cache_bytes: Option<u64>,
    /// Most live walkthroughs.
    pub max_walkthroughs: Option<u64>,
    /// Where baked data is cached between runs; relative to the config file.
    pub bake_dir: Option<PathBuf>,
    /// Methods the operator turns off (`/scenes` lists them as unsupported).
    #[serde(default)]
    pub disabled_methods: Vec<String>,
    /// The bearer token of routes that change scenes (`PUT
    /// /scenes/{id}/objects/{oid}`); without one they answer 403.
    pub admin_token: Option<String>,
    /// Whether each scene's methods are measured in the background after
    /// it starts serving, for `auto` (default true; off, `auto` answers
    /// with frustum culling).
    pub rank_methods: Option<bool>,
    /// Modelled cost of drawing a triangle, ns, for `auto` (default 2).
    pub cost_per_triangle_ns: Option<f64>,
    /// Modelled cost of sending a byte of geometry, ns, for `auto` (default 0).
    pub cost_per_byte_ns: Option<f64>,
    /// Most open connections.
    pub max_connections: Option<usize>,
    /// Longest a client may take to send a request's head, ms.
    pub header_timeout_ms: Option<u64>,
    /// Longest a client may take to send a request's body, ms.
    pub body_timeout_ms: Option<u64>,
    /// How long the server, told to stop, serves on while answering
    /// `/healthz/ready` with 503 (so load balancers take it out), ms.
    pub drain_ms: Option<u64>,
    /// How long shutdown waits for requests in flight, seconds.
    pub shutdown_grace_s: Option<u64>,
    /// This replica's name, sent in every answer's `x-pvsd-replica`
    /// header (`--replica` or `PVSD_REPLICA` win over it).
    pub replica: Option<String>,
    /// `ddo`'s octree leaves hold at most this many triangles (each value
    /// is its own bake).
    pub ddo_leaf_triangles: Option<usize>,
    /// Most nested arrays and objects in a JSON body.
    pub json_max_depth: Option<usize>,
    /// Most items in one array of a JSON body.
    pub json_max_array: Option<usize>,
    /// Requests a second each client IP may make (off when absent).
    pub rate_limit_per_s: Option<f64>,
    /// Requests a client IP may make at once (default: a second's worth).
    pub rate_limit_burst: Option<u32>,
    /// Messages a second each WebSocket may send (off when absent).
    pub websocket_messages_per_s: Option<f64>,
    /// Messages a WebSocket may send at once (default: a second's worth).
    pub websocket_burst: Option<u32>,
    /// PEM certificate chain; with `tls_key`, the server speaks HTTPS.
    pub tls_cert: Option<PathBuf>,
    /// PEM private key of `tls_cert`.
    pub tls_key: Option<PathBuf>,
}

/// Checks a replica name: it travels in a header, so 1–64 characters of
/// letters, digits, `-`, `_` and `.`.
pub fn check_replica_name(name: &str) -> Result<(), String> {
    let fits = (1..=64).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'));
    if fits {
        Ok(())
    } else {
        Err(format!(
            "'{name}' is not 1-64 letters, digits, '-', '_' or '.'"
        ))
    }
}

/// A config file that could not be used.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct ConfigError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong.
    pub problem: String,
}

impl ServeConfig {
    /// Reads and checks a config file.
    pub fn load(path: &Path) -> Result<ServeConfig, ConfigError> {
        let fail = |problem: String| ConfigError {
            path: path.to_path_buf(),
            problem,
        };
        let text = std::fs::read_to_string(path).map_err(|e| fail(format!("cannot read: {e}")))?;
        ServeConfig::from_toml(&text, path.parent().unwrap_or(Path::new("."))).map_err(fail)
    }

    /// Reads and checks a config file's text; relative paths are taken
    /// relative to `dir`. The error says what is wrong, without the file.
    pub fn from_toml(text: &str, dir: &Path) -> Result<ServeConfig, String> {
        let mut cfg: ServeConfig = toml::from_str(text).map_err(|e| e.to_string())?;
        for s in cfg
            .scenes
            .iter_mut()
            .chain(&mut cfg.bake_dir)
            .chain(&mut cfg.tls_cert)
            .chain(&mut cfg.tls_key)
        {
            if s.is_relative() {
                *s = dir.join(&*s);
            }
        }
        let registry = Registry::standard();
        if let Some(m) = cfg.disabled_methods.iter().find(|m| !registry.knows(m)) {
            let known: Vec<&str> = registry.entries().iter().map(|e| e.name).collect();
            return Err(format!(
                "disabled_methods: unknown method '{m}'; known methods: {}",
                known.join(", ")
            ));
        }
        if cfg.disabled_methods.iter().any(|m| m == "frustum") {
            return Err(
                "disabled_methods: frustum cannot be disabled: every other method falls back to it"
                    .into(),
            );
        }
        for (range, value) in [
            (&COST_PER_TRIANGLE_NS, cfg.cost_per_triangle_ns),
            (&COST_PER_BYTE_NS, cfg.cost_per_byte_ns),
        ] {
            if let Some(v) = value.filter(|v| !(range.min..=range.max).contains(v)) {
                return Err(format!("{}: {v} is not {}", range.key, range.expected()));
            }
        }
        if let Some(n) = cfg.ddo_leaf_triangles {
            MethodContext::default()
                .with_ddo_leaf_triangles(n)
                .map_err(|e| format!("ddo_leaf_triangles: {e}"))?;
        }
        if cfg.body_limit_bytes == Some(0) {
            return Err("body_limit_bytes must be > 0".into());
        }
        for (key, value) in [
            ("request_timeout_ms", cfg.request_timeout_ms),
            ("session_idle_s", cfg.session_idle_s),
            ("max_sessions", cfg.max_sessions),
            ("session_cache_bytes", cfg.session_cache_bytes),
            ("max_walkthroughs", cfg.max_walkthroughs),
            ("max_connections", cfg.max_connections.map(|v| v as u64)),
            ("header_timeout_ms", cfg.header_timeout_ms),
            ("body_timeout_ms", cfg.body_timeout_ms),
            ("json_max_depth", cfg.json_max_depth.map(|v| v as u64)),
            ("json_max_array", cfg.json_max_array.map(|v| v as u64)),
            ("rate_limit_burst", cfg.rate_limit_burst.map(u64::from)),
            ("websocket_burst", cfg.websocket_burst.map(u64::from)),
        ] {
            if value == Some(0) {
                return Err(format!("{key} must be > 0"));
            }
        }
        for (key, value) in [
            ("rate_limit_per_s", cfg.rate_limit_per_s),
            ("websocket_messages_per_s", cfg.websocket_messages_per_s),
        ] {
            if let Some(v) = value.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(format!("{key}: {v} is not a rate > 0"));
            }
        }
        if cfg.rate_limit_burst.is_some() && cfg.rate_limit_per_s.is_none() {
            return Err("rate_limit_burst: set rate_limit_per_s too (no rate, no limit)".into());
        }
        if cfg.websocket_burst.is_some() && cfg.websocket_messages_per_s.is_none() {
            return Err(
                "websocket_burst: set websocket_messages_per_s too (no rate, no limit)".into(),
            );
        }
        if let Some(name) = &cfg.replica {
            check_replica_name(name).map_err(|e| format!("replica: {e}"))?;
        }
        if cfg.tls_cert.is_some() != cfg.tls_key.is_some() {
            return Err("tls_cert and tls_key: give both (HTTPS) or neither (HTTP)".into());
        }
        Ok(cfg)
    }

    /// The context the server prepares its scenes in: this machine's,
    /// with the config's bake folder (else the user's cache folder,
    /// [`BakeCache::default_dir`]), disabled methods, frame costs and
    /// `ddo`'s leaf size; an error names a value out of range (a config
    /// read from TOML was checked already; one built in code may not be).
    pub fn method_context(&self) -> Result<MethodContext, String> {
        let context = MethodContext {
            bake_dir: self.bake_dir.clone().or_else(BakeCache::default_dir),
            disabled: self.disabled_methods.clone(),
            frame_cost: FrameCost {
                per_triangle_ns: self
                    .cost_per_triangle_ns
                    .unwrap_or(COST_PER_TRIANGLE_NS.default),
                per_byte_ns: self.cost_per_byte_ns.unwrap_or(COST_PER_BYTE_NS.default),
            },
            ..MethodContext::of_this_machine()
        };
        match self.ddo_leaf_triangles {
            Some(n) => context
                .with_ddo_leaf_triangles(n)
                .map_err(|e| format!("ddo_leaf_triangles: {e}")),
            None => Ok(context),
        }
    }

    /// The limits it sets, defaults for what it leaves out.
    pub fn limits(&self) -> Limits {
        let d = Limits::default();
        let s = d.sessions;
        let c = d.connections;
        let ms = Duration::from_millis;
        Limits {
            body_bytes: self.body_limit_bytes.unwrap_or(d.body_bytes),
            request_timeout: self
                .request_timeout_ms
                .map_or(d.request_timeout, Duration::from_millis),
            sessions: SessionLimits {
                idle: self.session_idle_s.map_or(s.idle, Duration::from_secs),
                max_sessions: self.max_sessions.unwrap_or(s.max_sessions),
                cache_bytes: self.session_cache_bytes.unwrap_or(s.cache_bytes),
                max_walkthroughs: self.max_walkthroughs.unwrap_or(s.max_walkthroughs),
            },
            connections: ConnectionLimits {
                max_connections: self.max_connections.unwrap_or(c.max_connections),
                header_timeout: self.header_timeout_ms.map_or(c.header_timeout, ms),
                body_timeout: self.body_timeout_ms.map_or(c.body_timeout, ms),
                drain: self.drain_ms.map_or(c.drain, ms),
                shutdown_grace: self
                    .shutdown_grace_s
                    .map_or(c.shutdown_grace, Duration::from_secs),
            },
            json: JsonLimits {
                max_depth: self.json_max_depth.unwrap_or(d.json.max_depth),
                max_array: self.json_max_array.unwrap_or(d.json.max_array),
            },
            client_rate: self.rate_limit_per_s.map(|per_s| Rate {
                per_s,
                burst: self
                    .rate_limit_burst
                    .unwrap_or((per_s.ceil() as u32).max(1)),
            }),
            websocket_rate: self.websocket_messages_per_s.map(|per_s| Rate {
                per_s,
                burst: self.websocket_burst.unwrap_or((per_s.ceil() as u32).max(1)),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_keys_and_resolves_relative_scenes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("pvsd.toml");
        std::fs::write(
            &p,
            "addr = \"127.0.0.1:9000\"\nscenes = [\"a.glb\"]\nrequest_timeout_ms = 50\n\
             bake_dir = \"bakes\"\ndisabled_methods = [\"horizon\"]\n",
        )
        .unwrap();
        let c = ServeConfig::load(&p).unwrap();
        assert_eq!(c.addr, Some("127.0.0.1:9000".parse().unwrap()));
        assert_eq!(c.scenes, vec![dir.path().join("a.glb")]);
        assert_eq!(c.limits().request_timeout, Duration::from_millis(50));
        assert_eq!(c.limits().body_bytes, Limits::default().body_bytes);
        let context = c.method_context().unwrap();
        assert_eq!(context.bake_dir, Some(dir.path().join("bakes")));
        assert_eq!(context.disabled, vec!["horizon".to_string()]);
        assert_eq!(context.ddo_octree, MethodContext::default().ddo_octree);
    }

    #[test]
    fn ddo_leaf_triangles_is_read_and_checked() {
        let c = ServeConfig::from_toml("ddo_leaf_triangles = 128\n", Path::new(".")).unwrap();
        assert_eq!(c.method_context().unwrap().ddo_octree.leaf_triangles, 128);
        // A config built in code is checked when it makes the context.
        let built = ServeConfig {
            ddo_leaf_triangles: Some(8),
            ..ServeConfig::default()
        };
        let e = built.method_context().unwrap_err();
        assert!(
            e.starts_with("ddo_leaf_triangles: ") && e.contains('8'),
            "{e}"
        );
        for bad in ["0", "15", "1000001"] {
            let e =
                ServeConfig::from_toml(&format!("ddo_leaf_triangles = {bad}\n"), Path::new("."))
                    .unwrap_err();
            assert!(
                e.starts_with("ddo_leaf_triangles: ") && e.contains(bad),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn drain_and_replica_name_are_read_and_checked() {
        let c = ServeConfig::from_toml(
            "drain_ms = 2500\nreplica = \"pvsd-7.a_b\"\n",
            Path::new("."),
        )
        .unwrap();
        assert_eq!(c.limits().connections.drain, Duration::from_millis(2500));
        assert_eq!(c.replica.as_deref(), Some("pvsd-7.a_b"));
        assert_eq!(
            ServeConfig::default().limits().connections.drain,
            Duration::ZERO
        );
        for bad in ["", "a b", "x\\ny", &"r".repeat(65)] {
            let e = ServeConfig::from_toml(&format!("replica = {bad:?}\n"), Path::new("."))
                .unwrap_err();
            assert!(e.starts_with("replica:"), "{bad:?}: {e}");
        }
    }

    #[test]
    fn unknown_keys_and_zero_limits_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("pvsd.toml");
        std::fs::write(&p, "adr = \"x\"\n").unwrap();
        let e = ServeConfig::load(&p).unwrap_err().to_string();
        assert!(e.contains("pvsd.toml") && e.contains("adr"), "{e}");
        std::fs::write(&p, "disabled_methods = [\"octree\"]\n").unwrap();
        let e = ServeConfig::load(&p).unwrap_err().to_string();
        assert!(e.contains("unknown method 'octree'"), "{e}");
        std::fs::write(&p, "disabled_methods = [\"frustum\"]\n").unwrap();
        let e = ServeConfig::load(&p).unwrap_err().to_string();
        assert!(e.contains("frustum cannot be disabled"), "{e}");
        std::fs::write(&p, "body_limit_bytes = 0\n").unwrap();
        assert!(
            ServeConfig::load(&p)
                .unwrap_err()
                .to_string()
                .contains("body_limit_bytes")
        );
    }
}
