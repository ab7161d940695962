//! Scene reload without downtime: changed files are swapped in, unchanged
//! ones keep their scene and ids, a file that fails keeps the old scene
//! serving, sessions of a reloaded scene get the whole set at their next
//! frame, and only the admin token may ask. `SIGHUP` does it in a real
//! server process.

mod common;

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::server::{Server, new_session};
use pvsd::scene::generate::{CityOptions, city};
use pvsd::scene::load_path;
use pvsd::server::{AppState, Limits};
use pvsd_proto::json::{FrameResponse, ObjectInfo, ReloadReport, VisibleResponse};
use serde_json::{Value, json};

const TOKEN: &str = "reload-test-token";
const VIEW: &str = r#"{"eye":[0,300,0],"forward":[0.01,-1,0],"fov_y_deg":120}"#;

fn write_city(path: &Path, buildings: u32, seed: u64) {
    let glb = city(&CityOptions {
        buildings,
        seed,
        ..CityOptions::default()
    })
    .to_glb();
    // Written beside and renamed, as an operator's deploy would.
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, glb).unwrap();
    std::fs::rename(tmp, path).unwrap();
}

struct Fixture {
    _dir: tempfile::TempDir,
    a: std::path::PathBuf,
    b: std::path::PathBuf,
    state: AppState,
    server: Server,
    http: reqwest::Client,
}

async fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.glb"), dir.path().join("b.glb"));
    write_city(&a, 12, 1);
    write_city(&b, 12, 2);
    let scenes = [&a, &b]
        .iter()
        .map(|p| Arc::new(load_path(p).unwrap()))
        .collect();
    let state = AppState::new(scenes, Limits::default())
        .unwrap()
        .with_admin_token(Some(TOKEN.into()))
        .with_scene_files(vec![a.clone(), b.clone()]);
    let server = Server::start(state.clone()).await;
    Fixture {
        _dir: dir,
        a,
        b,
        state,
        server,
        http: reqwest::Client::new(),
    }
}

impl Fixture {
    async fn reload(&self) -> ReloadReport {
        let r = self
            .http
            .post(self.server.url("/admin/reload"))
            .bearer_auth(TOKEN)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        r.json().await.unwrap()
    }

    async fn objects(&self, scene: &str) -> Vec<ObjectInfo> {
        self.http
            .get(self.server.url(&format!("/scenes/{scene}/objects")))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap()
    }

    async fn visible(&self, scene: &str) -> Vec<u32> {
        let r: VisibleResponse = self
            .http
            .post(self.server.url(&format!("/scenes/{scene}/visible")))
            .body(VIEW)
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        r.visible
    }

    async fn frame(&self, sid: &str) -> FrameResponse {
        let r = self
            .http
            .post(self.server.url(&format!("/sessions/{sid}/frames")))
            .body(VIEW)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        r.json().await.unwrap()
    }
}

#[tokio::test]
async fn a_changed_file_is_swapped_in_and_its_sessions_get_the_whole_set() {
    let f = fixture().await;
    let sid = new_session(
        &f.http,
        &f.server,
        json!({"scene": "a", "method": "frustum"}),
    )
    .await;
    let first = f.frame(&sid).await;
    assert_eq!((first.frame, first.base), (1, None));
    let second = f.frame(&sid).await;
    assert_eq!(second.base, Some(1));
    let b_objects = f.objects("b").await;
    let b_scene = f.state.scene("b").unwrap();
    let old_a = f.state.scene("a").unwrap();

    write_city(&f.a, 30, 5);
    let report = f.reload().await;
    assert_eq!(report.reloaded, ["a"]);
    assert_eq!(report.unchanged, ["b"]);
    assert!(report.failed.is_empty());
    // The new a serves; b is the same scene, ids and all.
    assert_eq!(f.objects("a").await.len(), 31);
    assert_eq!(f.objects("b").await, b_objects);
    assert!(Arc::ptr_eq(&f.state.scene("b").unwrap(), &b_scene));
    // What a request in flight held still answers, on the old version.
    assert_eq!(old_a.scene().objects().len(), 13);
    // The session moves to the new scene: the whole set, numbers going on.
    let third = f.frame(&sid).await;
    assert_eq!((third.frame, third.base), (3, None));
    let mut held = third.added.clone();
    held.sort_unstable();
    assert_eq!(held, f.visible("a").await);
    let fourth = f.frame(&sid).await;
    assert_eq!(fourth.base, Some(3));
    // Nothing changed since: a second reload swaps nothing.
    let again = f.reload().await;
    assert!(again.reloaded.is_empty() && again.failed.is_empty());
}

#[tokio::test]
async fn a_broken_file_keeps_the_old_scene_serving() {
    let f = fixture().await;
    let before = f.visible("a").await;
    std::fs::write(&f.a, b"this is not a glTF file").unwrap();
    let glb = std::fs::read(&f.b).unwrap();
    std::fs::write(&f.b, &glb[..glb.len() / 2]).unwrap();
    let report = f.reload().await;
    assert!(report.reloaded.is_empty());
    let failed: Vec<&str> = report.failed.iter().map(|x| x.scene.as_str()).collect();
    assert_eq!(failed, ["a", "b"]);
    assert!(report.failed[0].error.contains("a.glb"), "{report:?}");
    assert!(report.failed[1].error.contains("b.glb"), "{report:?}");
    assert_eq!(f.visible("a").await, before);
    assert_eq!(f.objects("b").await.len(), 13);
    // A file gone is a failure too.
    std::fs::remove_file(&f.a).unwrap();
    assert_eq!(f.reload().await.failed.len(), 2);
    assert_eq!(f.visible("a").await, before);
}

#[tokio::test]
async fn only_the_admin_token_may_reload() {
    let f = fixture().await;
    write_city(&f.a, 30, 5);
    let r = f
        .http
        .post(f.server.url("/admin/reload"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 401);
    let r = f
        .http
        .post(f.server.url("/admin/reload"))
        .bearer_auth("not-the-token")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 401);
    let e: Value = r.json().await.unwrap();
    assert_eq!(e["error"]["code"], "unauthorized");
    // Nothing was reloaded.
    assert_eq!(f.objects("a").await.len(), 13);
    // A server with no token refuses everyone.
    let open = Server::start(
        AppState::new(vec![common::city_scene(3, 1, [0.0; 3])], Limits::default()).unwrap(),
    )
    .await;
    let r = f
        .http
        .post(open.url("/admin/reload"))
        .bearer_auth(TOKEN)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 403);
}

/// `kill -HUP` reloads a real server's scene files.
#[test]
fn sighup_reloads_the_scene_files() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.glb");
    write_city(&a, 12, 1);
    let (mut child, addr, _) = common::spawn_serve(&["--scene", a.to_str().unwrap()], &[]);
    let count = || {
        get_json(&format!("http://{addr}/scenes/a/objects"))
            .as_array()
            .map_or(0, Vec::len)
    };
    assert_eq!(count(), 13);
    write_city(&a, 30, 5);
    let status = std::process::Command::new("kill")
        .args(["-HUP", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let deadline = Instant::now() + Duration::from_secs(30);
    while count() != 31 {
        assert!(Instant::now() < deadline, "SIGHUP did not reload the scene");
        std::thread::sleep(Duration::from_millis(100));
    }
    child.kill().unwrap();
    child.wait().unwrap();
}

/// GET as JSON from a plain thread (the test is not async).
fn get_json(url: &str) -> Value {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async { reqwest::get(url).await.unwrap().json().await.unwrap() })
}
