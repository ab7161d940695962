//! What the loadtest crate's tests share: the real `pvsd` binary.
//!
//! loadtest shares only `pvsd-proto` with the server, so the real pvsd is
//! its binary, run as an operator would; it is built first with the cargo
//! that runs the tests (a no-op when it is fresh), so it is never a stale
//! one.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

use serde_json::Value;

/// The `pvsd` binary of this workspace, built (once per test run) in the
/// profile and target directory of this test.
pub fn pvsd_binary() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        // This test runs as <target>/<profile dir>/deps/loadtest-<hash>.
        let exe = std::env::current_exe().unwrap();
        let profile_dir = exe.parent().and_then(Path::parent).unwrap();
        let target_dir = profile_dir.parent().unwrap();
        let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
            Some("debug") | None => "dev",
            Some(other) => other,
        };
        let out = Command::new(env!("CARGO"))
            .args([
                "build",
                "-p",
                "pvsd",
                "--bin",
                "pvsd",
                "--message-format=json",
            ])
            .args(["--profile", profile])
            .arg("--target-dir")
            .arg(target_dir)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "cargo build -p pvsd failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout)
            .unwrap()
            .lines()
            .filter_map(|l| serde_json::from_str::<Value>(l).ok())
            .filter(|m| m["reason"] == "compiler-artifact" && m["target"]["name"] == "pvsd")
            .find_map(|m| m["executable"].as_str().map(PathBuf::from))
            .expect("cargo named the pvsd executable")
    })
}
