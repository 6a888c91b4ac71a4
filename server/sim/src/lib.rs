//! scalpel-sim: the physics core of scalpel, sans-IO.
//!
//! The coupled mesh/meshless soft-tissue model of Cheng et al. 2018, with the corrections of
//! `shared/reference/physics.md`: a closed surface triangle mesh for rendering, interior
//! meshless points on a regular lattice for deformation, and the embedding that ties them.
//!
//! No threads, clocks, files or sockets: callers hand in bytes (mesh files) and read results.
//! Units are SI throughout (m, kg, s, Pa, N); millimetres appear only in user-facing names.
//!
//! ```
//! use scalpel_sim::progress::Silent;
//! use scalpel_sim::scene::{build_scene, builtin};
//!
//! // The built-in liver of the paper's Table 1: 508 triangles, about 1526 interior points.
//! let spec = builtin("liver").expect("liver is a built-in scene");
//! let scene = build_scene(&spec, None, &mut Silent).expect("built-in scenes always build");
//! let summary = scene.model.summary();
//! assert_eq!(scene.mesh_stats.triangles, 508);
//! assert!(summary.points.abs_diff(1526) <= 45);
//! // Σ V_i equals the enclosed volume: the lattice cells are clipped to the organ exactly.
//! assert!(summary.volume_error.abs() < 1e-6);
//! ```

pub mod cut;
pub mod force;
pub mod geometry;
pub mod lesson;
pub mod math;
pub mod mls;
pub mod model;
pub mod pipeline;
pub mod progress;
pub mod scene;
pub mod solver;
pub mod sparse_llt;
pub mod validate;
