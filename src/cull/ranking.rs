//! What `auto` answers with: each conservative method of a scene measured
//! on sample views of that scene, ranked by modelled frame cost.
//!
//! The cost of a frame to the user (after Bittner et al.'s Table 2
//! "speedup") is the time to cull plus the time to draw and to send what
//! was not culled: `mean cull µs + PVS triangles × cost_per_triangle_ns +
//! PVS bytes × cost_per_byte_ns`. Which method is cheapest depends on those
//! two prices (a GPU that draws fast wants the quickest cull; a thin client
//! behind a slow link wants the smallest set), so a [`Ranking`] keeps the
//! measured figures and ranks them for the prices a request names.
//! `eval::rank` measures; this module only holds and orders the result.

use serde::{Deserialize, Serialize};

use super::{MethodError, MethodOptions, Ranged};

/// Modelled cost of drawing one triangle, nanoseconds (`cost_per_triangle_ns`).
pub const COST_PER_TRIANGLE_NS: Ranged<f64> = Ranged {
    key: "cost_per_triangle_ns",
    noun: "a number of nanoseconds",
    // ~2 ns a triangle: a mid-range GPU's throughput for small meshes.
    default: 2.0,
    min: 0.0,
    max: 1e9,
};

/// Modelled cost of sending one byte of geometry, nanoseconds
/// (`cost_per_byte_ns`; 0: clients hold the scene already).
pub const COST_PER_BYTE_NS: Ranged<f64> = Ranged {
    key: "cost_per_byte_ns",
    noun: "a number of nanoseconds",
    default: 0.0,
    min: 0.0,
    max: 1e9,
};

/// Bytes of geometry a thin client receives per triangle: three
/// world-space `f32` positions.
pub const BYTES_PER_TRIANGLE: f64 = 36.0;

/// The prices a frame's cost is modelled with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameCost {
    /// Nanoseconds to draw a triangle.
    pub per_triangle_ns: f64,
    /// Nanoseconds to send a byte of geometry.
    pub per_byte_ns: f64,
}

impl Default for FrameCost {
    fn default() -> Self {
        FrameCost {
            per_triangle_ns: COST_PER_TRIANGLE_NS.default,
            per_byte_ns: COST_PER_BYTE_NS.default,
        }
    }
}

impl FrameCost {
    /// The option keys `auto` takes.
    pub const KEYS: [&'static str; 2] = [COST_PER_TRIANGLE_NS.key, COST_PER_BYTE_NS.key];

    /// The prices `auto`'s options name, each absent one taken from `base`
    /// (the server's configuration); any other option is refused.
    pub fn read(options: &MethodOptions, base: FrameCost) -> Result<FrameCost, MethodError> {
        let r = options.reader("auto", &FrameCost::KEYS);
        let given = |key: &str| options.iter().any(|(k, _)| k == key);
        let cost = FrameCost {
            per_triangle_ns: if given(COST_PER_TRIANGLE_NS.key) {
                r.ranged(&COST_PER_TRIANGLE_NS)?
            } else {
                base.per_triangle_ns
            },
            per_byte_ns: if given(COST_PER_BYTE_NS.key) {
                r.ranged(&COST_PER_BYTE_NS)?
            } else {
                base.per_byte_ns
            },
        };
        r.finish()?;
        Ok(cost)
    }
}

/// One method measured on a scene's sample views.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Measured {
    /// The method (default options).
    pub method: String,
    /// Mean time to cull a frame, microseconds (what a server pays): CPU
    /// time of the thread that culled, wall time for a device method.
    pub mean_cull_us: f64,
    /// Median time to cull a frame, microseconds, measured alike.
    pub median_cull_us: f64,
    /// Mean objects in the answer.
    pub mean_pvs: f64,
    /// Mean triangles of the objects in the answer.
    pub mean_pvs_triangles: f64,
}

impl Measured {
    /// Mean bytes of geometry the answer's objects weigh ([`BYTES_PER_TRIANGLE`]).
    pub fn mean_pvs_bytes(&self) -> f64 {
        self.mean_pvs_triangles * BYTES_PER_TRIANGLE
    }

    /// Modelled cost of a frame answered by this method, microseconds.
    pub fn frame_cost_us(&self, cost: FrameCost) -> f64 {
        self.mean_cull_us
            + self.mean_pvs_triangles * cost.per_triangle_ns * 1e-3
            + self.mean_pvs_bytes() * cost.per_byte_ns * 1e-3
    }
}

/// Every conservative method of a scene, measured on the same views.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ranking {
    /// The walks the sample views came from (`street`, `orbit`, `random`).
    pub walks: Vec<String>,
    /// Sample views in all.
    pub frames: usize,
    /// Viewport of the sample views.
    pub viewport: [u32; 2],
    /// The methods, in registry order.
    pub measured: Vec<Measured>,
}

impl Ranking {
    /// The methods cheapest first at these prices, each with its modelled
    /// frame cost (ties keep registry order).
    pub fn ranked(&self, cost: FrameCost) -> Vec<(&Measured, f64)> {
        let mut r: Vec<(&Measured, f64)> = self
            .measured
            .iter()
            .map(|m| (m, m.frame_cost_us(cost)))
            .collect();
        r.sort_by(|a, b| a.1.total_cmp(&b.1));
        r
    }

    /// The cheapest method at these prices, `None` when nothing was measured.
    pub fn best(&self, cost: FrameCost) -> Option<&str> {
        self.ranked(cost).first().map(|(m, _)| m.method.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn measured(method: &str, cull: f64, triangles: f64) -> Measured {
        Measured {
            method: method.into(),
            mean_cull_us: cull,
            median_cull_us: cull,
            mean_pvs: triangles / 100.0,
            mean_pvs_triangles: triangles,
        }
    }

    #[test]
    fn the_best_method_follows_the_prices() {
        let r = Ranking {
            walks: vec!["street".into()],
            frames: 10,
            viewport: [1024, 768],
            measured: vec![
                measured("frustum", 20.0, 200_000.0),
                measured("horizon", 100.0, 10_000.0),
            ],
        };
        // 2 ns a triangle: 420 vs 120 µs.
        assert_eq!(r.best(FrameCost::default()), Some("horizon"));
        // Drawing for free: the quicker cull wins.
        let free = FrameCost {
            per_triangle_ns: 0.0,
            per_byte_ns: 0.0,
        };
        assert_eq!(r.best(free), Some("frustum"));
        // Bytes count too: 10k triangles are 360 kB.
        let m = &r.measured[1];
        let bytes = FrameCost {
            per_triangle_ns: 0.0,
            per_byte_ns: 1.0,
        };
        assert!((m.frame_cost_us(bytes) - (100.0 + 360.0)).abs() < 1e-9);
    }

    #[test]
    fn autos_options_are_its_prices_and_nothing_else() {
        let base = FrameCost {
            per_triangle_ns: 5.0,
            per_byte_ns: 0.5,
        };
        let mut o = MethodOptions::default();
        assert_eq!(FrameCost::read(&o, base).unwrap(), base);
        o.insert("cost_per_triangle_ns", "10");
        let c = FrameCost::read(&o, base).unwrap();
        assert_eq!((c.per_triangle_ns, c.per_byte_ns), (10.0, 0.5));
        o.insert("cost_per_byte_ns", "-1");
        assert!(FrameCost::read(&o, base).is_err());
        let mut o = MethodOptions::default();
        o.insert("k", "3");
        assert!(matches!(
            FrameCost::read(&o, base),
            Err(MethodError::UnknownOption { .. })
        ));
    }
}
