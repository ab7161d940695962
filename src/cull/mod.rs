//! Culling: the one trait every method implements, the registry of
//! methods, the dispatch that runs them, and the methods.
//!
//! Layout:
//! - [`view`]: a validated camera against one scene ([`View`]);
//! - [`visible_set`]: the answer ([`VisibleSet`]);
//! - [`method`]: the traits ([`CullMethod`], implemented by each method;
//!   [`Culler`], what callers see), execution modes, stats and errors;
//! - [`spec`]: naming a method and reading its options;
//! - [`registry`]: the list of methods and a scene prepared with those it
//!   supports ([`SceneMethods`]); [`ranking`]: the measured ranking `auto`
//!   answers from;
//! - [`dispatch`]: running a cull where its method runs, with the frustum
//!   fallback; [`device`]: the queue in front of a device's thread;
//! - [`occlusion`]: the vocabulary the object-space occlusion methods share
//!   (visibility classes, occluder selection, the kd hierarchy, tolerances);
//!   [`occluder`]: the scene's large planar occluders; [`depth`]: a
//!   conservative depth buffer at pixel centres (`raster`, `ddo`);
//! - one folder per method: [`frustum`], [`occlusion_tree`],
//!   [`supporting_planes`], [`horizon`], [`ddo`], [`gpu`], [`raster`]. A method imports from the shared
//!   modules, never from another method.
//!
//! **Invariant:** culling never mutates a scene; a conservative method never
//! drops an object whose box-and-triangles could show a pixel.

pub mod depth;
pub mod device;
pub mod dispatch;
pub mod method;
pub mod occluder;
pub mod occlusion;
pub mod pool;
pub mod ranking;
pub mod registry;
mod spec;
mod subtree;
pub mod view;
pub mod visible_set;

/// Declares each method's folder and lists its registry entry
/// (`<method>::ENTRY`), in DESIGN's order: a new method is its folder and
/// its name here ([`Registry::standard`] takes the list).
macro_rules! methods {
    ($($method:ident),* $(,)?) => {
        $(pub mod $method;)*

        /// The registry entries of the methods pvsd has, in DESIGN's order.
        const BUILT: &[MethodEntry] = &[$($method::ENTRY),*];
    };
}

methods!(
    frustum,
    occlusion_tree,
    supporting_planes,
    horizon,
    ddo,
    gpu,
    raster
);

pub use device::{DeviceLimits, DeviceQueue};
pub use dispatch::{Culled, Unanswered};
pub use method::{
    BatchItem, ClientCache, CullCounters, CullError, CullJob, CullMethod, CullStats, Culler,
    Execution, Fallback, InFrustum, Occludees,
};
pub use registry::{
    AUTO_CHOICE, CullOnceError, INLINE_BELOW_US, MethodContext, MethodEntry, Preparation, Registry,
    SceneMethods, Unsupported,
};
pub use spec::{METHOD_NAMES, MethodError, MethodOptions, MethodSpec, OptionReader, Ranged};
pub use view::View;
pub use visible_set::VisibleSet;
