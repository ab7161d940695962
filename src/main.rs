//! The `pvsd` binary: parses arguments and calls the library.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, bail};
use clap::{Args, Parser, Subcommand};
use glam::DVec3;
use indicatif::{ProgressBar, ProgressStyle};
use pvsd::cull::ddo::OctreeParams;
use pvsd::cull::ranking::{FrameCost, Ranking};
use pvsd::cull::{
    AUTO_CHOICE, MethodContext, MethodSpec, Registry, SceneMethods, View, VisibleSet,
};
use pvsd::eval::{EvalParams, RankParams, WalkParams, rank, rank_cached};
use pvsd::geom::{Camera, Region};
use pvsd::scene::generate::{
    CadOptions, CityOptions, CrowdOptions, OfficeOptions, cad, city, crowd, office,
};
use pvsd::scene::{BakeCache, Scene, load_path, load_slice};
use pvsd::server::config::{ServeConfig, check_replica_name};
use pvsd::server::{AppState, shutdown_signal};
use pvsd_proto::json::{Stats, VisibleResponse};

/// pvsd: a visibility server. It holds 3D scenes in memory and answers, for
/// a camera, which objects could be visible from it (a potentially visible set).
#[derive(Parser, Debug)]
#[command(version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Serve scenes over HTTP (GET /scenes, POST /scenes/{id}/visible, /metrics, ...).
    ///
    /// With no --scene and no scenes in --config, serves a generated city
    /// (1000 buildings, seed 1) under the id "city", so a new user gets
    /// answers at once. A scene that fails to load stops startup with a
    /// message naming the file. Stops gracefully on Ctrl+C or SIGTERM.
    Serve(ServeArgs),
    /// Generate a procedural scene as a glTF 2.0 binary (.glb) file.
    ///
    /// Deterministic: the same options and seed give the same bytes.
    #[command(subcommand)]
    Gen(GenCommand),
    /// Answer one view on the terminal: which objects could be visible.
    Query(QueryArgs),
    /// Measure each method's speed and accuracy over a walkthrough, against
    /// ground truth (every triangle rendered with its object id).
    ///
    /// Prints a table: cull time (median, p99), mean PVS, truth and
    /// in-frustum sizes, misses (truth-visible objects dropped; 0 for a
    /// conservative method), ties, overestimation, share of in-frustum objects
    /// culled, share of wrong pixels, and a modelled frame cost with the
    /// speedup over frustum culling.
    Eval(EvalArgs),
    /// List every method: what it is for, and, with --scene, whether that
    /// scene supports it or why not.
    Methods(MethodsArgs),
    /// Precompute what a scene's methods bake (occluder polygons, prisms)
    /// into the bake folder, so that the next serve or eval starts warm.
    ///
    /// Bakes already there and whole are read, not made again; the log says
    /// which, and why any was (re)built.
    Bake(BakeArgs),
}

#[derive(Args, Debug)]
struct BakeArgs {
    /// The .gltf or .glb scene.
    #[arg(long, value_name = "FILE")]
    scene: PathBuf,
    /// The bake folder [default: $XDG_CACHE_HOME/pvsd or ~/.cache/pvsd].
    #[arg(long, value_name = "DIR")]
    bake_dir: Option<PathBuf>,
    #[command(flatten)]
    octree: OctreeArgs,
}

/// How the methods that bake a scene cut it.
#[derive(Args, Debug)]
struct OctreeArgs {
    /// `ddo`'s octree splits a node holding more triangles than this (the
    /// paper's threshold, 16 to 1000000): fewer gives more occluders near
    /// the geometry for a longer bake and cull; each value is its own bake
    /// [default: the config's ddo_leaf_triangles, else 256].
    #[arg(long, value_name = "N", value_parser = leaf_triangles)]
    ddo_leaf_triangles: Option<OctreeParams>,
}

fn leaf_triangles(s: &str) -> Result<OctreeParams, String> {
    let n: usize = s.parse().map_err(|e| format!("{e}"))?;
    OctreeParams::with_leaf_triangles(n)
}

