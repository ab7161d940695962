//! The config TOML. Invariants: a config that is accepted has limits the
//! server can run with (every count and time > 0), paths resolved against
//! the config's folder, and TLS either whole or absent.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use pvsd::server::config::ServeConfig;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(cfg) = ServeConfig::from_toml(text, Path::new("/etc/pvsd")) else {
        return;
    };
    let l = cfg.limits();
    assert!(l.body_bytes > 0 && l.connections.max_connections > 0);
    assert!(!l.request_timeout.is_zero() && !l.connections.header_timeout.is_zero());
    assert!(!l.connections.body_timeout.is_zero());
    assert!(l.sessions.max_sessions > 0 && l.sessions.cache_bytes > 0);
    assert!(l.json.max_depth > 0 && l.json.max_array > 0);
    for rate in l.client_rate.iter().chain(&l.websocket_rate) {
        assert!(rate.per_s.is_finite() && rate.per_s > 0.0 && rate.burst > 0);
    }
    for p in cfg.scenes.iter().chain(&cfg.bake_dir).chain(&cfg.tls_cert) {
        assert!(p.is_absolute(), "{} is not resolved", p.display());
    }
    assert_eq!(cfg.tls_cert.is_some(), cfg.tls_key.is_some());
    // (Not `method_context()`: it opens this machine's Vulkan device.)
    assert!(!cfg.disabled_methods.iter().any(|m| m == "frustum"));
});
