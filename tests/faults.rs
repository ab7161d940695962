//! Faults survived, over real sockets and a real server process: clients
//! that vanish mid-request and mid-WebSocket-frame, session ids that are
//! guessed (a prefix, a walkthrough's id), a bake cache that cannot be
//! written. (Killing and restarting the server under load is in
//! `loadtest/tests`; shutdown under load and slow clients in `limits.rs`;
//! broken files at reload in `reload.rs`.)

mod common;

use std::time::Duration;

use common::city_scene;
use common::server::{Server, new_session};
use futures_util::{SinkExt, StreamExt};
use pvsd::server::Limits;
use serde_json::{Value, json};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;

const VIEW: &str = r#"{"eye":[0,1.7,0],"forward":[1,0,0.2]}"#;

async fn frame(c: &reqwest::Client, s: &Server, sid: &str) -> reqwest::StatusCode {
    c.post(s.url(&format!("/sessions/{sid}/frames")))
        .body(VIEW)
        .send()
        .await
        .unwrap()
        .status()
}

/// Clients that disconnect with a body or a WebSocket frame half sent cost
/// the server nothing: their session still answers, others are served,
/// the socket is counted closed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_vanishing_mid_request_and_mid_frame_leave_nothing_behind() {
    let s = Server::with(vec![city_scene(30, 2, [0.0; 3])], Limits::default()).await;
    let c = reqwest::Client::new();
    let sid = new_session(&c, &s, json!({"scene": "city", "method": "horizon"})).await;
    assert_eq!(frame(&c, &s, &sid).await, 200);
    for _ in 0..20 {
        // A frame's head and half its body, then gone.
        let mut t = TcpStream::connect(s.addr).await.unwrap();
        t.write_all(
            format!(
                "POST /sessions/{sid}/frames HTTP/1.1\r\nhost: x\r\ncontent-length: {}\r\n\r\n{}",
                VIEW.len(),
                &VIEW[..VIEW.len() / 2]
            )
            .as_bytes(),
        )
        .await
        .unwrap();
        drop(t);
        // A WebSocket message's header and part of its payload, then gone.
        let (mut ws, _) =
            tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws")))
                .await
                .unwrap();
        ws.send(Message::text(VIEW)).await.unwrap();
        ws.next().await.unwrap().unwrap();
        let tcp = match ws.get_mut() {
            tokio_tungstenite::MaybeTlsStream::Plain(t) => t,
            _ => unreachable!("plain ws://"),
        };
        // FIN + text, masked, 126 → a 16-bit length of 200; 4 mask bytes;
        // 10 of the 200 payload bytes.
        tcp.write_all(&[0x81, 0xFE, 0x00, 0xC8, 1, 2, 3, 4])
            .await
            .unwrap();
        tcp.write_all(&[0u8; 10]).await.unwrap();
        drop(ws);
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    // The session answers on, in order.
    assert_eq!(frame(&c, &s, &sid).await, 200);
    let r = c
        .post(s.url("/scenes/city/visible"))
        .body(VIEW)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(s.metric(&c, "pvsd_websocket_connections").await, 0.0);
    assert_eq!(s.metric(&c, "pvsd_sessions").await, 1.0);
}