impl OctreeArgs {
    /// Sets what was given on `context`.
    fn apply(&self, context: &mut MethodContext) {
        if let Some(params) = self.ddo_leaf_triangles {
            context.ddo_octree = params;
        }
    }
}

#[derive(Args, Debug)]
struct MethodsArgs {
    /// A .gltf or .glb scene to check each method against.
    #[arg(long, value_name = "FILE")]
    scene: Option<PathBuf>,
}

#[derive(Args, Debug)]
struct EvalArgs {
    /// The .gltf or .glb scene.
    #[arg(long, value_name = "FILE")]
    scene: PathBuf,
    /// Where bakes (precomputed occluders) are kept between runs [default:
    /// $XDG_CACHE_HOME/pvsd or ~/.cache/pvsd].
    #[arg(long, value_name = "DIR")]
    bake_dir: Option<PathBuf>,
    /// Methods with their options, comma-separated: `frustum,occlusion_tree:k=32`.
    #[arg(long, value_delimiter = ',', required = true, value_name = "M1,M2,...")]
    methods: Vec<String>,
    /// The walkthrough: street, orbit, random, or views (unrelated random views: eyes uniform in the bounds, pitch within ±0.6 rad).
    #[arg(long, default_value = "street")]
    walk: pvsd::eval::WalkKind,
    /// Number of frames.
    #[arg(long, default_value_t = 100)]
    frames: usize,
    /// Seed of the walkthrough.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Width of the ground-truth image, pixels.
    #[arg(long, default_value_t = 1024)]
    width: u32,
    /// Height of the ground-truth image, pixels.
    #[arg(long, default_value_t = 768)]
    height: u32,
    /// Modelled cost of drawing one triangle, nanoseconds (frame cost model).
    #[arg(long, default_value_t = 2.0)]
    cost_per_triangle_ns: f64,
    /// Answers valid for every eye within this distance of each frame's
    /// eye: each answer is held to the truths of cameras sampled in the
    /// ball (and cone), and the PVS growth against point views is reported.
    #[arg(long, default_value_t = 0.0)]
    radius: f64,
    /// Answers valid for every direction within this many degrees of each
    /// frame's.
    #[arg(long, default_value_t = 0.0)]
    angle: f64,
    /// The speed of the walking client whose saved requests a region
    /// reports (scene units per second, at 30 frames a second).
    #[arg(long, default_value_t = 1.4)]
    walker_speed: f64,
    /// Write the report as JSON here.
    #[arg(long, value_name = "OUT.json")]
    json: Option<PathBuf>,
    /// Write a plot of the trade (cull time against PVS size) as SVG here.
    #[arg(long, value_name = "OUT.svg")]
    svg: Option<PathBuf>,
    #[command(flatten)]
    octree: OctreeArgs,
}

#[derive(Args, Debug)]
struct ServeArgs {
    /// A .gltf or .glb scene to serve (repeatable); its id is the file stem.
    #[arg(long = "scene", value_name = "FILE")]
    scenes: Vec<PathBuf>,
    /// A TOML file with addr, scenes, body_limit_bytes, request_timeout_ms.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Address to listen on [default: 127.0.0.1:8080].
    #[arg(long, value_name = "HOST:PORT")]
    addr: Option<SocketAddr>,
    /// Where bakes (precomputed occluders) are kept between runs [default:
    /// the config's bake_dir, else $XDG_CACHE_HOME/pvsd or ~/.cache/pvsd].
    #[arg(long, value_name = "DIR")]
    bake_dir: Option<PathBuf>,
    /// This replica's name, sent in every answer's x-pvsd-replica header
    /// (several replicas behind one load balancer) [default: the config's
    /// replica].
    #[arg(long, env = "PVSD_REPLICA", value_name = "NAME")]
    replica: Option<String>,
    #[command(flatten)]
    octree: OctreeArgs,
}

