//! What each method's data costs in memory on one scene: live heap bytes
//! (counted by a wrapping allocator) after preparing the scene with
//! frustum culling alone, and with frustum culling and one more method;
//! then every method, and what stays once the scene is ranked and the
//! methods no client asked for are released, as `pvsd serve` does.
//!
//! ```sh
//! cargo run --example method_memory -- city10k.glb ../shared/scenes/Sponza/Sponza.gltf
//! ONLY_PER_METHOD=1 cargo run --example method_memory -- city10k.glb   # skip the ranking
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use pvsd::cull::{MethodContext, Registry, SceneMethods};

struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LIVE.fetch_add(layout.size(), Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LIVE.fetch_add(new_size, Ordering::Relaxed);
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn mib(bytes: usize) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

/// Live bytes held by `scene` prepared with `frustum` and `extra`.
fn prepared_bytes(scene: &Arc<pvsd::scene::Scene>, extra: Option<&str>) -> Option<usize> {
    let registry = Registry::standard();
    let context = MethodContext {
        disabled: registry
            .entries()
            .iter()
            .map(|e| e.name)
            .filter(|&n| n != "frustum" && Some(n) != extra)
            .map(String::from)
            .collect(),
        ..MethodContext::of_this_machine()
    };
    let before = LIVE.load(Ordering::Relaxed);
    let methods = SceneMethods::prepare_with(scene.clone(), &registry, &context);
    let held = LIVE.load(Ordering::Relaxed) - before;
    let supported = extra.is_none_or(|m| methods.names().contains(&m));
    drop(methods);
    supported.then_some(held)
}

fn main() {
    for path in std::env::args().skip(1) {
        let before = LIVE.load(Ordering::Relaxed);
        let scene = Arc::new(pvsd::scene::load_path(Path::new(&path)).expect("a scene"));
        let scene_bytes = LIVE.load(Ordering::Relaxed) - before;
        let base = prepared_bytes(&scene, None).unwrap_or(0);
        println!(
            "{path}: scene {:.1} MiB, frustum (kd-tree) {:.1} MiB",
            mib(scene_bytes),
            mib(base)
        );
        for entry in Registry::standard().entries() {
            if entry.name == "frustum" {
                continue;
            }
            match prepared_bytes(&scene, Some(entry.name)) {
                Some(bytes) => println!(
                    "  {:<18} +{:.1} MiB",
                    entry.name,
                    mib(bytes.saturating_sub(base))
                ),
                None => println!("  {:<18} unsupported", entry.name),
            }
        }
        if std::env::var_os("ONLY_PER_METHOD").is_some() {
            continue;
        }
        let before = LIVE.load(Ordering::Relaxed);
        let methods = SceneMethods::prepare_with(
            scene.clone(),
            &Registry::standard(),
            &MethodContext::of_this_machine(),
        );
        let all = LIVE.load(Ordering::Relaxed) - before;
        methods.set_ranking(pvsd::eval::rank(
            &methods,
            &pvsd::eval::RankParams::default(),
        ));
        let released = methods.release_unasked();
        let kept = LIVE.load(Ordering::Relaxed) - before;
        println!(
            "  every method {:.1} MiB; ranked (auto -> {}), {released:?} released: {:.1} MiB",
            mib(all),
            methods.auto_choice(methods.frame_cost()),
            mib(kept)
        );
    }
}