/// Session ids are capabilities: only the whole id drives a session; a
/// prefix, another case, the same routing key with another secret, or a
/// walkthrough's id is no session.
#[tokio::test]
async fn a_session_answers_only_to_its_whole_id() {
    let s = Server::with(vec![city_scene(10, 2, [0.0; 3])], Limits::default()).await;
    let c = reqwest::Client::new();
    let sid = new_session(&c, &s, json!({"scene": "city", "method": "horizon"})).await;
    // `<16 hex routing key>-<32 hex secret>` (proto/scale-out.md).
    assert_eq!(sid.len(), 49);
    assert_eq!(sid.as_bytes()[16], b'-');
    assert!(
        sid.bytes()
            .filter(|&b| b != b'-')
            .all(|b| b.is_ascii_hexdigit())
    );
    let walkthrough: Value = c
        .post(s.url("/walkthroughs"))
        .body(r#"{"scene":"city","method":"frustum"}"#)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let wid = walkthrough["walkthrough"].as_str().unwrap().to_string();
    for guess in [
        sid[..48].to_string(),
        sid[..17].to_string(),
        format!("{}{}", &sid[..17], "0".repeat(32)),
        sid.to_uppercase(),
        format!("{sid}0"),
        wid.clone(),
        String::new() + "%20" + &sid,
    ] {
        if guess == sid {
            continue;
        }
        assert_eq!(frame(&c, &s, &guess).await, 404, "{guess}");
        let r = c
            .delete(s.url(&format!("/sessions/{guess}")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 404, "{guess}");
    }
    // The real one was neither driven nor ended by the guesses.
    let first: Value = c
        .post(s.url(&format!("/sessions/{sid}/frames")))
        .body(VIEW)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(first["frame"], 1);
    // Nor is a session a walkthrough.
    let r = c
        .get(s.url(&format!("/walkthroughs/{sid}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 404);
}

/// A bake cache that cannot be written (here a path through a file; a
/// read-only or full disk fails the same write) does not stop the server:
/// it says so once at start, builds its bakes in memory, and serves.
#[test]
fn an_unwritable_bake_cache_is_reported_and_the_server_serves_without_it() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("city.glb");
    std::fs::write(
        &scene,
        pvsd::scene::generate::city(&pvsd::scene::generate::CityOptions {
            buildings: 30,
            seed: 4,
            ..Default::default()
        })
        .to_glb(),
    )
    .unwrap();
    let blocker = dir.path().join("not-a-folder");
    std::fs::write(&blocker, b"a file").unwrap();
    let bakes = blocker.join("bakes");
    let (mut child, addr, log) = common::spawn_serve(
        &[
            "--scene",
            scene.to_str().unwrap(),
            "--bake-dir",
            bakes.to_str().unwrap(),
        ],
        &[],
    );
    let said = log
        .iter()
        .any(|l| l.contains("the bake cache cannot be written") && l.contains("not-a-folder"));
    assert!(said, "no warning in:\n{}", log.join("\n"));
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = reqwest::Client::new();
        for method in ["horizon", "occlusion_tree", "supporting_planes"] {
            let r = c
                .post(format!("http://{addr}/scenes/city/visible"))
                .body(format!(
                    r#"{{"eye":[0,1.7,0],"forward":[1,0,0.2],"method":"{method}"}}"#
                ))
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 200, "{method}");
        }
    });
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!bakes.exists());
}

/// A full disk under the bake cache: the bakes cannot be saved (each says
/// why in the log), none leaves a partial file behind, and the server
/// serves. Needs a tiny file system, so it mounts a 64 KiB tmpfs; where
/// mounting is not allowed (not root, a locked-down container) it says so
/// and checks nothing.
#[test]
fn a_full_disk_under_the_bake_cache_leaves_no_partial_file_and_serves() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full");
    std::fs::create_dir(&full).unwrap();
    let mounted = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=64k", "tmpfs"])
        .arg(&full)
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !mounted {
        eprintln!("skipped: cannot mount a tmpfs here");
        return;
    }
    struct Unmount<'a>(&'a std::path::Path);
    impl Drop for Unmount<'_> {
        fn drop(&mut self) {
            let _ = std::process::Command::new("umount").arg(self.0).status();
        }
    }
    let _unmount = Unmount(&full);
    let scene = dir.path().join("city.glb");
    std::fs::write(
        &scene,
        pvsd::scene::generate::city(&pvsd::scene::generate::CityOptions {
            buildings: 200,
            seed: 4,
            ..Default::default()
        })
        .to_glb(),
    )
    .unwrap();
    let (mut child, addr, log) = common::spawn_serve(
        &[
            "--scene",
            scene.to_str().unwrap(),
            "--bake-dir",
            full.to_str().unwrap(),
        ],
        &[],
    );
    let unsaved = log
        .iter()
        .filter(|l| l.contains("baked") && l.contains("No space left on device"))
        .count();
    assert!(
        unsaved > 0,
        "no bake said the disk is full:\n{}",
        log.join("\n")
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let r = reqwest::Client::new()
            .post(format!("http://{addr}/scenes/city/visible"))
            .body(r#"{"eye":[0,1.7,0],"forward":[1,0,0.2],"method":"occlusion_tree"}"#)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
    });
    child.kill().unwrap();
    child.wait().unwrap();
    // Whatever did fit is whole; nothing half-written is left.
    for entry in std::fs::read_dir(&full).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        assert!(!name.ends_with(".tmp"), "a partial file is left: {name}");
    }
}