#[derive(Subcommand, Debug)]
enum GenCommand {
    /// A city after the urbania generator of Downs et al.: straight streets,
    /// small 120–180-triangle buildings with space between them, some tall
    /// ones, rotated 15° to the axes. 1000 buildings ≈ urban1k, 10000 ≈ urban10k.
    City {
        /// Seed of the random layout.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Number of buildings.
        #[arg(long, default_value_t = 1000)]
        buildings: u32,
        /// Translate the whole scene by x,y,z (for precision tests far from the origin).
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, value_name = "X,Y,Z")]
        offset: Option<DVec3>,
        /// Output file (.glb).
        #[arg(short, long, value_name = "FILE.glb")]
        output: PathBuf,
    },
    /// Office interiors after Bittner et al. and Coorg–Teller: storeys of
    /// rooms with walls and doors, and ~650-triangle plants spread at random.
    Office {
        /// Seed of the random layout.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Storeys.
        #[arg(long, default_value_t = 2)]
        floors: u32,
        /// Rooms along x per storey.
        #[arg(long, default_value_t = 6)]
        rooms_x: u32,
        /// Rooms along z per storey.
        #[arg(long, default_value_t = 4)]
        rooms_z: u32,
        /// Detail objects (plants) over all rooms.
        #[arg(long, default_value_t = 100)]
        details: u32,
        /// Translate the whole scene by x,y,z.
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, value_name = "X,Y,Z")]
        offset: Option<DVec3>,
        /// Output file (.glb).
        #[arg(short, long, value_name = "FILE.glb")]
        output: PathBuf,
    },
    /// A closed, finely tessellated body around many dense parts, with
    /// windows (~160k triangles by default, like Bernardini et al.'s car).
    Cad {
        /// Seed of the parts' sizes and places.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Cells along each edge of each face of the body (24 × cells² triangles).
        #[arg(long, default_value_t = 52)]
        cells: u32,
        /// Inner parts (~300 triangles each).
        #[arg(long, default_value_t = 400)]
        parts: u32,
        /// Translate the whole model by x,y,z.
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, value_name = "X,Y,Z")]
        offset: Option<DVec3>,
        /// Output file (.glb).
        #[arg(short, long, value_name = "FILE.glb")]
        output: PathBuf,
    },
    /// Many small objects between rows of walls on a ground, half of them
    /// movable (`extras.movable`: `PUT /scenes/{id}/objects/{oid}` moves
    /// them), after Tai & Hsu's dynamic scene.
    Crowd {
        /// Seed of the random layout.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Small objects; every other one is movable.
        #[arg(long, default_value_t = 2000)]
        objects: u32,
        /// Translate the whole scene by x,y,z.
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, value_name = "X,Y,Z")]
        offset: Option<DVec3>,
        /// Output file (.glb).
        #[arg(short, long, value_name = "FILE.glb")]
        output: PathBuf,
    },
}

#[derive(Args, Debug)]
struct QueryArgs {
    /// The .gltf or .glb scene.
    #[arg(long, value_name = "FILE")]
    scene: PathBuf,
    /// Eye position, world coordinates.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, value_name = "X,Y,Z")]
    eye: DVec3,
    /// Viewing direction.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, value_name = "X,Y,Z")]
    dir: DVec3,
    /// Up direction.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, value_name = "X,Y,Z", default_value = "0,1,0")]
    up: DVec3,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 60.0)]
    fov: f64,
    /// Width over height.
    #[arg(long, default_value_t = 1.6)]
    aspect: f64,
    /// Near plane distance.
    #[arg(long, default_value_t = 0.1)]
    near: f64,
    /// Far plane distance.
    #[arg(long, default_value_t = 10_000.0)]
    far: f64,
    /// Method and options, e.g. `frustum` or `occlusion_tree:k=32:variant=fme`.
    #[arg(long, default_value = "auto")]
    method: String,
    /// Print the answer as the HTTP API's JSON instead of a summary.
    #[arg(long)]
    json: bool,
}

