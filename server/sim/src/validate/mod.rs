//! Analytic validation benchmarks (physics.md §8), shared by the tests and `scalpel validate`.
//!
//! Each benchmark builds its body through the real pipeline (box surface → validated mesh →
//! lattice with exact clipped volumes → MLS operator → solver) and compares with the
//! analytic answer. No clock here: callers time the runs.

mod bodies;
mod cantilever;
mod cases;
mod griffith;
mod punch;
mod stability;
mod supports;

use serde::Serialize;

pub use bodies::{BoxBody, LatticeCube, box_body, cut_down_to, timoshenko_tip_deflection};
pub use cantilever::*;
pub use cases::*;
pub use griffith::*;
pub use punch::*;
pub use stability::*;
pub use supports::*;

/// The outcome of one benchmark.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchmarkResult {
    /// Short id (B1, B2, ...).
    pub name: &'static str,
    /// What it checks.
    pub title: &'static str,
    /// Measured error (relative unless the detail says otherwise).
    pub error: f64,
    /// Pass band.
    pub tolerance: f64,
    /// `error <= tolerance`.
    pub pass: bool,
    /// Figures behind the error, for people.
    pub detail: String,
}

impl BenchmarkResult {
    fn new(
        name: &'static str,
        title: &'static str,
        error: f64,
        tolerance: f64,
        detail: String,
    ) -> Self {
        Self {
            name,
            title,
            error,
            tolerance,
            pass: error <= tolerance && error.is_finite(),
            detail,
        }
    }
}

/// A benchmark that can be run by name.
pub struct Benchmark {
    /// Short id.
    pub name: &'static str,
    /// Runs it.
    pub run: fn() -> BenchmarkResult,
}

/// Every benchmark, in order (issue 3's list plus B10, the clean cut).
pub fn all() -> Vec<Benchmark> {
    vec![
        Benchmark {
            name: "B1",
            run: b1_kinematic_patch,
        },
        Benchmark {
            name: "B2",
            run: b2_static_patch,
        },
        Benchmark {
            name: "B3",
            run: b3_uniaxial_tension,
        },
        Benchmark {
            name: "B5",
            run: b5_cantilever,
        },
        Benchmark {
            name: "B5T",
            run: b5t_cantilever_timoshenko,
        },
        Benchmark {
            name: "B5b",
            run: b5b_slender_cantilever,
        },
        Benchmark {
            name: "B6",
            run: b6_bending_frequency,
        },
        Benchmark {
            name: "B9",
            run: b9_rigid_rotation,
        },
        Benchmark {
            name: "B10",
            run: b10_clean_cut,
        },
        Benchmark {
            name: "B11",
            run: b11_sliver_completion,
        },
        Benchmark {
            name: "B12",
            run: b12_momentum,
        },
        Benchmark {
            name: "B13",
            run: b13_column_under_gravity,
        },
        Benchmark {
            name: "B14",
            run: b14_flat_punch,
        },
        Benchmark {
            name: "B15",
            run: b15_griffith_slit,
        },
    ]
}
