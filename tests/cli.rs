//! The `pvsd` binary end to end: help, gen, query, and serve on a real
//! socket stopped by SIGTERM.

mod common;

use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use common::{fetch, shared_scene_path};
use serde_json::Value;

fn pvsd() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_pvsd"));
    c.env_remove("RUST_BACKTRACE").env("RUST_LOG", "info");
    c
}

fn run(args: &[&str]) -> (bool, String, String) {
    let out = pvsd().args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

#[test]
fn every_command_explains_itself() {
    for args in [
        &["--help"][..],
        &["serve", "--help"],
        &["gen", "--help"],
        &["gen", "city", "--help"],
        &["query", "--help"],
        &["methods", "--help"],
    ] {
        let (ok, out, _) = run(args);
        assert!(ok, "{args:?}");
        assert!(out.contains("Usage"), "{args:?}: {out}");
    }
    let (_, out, _) = run(&["serve", "--help"]);
    assert!(
        out.contains("generated city") && out.contains("--scene"),
        "{out}"
    );
}

#[test]
fn gen_then_query() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("town.glb");
    let f = file.to_str().unwrap();
    let (ok, _, err) = run(&["gen", "city", "--buildings", "120", "--seed", "4", "-o", f]);
    assert!(ok, "{err}");
    assert!(err.contains("121 objects"), "{err}");
    let (ok, out, err) = run(&[
        "query",
        "--scene",
        f,
        "--eye",
        "-20,1.7,-20",
        "--dir",
        "1,0,1",
        "--method",
        "frustum",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert!(!v["visible"].as_array().unwrap().is_empty());
    assert_eq!(v["stats"]["method"], "frustum");

    let (ok, out, _) = run(&[
        "query",
        "--scene",
        f,
        "--eye",
        "-20,1.7,-20",
        "--dir",
        "1,0,1",
    ]);
    assert!(ok);
    assert!(out.starts_with("frustum: "), "{out}");
    assert!(out.contains("building_"), "{out}");

    let office = dir.path().join("office.glb");
    let (ok, _, err) = run(&[
        "gen",
        "office",
        "--details",
        "10",
        "-o",
        office.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
}

#[test]
fn methods_lists_the_registry_and_what_a_scene_supports() {
    let (ok, out, err) = run(&["methods"]);
    assert!(ok, "{err}");
    for name in pvsd::cull::METHOD_NAMES {
        assert!(out.lines().any(|l| l.starts_with(name)), "{name}: {out}");
    }
    let saw = shared_scene_path("2CylinderEngine");
    let (ok, out, err) = run(&["methods", "--scene", saw.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(out.contains("supported by 2CylinderEngine"), "{out}");
    assert!(out.contains("not supported by 2CylinderEngine: "), "{out}");
}

#[test]
fn cli_errors_are_one_clear_line() {
    let scene = shared_scene_path("Sponza");
    let s = scene.to_str().unwrap();
    let cases: [(&[&str], &str); 7] = [
        (
            &["query", "--scene", s, "--eye", "0,nan,0", "--dir", "1,0,0"],
            "error: eye[1] is NaN",
        ),
        // An unknown method is refused before any scene is read.
        (
            &[
                "query",
                "--scene",
                "/nonexistent/x.glb",
                "--eye",
                "0,1,0",
                "--dir",
                "1,0,0",
                "--method",
                "octree",
            ],
            "error: unknown method 'octree'",
        ),
        (
            &[
                "eval",
                "--scene",
                "/nonexistent/x.glb",
                "--methods",
                "frustum,octree",
            ],
            "error: unknown method 'octree'",
        ),
        (
            &["query", "--scene", s, "--eye", "0,1,0", "--dir", "0,0,0"],
            "error: forward is a zero vector",
        ),
        (
            &[
                "query", "--scene", s, "--eye", "0,1,0", "--dir", "1,0,0", "--method", "horizon",
            ],
            "not supported by scene 'Sponza'",
        ),
        (
            &[
                "query",
                "--scene",
                "/nonexistent/x.glb",
                "--eye",
                "0,1,0",
                "--dir",
                "1,0,0",
            ],
            "/nonexistent/x.glb: cannot read file",
        ),
        (
            &["query", "--scene", s, "--eye", "0,1", "--dir", "1,0,0"],
            "expected three comma-separated numbers",
        ),
    ];
    for (args, want) in cases {
        let (ok, _, err) = run(args);
        assert!(!ok, "{args:?}");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(!err.contains("backtrace"), "{err}");
    }
}

#[test]
fn serve_refuses_a_broken_scene_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("broken.glb");
    std::fs::write(&bad, b"glTF garbage").unwrap();
    let (ok, _, err) = run(&[
        "serve",
        "--scene",
        bad.to_str().unwrap(),
        "--addr",
        "127.0.0.1:0",
    ]);
    assert!(!ok);
    assert!(err.contains("broken.glb"), "{err}");
}

#[test]
fn serve_answers_and_stops_on_sigterm() {
    let (mut child, addr, _) = common::spawn_serve(&[], &[]);
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let c = reqwest::Client::new();
        let scenes: Value = fetch(c.get(format!("http://{addr}/scenes"))).await;
        assert_eq!(scenes[0]["id"], "city", "the built-in city");
        let v: Value = fetch(
            c.post(format!("http://{addr}/scenes/city/visible"))
                .body(r#"{"eye":[60,1.7,-20],"forward":[1,0,0.3]}"#),
        )
        .await;
        assert!(!v["visible"].as_array().unwrap().is_empty(), "{v}");
    });
    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        if let Some(code) = child.try_wait().unwrap() {
            assert!(code.success(), "graceful exit, got {code}");
            break;
        }
        assert!(Instant::now() < deadline, "did not stop on SIGTERM");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A second server start reads the occluders the first one baked; a
/// damaged bake is rebuilt, with the reason logged.
#[test]
fn serve_bakes_occluders_once_and_rebuilds_a_damaged_bake() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("office.glb");
    let (ok, _, err) = run(&[
        "gen",
        "office",
        "--seed",
        "3",
        "-o",
        scene.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let bakes = dir.path().join("bakes");
    let start = || {
        let (mut child, _, log) = common::spawn_serve(
            &[
                "--scene",
                scene.to_str().unwrap(),
                "--bake-dir",
                bakes.to_str().unwrap(),
            ],
            &[],
        );
        let _ = child.kill();
        let _ = child.wait();
        log.join("\n")
    };
    let first = start();
    assert!(
        first.contains("baked") && first.contains("none yet"),
        "{first}"
    );
    let second = start();
    assert!(second.contains("loaded a bake"), "{second}");
    // One flipped byte: refused by its checksum and baked again.
    let file = std::fs::read_dir(&bakes)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let mut bytes = std::fs::read(&file).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    std::fs::write(&file, bytes).unwrap();
    let third = start();
    assert!(third.contains("checksum"), "{third}");
    assert!(start().contains("loaded a bake"));
}

/// A generated city of `buildings` in a scratch folder, and the arguments
/// of `pvsd bake` for it with a bake folder beside it.
fn city_to_bake(buildings: &str) -> (tempfile::TempDir, Vec<String>) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("city.glb").to_string_lossy().into_owned();
    let (ok, _, err) = run(&["gen", "city", "--buildings", buildings, "-o", &scene]);
    assert!(ok, "{err}");
    let bakes = dir.path().join("bakes").to_string_lossy().into_owned();
    let args = ["bake", "--scene", &scene, "--bake-dir", &bakes].map(String::from);
    (dir, args.to_vec())
}

/// `pvsd bake` makes the bakes a serve would, and finds them the next time.
#[test]
fn bake_makes_the_bakes_and_reuses_them() {
    let (dir, args) = city_to_bake("50");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let bakes = dir.path().join("bakes");
    let (ok, out, err) = run(&args);
    assert!(ok && out.contains("prepared in"), "{out}{err}");
    assert_eq!(
        err.matches("baked").count(),
        3,
        "occluders, prisms and auto's ranking: {err}"
    );
    assert_eq!(std::fs::read_dir(&bakes).unwrap().count(), 3);
    let (ok, _, err) = run(&args);
    assert!(ok);
    assert_eq!(err.matches("loaded a bake").count(), 3, "{err}");
}

/// Every file in the bake folder `dir` is a bake: no temporary file left.
fn assert_only_whole_bakes(dir: &std::path::Path) {
    let names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| n.ends_with(".bake")),
        "leftovers: {names:?}"
    );
}

/// Two bakers at once on one folder (two servers starting together): both
/// finish, and what they leave loads.
#[test]
fn two_bakers_at_once_leave_whole_bakes() {
    let (dir, args) = city_to_bake("300");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let bakes = dir.path().join("bakes");
    let children: Vec<_> = (0..2)
        .map(|_| {
            pvsd()
                .args(&args)
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null())
                .spawn()
                .unwrap()
        })
        .collect();
    for mut c in children {
        assert!(c.wait().unwrap().success());
    }
    let (ok, _, err) = run(&args);
    assert!(ok);
    assert_eq!(err.matches("loaded a bake").count(), 3, "{err}");
    assert_only_whole_bakes(&bakes);
}

/// A bake killed at any moment (SIGKILL) leaves nothing that loads wrong:
/// the next run either reads a whole bake or makes it again.
#[test]
fn a_killed_bake_leaves_nothing_that_loads_wrong() {
    let (dir, args) = city_to_bake("1500");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let bakes = dir.path().join("bakes");
    for wait_ms in [30, 120, 250, 400, 600] {
        let _ = std::fs::remove_dir_all(&bakes);
        let mut child = pvsd()
            .args(&args)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(wait_ms));
        let _ = child.kill();
        let _ = child.wait();
        let (ok, _, err) = run(&args);
        assert!(ok, "after a kill at {wait_ms} ms: {err}");
        let loaded = err.matches("loaded a bake").count();
        let baked = err.matches("none yet").count();
        assert_eq!(
            loaded + baked,
            3,
            "at {wait_ms} ms, every bake loads or is made: {err}"
        );
        assert!(
            !err.contains("checksum") && !err.contains("truncated"),
            "{err}"
        );
        // And the run after loads all three.
        let (_, _, err) = run(&args);
        assert_eq!(err.matches("loaded a bake").count(), 3, "{err}");
    }
}

/// A small CAD body written by `pvsd gen cad` into a fresh folder, with a
/// bake folder beside it: (folder, scene, bake folder).
fn small_cad() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("cad.glb");
    let (ok, _, err) = run(&[
        "gen",
        "cad",
        "--cells",
        "12",
        "--parts",
        "20",
        "-o",
        &scene.to_string_lossy(),
    ]);
    assert!(ok, "{err}");
    let bakes = dir.path().join("bakes");
    (dir, scene, bakes)
}