fn parse_vec3(s: &str) -> Result<DVec3, String> {
    let parts: Vec<&str> = s.split(',').collect();
    let [x, y, z] = parts.as_slice() else {
        return Err(format!("expected three comma-separated numbers, got '{s}'"));
    };
    let num = |t: &str| {
        t.trim()
            .parse::<f64>()
            .map_err(|_| format!("'{t}' is not a number"))
    };
    Ok(DVec3::new(num(x)?, num(y)?, num(z)?))
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "info,tower_http=warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let result = match Cli::parse().command {
        Command::Serve(args) => serve(args),
        Command::Gen(cmd) => generate(cmd),
        Command::Query(args) => query(args),
        Command::Eval(args) => eval(args),
        Command::Methods(args) => methods(args),
        Command::Bake(args) => bake(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line with every cause, and no backtrace: this is for users.
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Loads a scene file behind a spinner (drawn only on a terminal).
fn load_scene(path: &Path) -> anyhow::Result<Arc<Scene>> {
    let bar = ProgressBar::new_spinner().with_message(format!("loading {}", path.display()));
    bar.enable_steady_tick(Duration::from_millis(100));
    let scene = load_path(path);
    bar.finish_and_clear();
    let scene = scene?;
    tracing::info!(
        scene = %scene.id, objects = scene.objects().len(), triangles = scene.triangle_count(),
        "loaded {}", path.display()
    );
    Ok(Arc::new(scene))
}

/// The built-in scene served when none is given.
fn default_city() -> anyhow::Result<Arc<Scene>> {
    let glb = city(&CityOptions::default()).to_glb();
    Ok(Arc::new(load_slice(
        "city",
        &glb,
        None,
        Path::new("<built-in city>"),
    )?))
}

fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(p) => ServeConfig::load(p)?,
        None => ServeConfig::default(),
    };
    let replica = args.replica.clone().or_else(|| config.replica.clone());
    if let Some(name) = &replica {
        check_replica_name(name).map_err(|e| anyhow::anyhow!("--replica: {e}"))?;
    }
    let paths: Vec<PathBuf> = config.scenes.iter().chain(&args.scenes).cloned().collect();
    let mut context = config
        .method_context()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    if let Some(dir) = &args.bake_dir {
        context.bake_dir = Some(dir.clone());
    }
    args.octree.apply(&mut context);
    if let Some(dir) = &context.bake_dir
        && let Err(e) = BakeCache::new(dir).check_writable()
    {
        tracing::warn!("the bake cache cannot be written ({e}): serving without caching bakes");
    }
    // The server listens at once and loads its scenes after: an
    // orchestrator sees it live (`/healthz/live`) while a big scene loads,
    // and ready (`/healthz/ready`) once every scene is in.
    let state =
        AppState::with_methods(Vec::new(), config.limits(), &Registry::standard(), &context)?
            .with_admin_token(config.admin_token.clone())
            .with_replica(replica)
            .with_scene_files(paths.clone());
    let rank = config.rank_methods.unwrap_or(true);
    state.readiness().loading(paths.len().max(1), rank);
    open_files_for(config.limits().connections.max_connections);
    let addr = args
        .addr
        .or(config.addr)
        .unwrap_or_else(|| "127.0.0.1:8080".parse().expect("literal address"));
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    let served = runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("cannot listen on {addr}"))?;
        let local = listener.local_addr()?;
        let scheme = match (&config.tls_cert, &config.tls_key) {
            (Some(_), Some(_)) => "https",
            _ => "http",
        };
        tracing::info!("listening on {scheme}://{local} (loading scenes; not ready yet)");
        let loading = {
            let state = state.clone();
            let bake_dir = context.bake_dir.clone();
            tokio::task::spawn_blocking(move || load_scenes(&state, &paths, rank, bake_dir))
        };
        // A scene that cannot be loaded stops the server, as it always has:
        // an operator (or an orchestrator's restart count) must see it.
        let failure = Arc::new(std::sync::Mutex::new(None));
        {
            let (stop, failure) = (state.lifecycle().shutdown.clone(), failure.clone());
            tokio::spawn(async move {
                let error = match loading.await {
                    Ok(Ok(())) => return,
                    Ok(Err(e)) => e,
                    Err(e) => anyhow::anyhow!("loading the scenes failed: {e}"),
                };
                *failure.lock().unwrap_or_else(|e| e.into_inner()) = Some(error);
                stop.cancel();
            });
        }
        tokio::spawn(pvsd::server::reload_on_sighup(state.clone()));
        let stopped = state.lifecycle().shutdown.clone();
        let shutdown = async move {
            tokio::select! {
                () = shutdown_signal() => {},
                () = stopped.cancelled() => {},
            }
        };
        match (&config.tls_cert, &config.tls_key) {
            (Some(cert), Some(key)) => {
                let tls = pvsd::server::tls::acceptor(cert, key)?;
                pvsd::server::run_tls(listener, state, tls, shutdown).await?;
            }
            _ => pvsd::server::run(listener, state, shutdown).await?,
        }
        match failure.lock().unwrap_or_else(|e| e.into_inner()).take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    });
    // Scenes still loading (told to stop while starting) are not waited
    // for: a bake is written to a temporary file and renamed, so one cut
    // short leaves nothing that loads.
    runtime.shutdown_background();
    served
}

