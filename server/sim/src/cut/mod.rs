//! Cutting: the virtual scalpel, the swept cut surface and the visibility criterion.

pub mod blade;
pub mod incision;
pub mod swept;

pub use crate::geometry::predicates::segment_meets_triangle;
pub use blade::{Blade, ToolPose};
pub use incision::{FaceKind, Incised, IncisionError, IncisionParams, PathSample, incise};
pub use swept::{SweptSurface, cut_pairs, visit_crossing_pairs};