/// `--ddo-leaf-triangles` cuts a finer octree (more nodes) into a bake of
/// its own beside the default one, loaded again the next time; a size
/// below the range is refused naming the flag.
#[test]
fn ddo_leaf_triangles_cuts_a_finer_octree_into_its_own_bake() {
    let (_dir, scene, bakes) = small_cad();
    let scene_arg = scene.to_string_lossy().into_owned();
    let bakes_arg = bakes.to_string_lossy().into_owned();
    let bake = |extra: &[&str]| {
        let mut args = vec!["bake", "--scene", &scene_arg, "--bake-dir", &bakes_arg];
        args.extend_from_slice(extra);
        let (ok, _, err) = run(&args);
        assert!(ok, "{err}");
        err
    };
    // The nodes of the ddo octree the log says were baked.
    let nodes = |log: &str| -> usize {
        let line = log
            .lines()
            .find(|l| l.contains("baked directional discretized occluders"))
            .unwrap_or_else(|| panic!("a ddo bake: {log}"));
        // Without the log's colours (`ESC [ … m`).
        let mut plain = String::new();
        let mut chars = line.chars();
        while let Some(c) = chars.next() {
            if c == '\u{1b}' {
                chars.by_ref().find(|&c| c == 'm');
            } else {
                plain.push(c);
            }
        }
        let at = plain.find("nodes=").expect("a node count") + "nodes=".len();
        plain[at..]
            .chars()
            .take_while(char::is_ascii_digit)
            .collect::<String>()
            .parse()
            .unwrap()
    };
    let coarse = nodes(&bake(&[]));
    let fine = nodes(&bake(&["--ddo-leaf-triangles", "16"]));
    assert!(
        fine > coarse,
        "16 triangles a leaf: {fine} nodes, 256: {coarse}"
    );
    // Each cut is its own bake, and both stay.
    let ddo_bakes = std::fs::read_dir(&bakes)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .to_string_lossy()
                .contains("-ddo-")
        })
        .count();
    assert_eq!(ddo_bakes, 2);
    assert!(bake(&["--ddo-leaf-triangles", "16"]).contains("loaded a bake"));
    let (ok, _, err) = run(&["bake", "--scene", &scene_arg, "--ddo-leaf-triangles", "8"]);
    assert!(
        !ok && err.contains("--ddo-leaf-triangles") && err.contains("16 to 1000000"),
        "{err}"
    );
}