/// Loads and prepares every scene file (the built-in city when there is
/// none), ranks their methods for `auto` when `rank`, and then says the
/// server is ready.
fn load_scenes(
    state: &AppState,
    paths: &[PathBuf],
    rank: bool,
    bake_dir: Option<PathBuf>,
) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    if paths.is_empty() {
        tracing::info!("no --scene given: serving a generated city as 'city'");
        state.add_scene(default_city()?)?;
        state.readiness().scene_loaded();
    }
    for path in paths {
        state.add_scene(load_scene(path)?)?;
        state.readiness().scene_loaded();
    }
    tracing::info!(
        ms = started.elapsed().as_millis() as u64,
        bake_dir = %bake_dir.as_deref().map_or("none".into(), |d| d.display().to_string()),
        "scenes prepared"
    );
    if rank {
        // Joined: ready means ranked, so every replica's `auto` answers
        // with the method its ranking picked from the first request on.
        let ranked = state
            .rank_in_background(RankParams::default(), bake_dir.as_ref().map(BakeCache::new))
            .join();
        if ranked.is_err() {
            tracing::error!("ranking the methods failed: auto answers with frustum culling");
        }
        state.readiness().ranking_over();
    }
    tracing::info!(
        ms = started.elapsed().as_millis() as u64,
        "ready: every scene is loaded"
    );
    Ok(())
}

/// Raises the soft limit on open files towards what `max_connections`
/// needs (each connection is a file, and the server keeps some of its
/// own), as nginx's `worker_rlimit_nofile` does; says so when the hard
/// limit is lower, since connections past it fail to be accepted.
fn open_files_for(max_connections: usize) {
    let wanted = max_connections as u64 + 256;
    match rlimit::increase_nofile_limit(wanted) {
        Ok(got) if got < wanted => tracing::warn!(
            open_files = got,
            max_connections,
            "the open-file limit is below max_connections: connections past it will wait to be accepted"
        ),
        Ok(_) => {}
        Err(e) => tracing::warn!("cannot raise the open-file limit: {e}"),
    }
}

fn generate(cmd: GenCommand) -> anyhow::Result<()> {
    let offset = |o: Option<DVec3>| o.map_or([0.0; 3], |v| v.as_vec3().to_array());
    let bar = ProgressBar::new_spinner().with_message("generating");
    bar.enable_steady_tick(Duration::from_millis(100));
    let (doc, output) = match cmd {
        GenCommand::City {
            seed,
            buildings,
            offset: o,
            output,
        } => {
            if buildings == 0 {
                bail!("--buildings must be at least 1");
            }
            (
                city(&CityOptions {
                    seed,
                    buildings,
                    offset: offset(o),
                    ..CityOptions::default()
                }),
                output,
            )
        }
        GenCommand::Office {
            seed,
            floors,
            rooms_x,
            rooms_z,
            details,
            offset: o,
            output,
        } => {
            if floors == 0 || rooms_x == 0 || rooms_z == 0 {
                bail!("--floors, --rooms-x and --rooms-z must be at least 1");
            }
            (
                office(&OfficeOptions {
                    seed,
                    floors,
                    rooms_x,
                    rooms_z,
                    details,
                    offset: offset(o),
                }),
                output,
            )
        }
        GenCommand::Cad {
            seed,
            cells,
            parts,
            offset: o,
            output,
        } => {
            if cells < 2 {
                bail!("--cells must be at least 2");
            }
            (
                cad(&CadOptions {
                    seed,
                    cells,
                    parts,
                    offset: offset(o),
                }),
                output,
            )
        }
        GenCommand::Crowd {
            seed,
            objects,
            offset: o,
            output,
        } => (
            crowd(&CrowdOptions {
                seed,
                objects,
                offset: offset(o),
            }),
            output,
        ),
    };
    let bytes = doc.to_glb();
    bar.finish_and_clear();
    std::fs::write(&output, &bytes)
        .with_context(|| format!("cannot write {}", output.display()))?;
    let triangles: usize = doc.meshes.iter().map(|m| m.indices.len() / 3).sum();
    eprintln!(
        "wrote {}: {} objects, {} triangles, {} bytes",
        output.display(),
        doc.meshes.len(),
        triangles,
        bytes.len()
    );
    Ok(())
}

