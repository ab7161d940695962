//! The web viewer in a real browser: Debian's headless Chromium (WebGL2 in
//! software through SwiftShader), driven over WebDriver by chromedriver.
//!
//! - The page loads, connects, walks a scripted path and shows its panel's
//!   numbers, without a console error.
//! - **Same picture**: at scripted views of the office, the 1k city and
//!   Sponza, the canvas drawn from the visible set alone is pixel for pixel
//!   the canvas drawn with every object, for every conservative method each
//!   scene supports; an answer that drops a visible object fails it.
//! - Two tabs in one walkthrough see each other's avatars.
//!
//! Without chromium and chromedriver the tests say so and pass, unless
//! `PVSD_REQUIRE_BROWSER` is set (as `.ci/run` does, after installing them).

mod common;

use std::collections::BTreeSet;
use std::net::TcpListener;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::server::Server;
use fantoccini::{Client, ClientBuilder};
use pvsd::cull::Registry;
use pvsd::scene::Scene;
use pvsd::server::{AppState, Limits};
use serde_json::{Value, json};

/// chromedriver, and a browser session through it; both end on drop.
struct Browser {
    driver: Child,
    client: Option<Client>,
}

impl Browser {
    /// A headless Chromium of `width` × `height`, or `None` (with the
    /// reason printed) when this machine has none and none is required.
    async fn start(test: &str, width: u32, height: u32) -> Option<Browser> {
        let found = ["chromium", "chromedriver"]
            .iter()
            .all(|b| Command::new(b).arg("--version").output().is_ok());
        if !found {
            assert!(
                std::env::var_os("PVSD_REQUIRE_BROWSER").is_none(),
                "{test}: PVSD_REQUIRE_BROWSER is set, but chromium or chromedriver is missing"
            );
            eprintln!(
                "{test}: skipped, no chromium/chromedriver (`apt-get install chromium \
                 chromium-driver`; PVSD_REQUIRE_BROWSER=1 makes this a failure)"
            );
            return None;
        }
        let port = TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let driver = Command::new("chromedriver")
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        let caps: serde_json::Map<String, Value> = serde_json::from_value(json!({
            "browserName": "chrome",
            "timeouts": { "script": 300_000, "pageLoad": 60_000 },
            "goog:chromeOptions": {
                "binary": "/usr/bin/chromium",
                "args": [
                    "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader", "--disable-gpu-sandbox",
                    "--disable-dev-shm-usage", "--hide-scrollbars",
                    format!("--window-size={width},{height}"),
                ],
            },
        }))
        .unwrap();
        let url = format!("http://127.0.0.1:{port}");
        let deadline = Instant::now() + Duration::from_secs(30);
        let client = loop {
            let connector = hyper_util::client::legacy::connect::HttpConnector::new();
            match ClientBuilder::new(connector)
                .capabilities(caps.clone())
                .connect(&url)
                .await
            {
                Ok(c) => break c,
                Err(e) if Instant::now() < deadline => {
                    let _ = e;
                    tokio::time::sleep(Duration::from_millis(200)).await;
                }
                Err(e) => panic!("{test}: no browser session through chromedriver: {e}"),
            }
        };
        Some(Browser {
            driver,
            client: Some(client),
        })
    }

    fn client(&self) -> &Client {
        self.client.as_ref().unwrap()
    }

    /// Opens the viewer at `query` and waits until it has its first answer.
    async fn open(&self, server: &Server, query: &str) {
        self.client()
            .goto(&server.url(&format!("/viewer?test=1&{query}")))
            .await
            .unwrap();
        // The module may still be loading when the navigation returns.
        let ready = self
            .run(
                "for (let i = 0; i < 600 && !window.pvsd; i++) await new Promise(r => setTimeout(r, 50));
                 return await window.pvsd.ready;",
                json!([]),
            )
            .await;
        assert_eq!(
            ready,
            json!(true),
            "the page did not start: {}",
            self.errors().await
        );
    }