/// The ddo bake through `pvsd bake` on a small CAD body: made once and
/// loaded after; a flipped byte is refused by its checksum and the bake
/// made again; a scene file changed by one byte gets a bake of its own;
/// two bakers at once and a baker killed mid-way leave only whole bakes.
#[test]
fn ddo_bakes_are_whole_checked_and_named_by_the_scene() {
    let (_dir, scene, bakes) = small_cad();
    let scene_arg = scene.to_string_lossy().into_owned();
    let bakes_arg = bakes.to_string_lossy().into_owned();
    let args = ["bake", "--scene", &scene_arg, "--bake-dir", &bakes_arg];
    // Whether the log has a line about the ddo bake saying `what`.
    let ddo_says = |log: &str, what: &str| {
        log.lines()
            .any(|l| l.contains("\"ddo\"") && l.contains(what))
    };
    let (ok, out, err) = run(&args);
    assert!(
        ok && out.contains("ddo"),
        "ddo is among the methods: {out}{err}"
    );
    assert!(ddo_says(&err, "none yet"), "{err}");
    let (_, _, err) = run(&args);
    assert!(ddo_says(&err, "loaded a bake"), "{err}");

    // One flipped byte in the ddo bake.
    let ddo_file = || {
        std::fs::read_dir(&bakes)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.to_string_lossy().contains("-ddo-"))
            .expect("a ddo bake")
    };
    let file = ddo_file();
    let mut bytes = std::fs::read(&file).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x10;
    std::fs::write(&file, bytes).unwrap();
    let (ok, _, err) = run(&args);
    assert!(ok);
    assert!(ddo_says(&err, "checksum"), "{err}");
    let (_, _, err) = run(&args);
    assert!(ddo_says(&err, "loaded a bake"), "{err}");

    // The scene changed by one byte (a name's last letter): a new bake.
    let mut glb = std::fs::read(&scene).unwrap();
    let at = glb
        .windows(9)
        .position(|w| w == b"part_0001")
        .expect("a part's name");
    glb[at + 8] = b'9';
    std::fs::write(&scene, glb).unwrap();
    let (ok, _, err) = run(&args);
    assert!(ok, "{err}");
    assert!(ddo_says(&err, "none yet"), "{err}");

    // Two bakers at once, then one killed early: every bake whole.
    std::fs::remove_dir_all(&bakes).unwrap();
    let spawn = || {
        pvsd()
            .args(args)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap()
    };
    let two = [spawn(), spawn()];
    for mut c in two {
        assert!(c.wait().unwrap().success());
    }
    assert_only_whole_bakes(&bakes);
    // A baker killed mid-way may leave its temporary file, never a bake
    // that loads wrong: the next run loads a whole one or makes it.
    std::fs::remove_dir_all(&bakes).unwrap();
    let mut killed = spawn();
    std::thread::sleep(Duration::from_millis(400));
    let _ = killed.kill();
    let _ = killed.wait();
    let (ok, _, err) = run(&args);
    assert!(ok, "{err}");
    assert!(
        ddo_says(&err, "loaded a bake") || ddo_says(&err, "none yet"),
        "{err}"
    );
    assert!(
        !err.contains("checksum") && !err.contains("truncated"),
        "{err}"
    );
}