/// A method spec whose name the registry knows, checked before any scene
/// is loaded.
fn known_spec(text: &str) -> anyhow::Result<MethodSpec> {
    let spec: MethodSpec = text.parse()?;
    if spec.name != "auto" && !Registry::standard().knows(&spec.name) {
        return Err(pvsd::cull::MethodError::Unknown { name: spec.name }.into());
    }
    Ok(spec)
}

fn query(args: QueryArgs) -> anyhow::Result<()> {
    let spec = known_spec(&args.method)?;
    let scene = load_scene(&args.scene)?;
    let camera = Camera {
        eye: args.eye,
        forward: args.dir,
        up: args.up,
        fov_y_deg: args.fov,
        aspect: args.aspect,
        near: args.near,
        far: args.far,
        ..Camera::default()
    };
    let methods = SceneMethods::prepare(scene);
    let view = View::new(camera, methods.scene())?;
    let mut out = VisibleSet::new();
    let stats = methods.cull_once(&spec, &view, &mut out)?;
    if args.json {
        let body = VisibleResponse {
            visible: out.ids().to_vec(),
            areas: out.areas(),
            stats: Stats::from(stats),
        };
        println!("{}", serde_json::to_string(&body)?);
    } else {
        println!(
            "{}: {} of {} objects possibly visible ({} in frustum, {} nodes tested, {:.1} µs)",
            stats.method,
            stats.visible,
            methods.scene().objects().len(),
            stats
                .in_frustum
                .map_or("uncounted".to_string(), |n| n.to_string()),
            stats.nodes_tested,
            stats.cull_us
        );
        let names: Vec<String> = out
            .ids()
            .iter()
            .map(|&id| format!("{id} {}", methods.scene().objects()[id as usize].name))
            .collect();
        println!("{}", names.join("\n"));
    }
    Ok(())
}

fn bake(args: BakeArgs) -> anyhow::Result<()> {
    let dir = args
        .bake_dir
        .or_else(BakeCache::default_dir)
        .context("no bake folder: give --bake-dir (neither XDG_CACHE_HOME nor HOME is set)")?;
    let scene = load_scene(&args.scene)?;
    let mut context = MethodContext {
        bake_dir: Some(dir.clone()),
        ..MethodContext::of_this_machine()
    };
    args.octree.apply(&mut context);
    let started = std::time::Instant::now();
    let methods = SceneMethods::prepare_with(scene, &Registry::standard(), &context);
    println!(
        "{}: prepared in {} ms with the bakes in {} (methods: {})",
        methods.scene().id,
        started.elapsed().as_millis(),
        dir.display(),
        methods.names().join(", ")
    );
    let started = std::time::Instant::now();
    let ranking = rank_cached(
        &methods,
        &RankParams::default(),
        Some(&BakeCache::new(&dir)),
    );
    println!(
        "{}: methods ranked for auto in {} ms",
        methods.scene().id,
        started.elapsed().as_millis()
    );
    print_ranking(&ranking, methods.frame_cost());
    Ok(())
}