    /// Runs `body` as an async function in the page (`args` as `args`);
    /// its value, or a panic with the page's error.
    async fn run(&self, body: &str, args: Value) -> Value {
        let script = format!(
            "const done = arguments[arguments.length - 1]; const args = arguments[0];
             (async () => {{ {body} }})().then(v => done({{ ok: v === undefined ? null : v }}),
               e => done({{ err: String(e && e.stack || e) }}));"
        );
        let out = self
            .client()
            .execute_async(&script, vec![args])
            .await
            .unwrap_or_else(|e| panic!("the page's script failed: {e}"));
        match out.get("err") {
            Some(e) => panic!("in the page: {}", e.as_str().unwrap_or_default()),
            None => out["ok"].clone(),
        }
    }

    /// The page's uncaught errors and console errors.
    async fn errors(&self) -> Value {
        self.client()
            .execute(
                "return window.pvsd ? window.pvsd.errors : ['no pvsd'];",
                vec![],
            )
            .await
            .unwrap()
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if let Some(c) = self.client.take() {
            // Ends the browser; chromedriver goes with the kill below.
            let _ = futures_executor(c.close());
        }
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

/// Runs `f` to completion on a runtime of its own (a drop cannot await).
fn futures_executor<F: std::future::Future>(f: F) -> F::Output {
    tokio::task::block_in_place(|| {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
            .block_on(f)
    })
}

/// A server of `scenes` with the tests' bake folder.
async fn serve(scenes: Vec<Arc<Scene>>) -> Server {
    let state = AppState::with_methods(
        scenes,
        Limits::default(),
        &Registry::standard(),
        &common::test_context(),
    )
    .unwrap();
    Server::start(state).await
}

/// Scripted views of a scene: cameras of its walk, some looking up or down.
async fn scripted_views(browser: &Browser, count: usize) -> Vec<Value> {
    let walk = browser.run("return window.pvsd.walk();", json!([])).await;
    let views = walk["views"].as_array().expect("the scene has a walk");
    (0..count)
        .map(|i| {
            let v = &views[i * (views.len() - 1) / (count.max(2) - 1)];
            let f = &v["forward"];
            let pitch = [0.0, 0.25, -0.2, 0.5][i % 4];
            json!({
                "eye": v["eye"],
                "forward": [f[0].as_f64().unwrap(), pitch, f[2].as_f64().unwrap()],
            })
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_walks_and_shows_its_numbers() {
    let Some(browser) = Browser::start("the_page_walks", 800, 500).await else {
        return;
    };
    let server = serve(vec![common::city_scene(1000, 7, [0.0; 3])]).await;
    browser.open(&server, "scene=city&method=horizon").await;
    // The panel's numbers after a scripted walk of 40 frames.
    let hud = browser
        .run(
            "const views = window.pvsd.walk().views;
             let h;
             for (let i = 0; i < 40; i++) h = await window.pvsd.goTo(views[i * 10]);
             return h;",
            json!([]),
        )
        .await;
    let n = |k: &str| hud[k].as_f64().unwrap_or_else(|| panic!("{k} in {hud}"));
    assert!(n("frame") >= 40.0, "{hud}");
    assert!(n("pvs") > 0.0 && n("pvs") < 1001.0, "{hud}");
    assert_eq!(n("drawn"), n("pvs"), "draws the visible set: {hud}");
    assert!(n("held") >= n("pvs"), "{hud}");
    assert!(n("triangles") > 0.0 && n("bytesFetched") > 0.0, "{hud}");
    assert!(n("latencyMs") > 0.0 && n("cullUs") > 0.0, "{hud}");
    assert_eq!(hud["method"], "horizon");
    // What a person reads: the panel's cells are filled in.
    let cells = browser
        .client()
        .execute(
            "return [...document.querySelectorAll('#hud td')].map(td => td.textContent);",
            vec![],
        )
        .await
        .unwrap();
    let cells: Vec<String> = serde_json::from_value(cells).unwrap();
    assert!(cells[0].ends_with("of 1001"), "{cells:?}");
    assert!(cells[..6].iter().all(|c| c != "–"), "{cells:?}");
    // The method picker says what the method takes, from `GET /scenes`.
    let help = browser
        .client()
        .execute(
            "return document.getElementById('option-help').textContent;",
            vec![],
        )
        .await
        .unwrap();
    assert_eq!(help, json!("takes areas, min_area, columns"));
    if let Some(path) = std::env::var_os("PVSD_VIEWER_SCREENSHOT") {
        // The README's picture: the city from its street walk, with the
        // panel and the map.
        browser.client().set_window_size(1280, 900).await.unwrap();
        browser
            .run(
                "await new Promise(r => setTimeout(r, 300));
                 await window.pvsd.goTo(window.pvsd.walk().views[600]);",
                json!([]),
            )
            .await;
        std::fs::write(path, browser.client().screenshot().await.unwrap()).unwrap();
    }
    // The draw modes and the map run without error.
    browser
        .run(
            "await window.pvsd.draw('tinted'); await window.pvsd.draw('xray'); await window.pvsd.draw('visible');",
            json!([]),
        )
        .await;
    assert_eq!(browser.errors().await, json!([]));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn walking_back_is_free_the_budget_holds_and_a_lost_session_is_made_again() {
    let Some(browser) = Browser::start("walking_back", 640, 540).await else {
        return;
    };
    let server = serve(vec![common::city_scene(1000, 7, [0.0; 3])]).await;
    browser.open(&server, "scene=city&method=horizon").await;
    // There and back again: the way back is held, not fetched.
    let there = browser
        .run(
            "const w = window.pvsd.walk().views;
             for (let i = 0; i <= 300; i += 10) await window.pvsd.goTo(w[i]);
             const there = window.pvsd.hud();
             for (let i = 300; i >= 0; i -= 10) await window.pvsd.goTo(w[i]);
             return [there, window.pvsd.hud()];",
            json!([]),
        )
        .await;
    let (out, back) = (&there[0], &there[1]);
    assert!(out["bytesFetched"].as_u64().unwrap() > 0, "{out}");
    assert_eq!(out["bytesFetched"], back["bytesFetched"], "{out} {back}");

    // A small budget: what left the set goes, what is in it stays.
    browser
        .open(&server, "scene=city&method=horizon&budget=60000")
        .await;
    let trimmed = browser
        .run(
            "const w = window.pvsd.walk().views;
             let h, most = 0;
             for (let i = 0; i <= 600; i += 20) {
               h = await window.pvsd.goTo(w[i]);
               most = Math.max(most, h.heldBytes - 60000);
               if (h.held < h.pvs) throw new Error(`holds ${h.held} of a set of ${h.pvs}`);
             }
             return [h, most];",
            json!([]),
        )
        .await;
    let h = &trimmed[0];
    assert!(
        h["bytesFetched"].as_u64().unwrap() > 60_000,
        "the walk fetched more than it holds: {h}"
    );
    assert!(
        h["heldBytes"].as_u64().unwrap() < h["bytesFetched"].as_u64().unwrap(),
        "{h}"
    );

    // The server forgets the session: the page makes a new one and walks on.
    let sid = h["session"].as_str().unwrap().to_string();
    let gone = reqwest::Client::new()
        .delete(server.url(&format!("/sessions/{sid}")))
        .send()
        .await
        .unwrap();
    assert_eq!(gone.status(), 204);
    let after = browser
        .run(
            "const w = window.pvsd.walk().views;
             let h = window.pvsd.hud();
             for (let i = 0; i < 100 && h.reconnects === 0; i++) {
               await window.pvsd.goTo(w[700 + i]);
               h = window.pvsd.hud();
             }
             return await window.pvsd.goTo(w[800]);",
            json!([]),
        )
        .await;
    assert_eq!(after["reconnects"], 1, "{after}");
    assert_ne!(after["session"], sid, "{after}");
    assert!(after["pvs"].as_u64().unwrap() > 0, "{after}");
    assert_eq!(after["drawn"], after["pvs"], "{after}");
    assert_eq!(
        browser.errors().await,
        json!([]),
        "a lost session is no error"
    );
}

/// The bit of a pixel of the viewer's id pictures set for see-through triangles.
const SEE_THROUGH: u32 = 1 << 23;

/// How the browser's picture of every object (ids + 1 per pixel, bottom row
/// first, base64) compares with pvsd's ground truth of the view it sent, at
/// the pixels where the browser shows an opaque surface or nothing: the
/// share showing the same object, and the objects each shows that the
/// other does not show anywhere.
fn against_truth(scene: &Scene, r: &Value) -> Agreement {
    use base64::Engine as _;
    let v = &r["view"];
    let get = |k: &str| -> [f64; 3] { serde_json::from_value(v[k].clone()).unwrap() };
    let camera = pvsd::geom::Camera {
        eye: get("eye").into(),
        forward: get("forward").into(),
        up: get("up").into(),
        fov_y_deg: v["fov_y_deg"].as_f64().unwrap(),
        aspect: v["aspect"].as_f64().unwrap(),
        near: v["near"].as_f64().unwrap(),
        far: v["far"].as_f64().unwrap(),
        viewport: serde_json::from_value(v["viewport"].clone()).unwrap(),
    };
    let truth = pvsd::truth::Truth::render(scene, &camera).unwrap();
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(r["ids"].as_str().unwrap())
        .unwrap();
    let (w, h) = (truth.width(), truth.height());
    assert_eq!(
        bytes.len() as u32,
        w * h * 4,
        "the browser drew the viewport it sent"
    );
    let (mut same, mut browser_seen, mut truth_seen) = (0, BTreeSet::new(), BTreeSet::new());
    let (mut compared, mut edge) = (w * h, 0);
    for y in 0..h {
        for x in 0..w {
            let at = (((h - 1 - y) * w + x) * 4) as usize;
            let id = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
            if id & SEE_THROUGH != 0 {
                // Truth's winners are opaque; see-through pixels are set
                // beside nothing.
                compared -= 1;
                continue;
            }
            let browser = id.checked_sub(1).unwrap_or(pvsd::truth::NO_OBJECT);
            let winner = truth.winner_at(x, y);
            if browser == winner {
                same += 1;
            } else {
                // Where they differ: at an edge of truth's picture (a
                // neighbour shows another object), or inside a surface.
                let neighbours = [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)];
                edge += u32::from(neighbours.iter().any(|&(dx, dy)| {
                    let (nx, ny) = (i64::from(x) + dx, i64::from(y) + dy);
                    (0..i64::from(w)).contains(&nx)
                        && (0..i64::from(h)).contains(&ny)
                        && truth.winner_at(nx as u32, ny as u32) != winner
                }));
            }
            let truth = winner;
            browser_seen.insert(browser);
            truth_seen.insert(truth);
        }
    }
    let only = |a: &BTreeSet<u32>, b: &BTreeSet<u32>| {
        a.difference(b)
            .copied()
            .filter(|&i| i != pvsd::truth::NO_OBJECT)
            .collect::<Vec<u32>>()
    };
    Agreement {
        same: f64::from(same) / f64::from(compared),
        at_edges: f64::from(edge) / f64::from((compared - same).max(1)),
        browser_only: only(&browser_seen, &truth_seen),
        truth_only: only(&truth_seen, &browser_seen),
    }
}

/// A browser picture beside pvsd's truth ([`against_truth`]).
#[derive(Debug)]
struct Agreement {
    /// Share of the compared pixels showing the same object.
    same: f64,
    /// Share of the differing pixels on an edge of truth's picture.
    at_edges: f64,
    /// Objects the browser shows at some pixel and truth at none.
    browser_only: Vec<u32>,
    /// Objects truth shows at some pixel and the browser at none.
    truth_only: Vec<u32>,
}

/// Every conservative method of `scene` gives the same picture as every
/// object at `views` scripted views. The first method's pictures are also
/// set beside pvsd's ground truth: the browser must draw the very view the
/// server culled, or the check would prove nothing.
async fn assert_same_picture(browser: &Browser, server: &Server, scene: &Scene, views: usize) {
    let id = scene.id.as_str();
    browser
        .open(server, &format!("scene={id}&method=frustum"))
        .await;
    let info: Vec<Value> = reqwest::get(server.url("/scenes"))
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let methods: Vec<String> = info.iter().find(|s| s["id"] == id).unwrap()["methods"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap().to_string())
        .collect();
    let views = scripted_views(browser, views).await;
    for (k, method) in methods.iter().enumerate() {
        browser
            .run(
                "await window.pvsd.open(args[0], args[1]);",
                json!([id, method]),
            )
            .await;
        for (i, view) in views.iter().enumerate() {
            let mut r = browser
                .run(
                    "await window.pvsd.goTo(args[0]);
                     return await window.pvsd.samePicture({ picture: args[1] });",
                    json!([view, k == 0]),
                )
                .await;
            if k == 0 {
                let a = against_truth(scene, &r);
                eprintln!(
                    "{id} view {i}: the browser and pvsd's truth show the same object at \
                     {:.3}% of pixels, {:.0}% of the others on an edge of truth's picture; \
                     objects only the browser shows: {:?}, only truth: {:?}",
                    a.same * 100.0,
                    a.at_edges * 100.0,
                    a.browser_only,
                    a.truth_only
                );
                // A camera off by anything (aspect, an axis, the origin)
                // differs inside surfaces, not only at their edges.
                assert!(
                    a.same > 0.99 && (a.same == 1.0 || a.at_edges > 0.5),
                    "{id} view {i}: the browser drew another view: {a:?}"
                );
                r["ids"] = Value::Null;
            }
            eprintln!("{id} {method} view {i}: {r}");
            assert_eq!(
                r["differing"], 0,
                "{id}, {method}, view {i}: pixels show objects the answer dropped: {r}"
            );
            assert!(
                r["seen"].as_u64().unwrap() > 0,
                "{id} view {i} shows nothing: {r}"
            );
        }
    }
    assert_eq!(browser.errors().await, json!([]));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_conservative_method_draws_the_same_picture() {
    let Some(browser) = Browser::start("same_picture", 640, 540).await else {
        return;
    };
    let scenes = vec![
        common::office_scene(7, [0.0; 3]),
        common::city_scene(1000, 7, [0.0; 3]),
        common::shared_scene("Sponza"),
    ];
    let server = serve(scenes.clone()).await;
    for scene in &scenes {
        assert_same_picture(&browser, &server, scene, 4).await;
    }

    // The check can fail: an answer less the object covering the most
    // pixels, and a method that drops small objects on purpose.
    browser.open(&server, "scene=city&method=frustum").await;
    let views = scripted_views(&browser, 4).await;
    let dropped = browser
        .run(
            "await window.pvsd.goTo(args[0]); return await window.pvsd.samePicture({ drop: 1 });",
            json!([views[0]]),
        )
        .await;
    assert!(dropped["differing"].as_u64().unwrap() > 0, "{dropped}");
    assert_eq!(dropped["missing"].as_array().unwrap().len(), 1, "{dropped}");
    browser
        .run(
            "await window.pvsd.open('city', 'horizon', 'min_area=400');",
            json!([]),
        )
        .await;
    let mut differing = 0;
    for view in &views {
        let r = browser
            .run(
                "await window.pvsd.goTo(args[0]); return await window.pvsd.samePicture();",
                json!([view]),
            )
            .await;
        differing += r["differing"].as_u64().unwrap();
    }
    assert!(
        differing > 0,
        "horizon:min_area=400 drops small visible objects, and the pictures should show it"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_tabs_in_a_walkthrough_see_each_other() {
    let Some(browser) = Browser::start("two_tabs", 640, 540).await else {
        return;
    };
    let server = serve(vec![common::city_scene(1000, 7, [0.0; 3])]).await;
    browser.open(&server, "scene=city&method=horizon").await;
    let first = browser.client().window().await.unwrap();
    let wid = browser
        .run("return await window.pvsd.together();", json!([]))
        .await;
    let wid = wid.as_str().unwrap().to_string();
    // The second user stands in the street; the first 12 m ahead of it,
    // facing it.
    let views = scripted_views(&browser, 4).await;
    let at = &views[0];
    let f: Vec<f64> = serde_json::from_value(at["forward"].clone()).unwrap();
    let e: Vec<f64> = serde_json::from_value(at["eye"].clone()).unwrap();
    let ahead = json!({
        "eye": [e[0] + f[0] * 12.0, e[1], e[2] + f[2] * 12.0],
        "forward": [-f[0], 0.0, -f[2]],
    });
    let behind = json!({ "eye": e, "forward": [f[0], 0.0, f[2]] });
    browser
        .run("await window.pvsd.goTo(args[0]);", json!([ahead]))
        .await;
    let second = browser.client().new_window(true).await.unwrap();
    browser
        .client()
        .switch_to_window(second.handle)
        .await
        .unwrap();
    browser
        .open(&server, &format!("scene=city&walkthrough={wid}"))
        .await;
    let seen = browser
        .run(
            "let h = await window.pvsd.goTo(args[0]);
             for (let i = 0; i < 100 && h.avatars.length === 0; i++) {
               await new Promise(r => setTimeout(r, 50));
               h = window.pvsd.hud();
             }
             return h;",
            json!([behind]),
        )
        .await;
    assert_eq!(seen["usersVisible"].as_array().unwrap().len(), 1, "{seen}");
    assert_eq!(seen["avatars"], seen["usersVisible"], "{seen}");
    assert_eq!(browser.errors().await, json!([]));
    // Back in the first tab, facing the second user: it is seen too.
    browser.client().switch_to_window(first).await.unwrap();
    let h = browser
        .run("return await window.pvsd.goTo(args[0]);", json!([ahead]))
        .await;
    assert_eq!(h["usersVisible"].as_array().unwrap().len(), 1, "{h}");
    assert_eq!(browser.errors().await, json!([]));
}

/// The README's figure, in the browser: a 60-second street walk (30
/// frames a second at 10 m/s) of the scene file `PVSD_VIEWER_WALK_SCENE`
/// (e.g. `pvsd gen city --buildings 10000 --seed 7`), with
/// `PVSD_VIEWER_WALK_METHOD` (default `horizon`, `auto`'s choice there); prints
/// the geometry bytes the page fetched against the file and every mesh.
/// A measurement, not a check: `cargo test --release --test viewer --
/// --ignored --nocapture`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a measurement; needs PVSD_VIEWER_WALK_SCENE"]
async fn a_street_walk_fetches_a_small_share_of_the_scene() {
    let path = std::path::PathBuf::from(
        std::env::var_os("PVSD_VIEWER_WALK_SCENE").expect("PVSD_VIEWER_WALK_SCENE"),
    );
    let Some(browser) = Browser::start("street_walk", 640, 540).await else {
        return;
    };
    let scene = Arc::new(pvsd::scene::load_path(&path).unwrap());
    let id = scene.id.clone();
    let server = serve(vec![scene]).await;
    // What `auto` picks on the 10k city once `pvsd serve` has measured it
    // (this state is not ranked, so `auto` would answer with frustum).
    let method = std::env::var("PVSD_VIEWER_WALK_METHOD").unwrap_or_else(|_| "horizon".into());
    browser
        .open(&server, &format!("scene={id}&method={method}"))
        .await;
    let walk: Value = reqwest::get(server.url(&format!(
        "/scenes/{id}/walk?kind=street&frames=1800&step={}",
        10.0 / 30.0
    )))
    .await
    .unwrap()
    .json()
    .await
    .unwrap();
    // In runs of 100 frames, each within the script timeout.
    let mut hud = Value::Null;
    let started = Instant::now();
    for (i, run) in walk["views"].as_array().unwrap().chunks(100).enumerate() {
        hud = browser
            .run(
                "let h; for (const v of args) h = await window.pvsd.goTo(v); return h;",
                json!(run),
            )
            .await;
        eprintln!("{} frames in {:?}: {hud}", (i + 1) * 100, started.elapsed());
    }
    let objects: Vec<Value> = reqwest::get(server.url(&format!("/scenes/{id}/objects")))
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let ids: Vec<usize> = (0..objects.len()).collect();
    let mut whole = 0;
    for batch in ids.chunks(1024) {
        let res = reqwest::Client::new()
            .post(server.url(&format!("/scenes/{id}/meshes")))
            .json(&json!({ "ids": batch }))
            .send()
            .await
            .unwrap();
        whole += res.bytes().await.unwrap().len();
    }
    let file = std::fs::metadata(&path).unwrap().len() as f64;
    let fetched = hud["bytesFetched"].as_f64().unwrap();
    println!(
        "{id}: {} frames, method {}, PVS {} at the end; fetched {fetched} bytes = {:.2}% of the \
         file ({file} bytes), {:.2}% of every mesh ({whole} bytes)",
        hud["frame"],
        hud["method"],
        hud["pvs"],
        100.0 * fetched / file,
        100.0 * fetched / whole as f64
    );
    assert_eq!(browser.errors().await, json!([]));
}
