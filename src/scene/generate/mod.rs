//! Procedural scenes, written as real glTF 2.0 binary files (DESIGN "Scenes").
//!
//! Every generator is deterministic by its seed: it draws from a ChaCha
//! stream, whose output is fixed across platforms and `rand` releases, so the
//! same seed gives the same bytes everywhere.

mod cad;
mod city;
mod crowd;
mod mesh;
mod office;

pub use cad::{CadOptions, cad};
pub use city::{CityOptions, city};
pub use crowd::{CrowdOptions, crowd};
pub use mesh::MeshBuilder;
pub use office::{OfficeOptions, office};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}