fn methods(args: MethodsArgs) -> anyhow::Result<()> {
    let registry = Registry::standard();
    let prepared = match &args.scene {
        Some(path) => Some(SceneMethods::prepare(load_scene(path)?)),
        None => None,
    };
    for entry in registry.entries() {
        println!("{:<18} {}", entry.name, entry.purpose);
        if let Some(m) = &prepared {
            let id = &m.scene().id;
            match m.unsupported().iter().find(|u| u.method == entry.name) {
                None => println!("{:<18} supported by {id}", ""),
                Some(u) => println!("{:<18} not supported by {id}: {}", "", u.reason),
            }
        }
    }
    println!(
        "{:<18} the cheapest method measured on the scene's sample views (cull time + PVS triangles × cost_per_triangle_ns + bytes × cost_per_byte_ns); {AUTO_CHOICE} until measured",
        "auto"
    );
    if let Some(m) = &prepared {
        print_ranking(&rank(m, &RankParams::default()), m.frame_cost());
    }
    Ok(())
}

/// A ranking as a table, cheapest first at `cost`.
fn print_ranking(ranking: &Ranking, cost: FrameCost) {
    println!(
        "auto on {} sample views ({}), at {} ns a triangle and {} ns a byte:",
        ranking.frames,
        ranking.walks.join(", "),
        cost.per_triangle_ns,
        cost.per_byte_ns
    );
    println!(
        "  {:<18} {:>12} {:>12} {:>10} {:>14} {:>14}",
        "method", "mean cull µs", "median µs", "mean PVS", "PVS triangles", "frame cost µs"
    );
    for (m, frame_cost) in ranking.ranked(cost) {
        println!(
            "  {:<18} {:>12.1} {:>12.1} {:>10.1} {:>14.0} {:>14.1}",
            m.method,
            m.mean_cull_us,
            m.median_cull_us,
            m.mean_pvs,
            m.mean_pvs_triangles,
            frame_cost
        );
    }
}

fn eval(args: EvalArgs) -> anyhow::Result<()> {
    if args.frames == 0 || args.width == 0 || args.height == 0 {
        bail!("--frames, --width and --height must be at least 1");
    }
    let specs = args
        .methods
        .iter()
        .map(|m| known_spec(m))
        .collect::<anyhow::Result<Vec<MethodSpec>>>()?;
    let mut context = MethodContext {
        bake_dir: args.bake_dir.clone().or_else(BakeCache::default_dir),
        frame_cost: FrameCost {
            per_triangle_ns: args.cost_per_triangle_ns,
            ..FrameCost::default()
        },
        ..MethodContext::of_this_machine()
    };
    args.octree.apply(&mut context);
    let methods =
        SceneMethods::prepare_with(load_scene(&args.scene)?, &Registry::standard(), &context);
    if specs.iter().any(|s| s.name == "auto") {
        // `auto` answers from the scene's ranking: measure it (or read it
        // from the bake cache) as a server would.
        let cache = context.bake_dir.as_ref().map(BakeCache::new);
        methods.set_ranking(rank_cached(
            &methods,
            &RankParams::default(),
            cache.as_ref(),
        ));
    }
    let params = EvalParams {
        walk: WalkParams {
            kind: args.walk,
            frames: args.frames,
            seed: args.seed,
            viewport: [args.width, args.height],
            ..WalkParams::default()
        },
        cost_per_triangle_ns: args.cost_per_triangle_ns,
        region: Region::new(args.radius, args.angle)
            .map_err(|e| anyhow::anyhow!("--{} {}", e.field, e.problem))?,
        walker_speed: args.walker_speed,
    };
    let bar = ProgressBar::new(args.frames as u64).with_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} frames, {eta} left")
            .expect("a valid template")
            .progress_chars("=> "),
    );
    bar.set_message(format!("evaluating {}", methods.scene().id));
    let report = pvsd::eval::evaluate(&methods, &specs, &params, |n| bar.set_position(n as u64));
    bar.finish_and_clear();
    let report = report?;
    print!("{report}");
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(path) = &args.svg {
        pvsd::eval::write_svg(&report, path).map_err(anyhow::Error::msg)?;
    }
    Ok(())
}
