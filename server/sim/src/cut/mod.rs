//! Cutting: the virtual scalpel, the swept cut surface and the visibility criterion.

pub mod blade;
mod cells;
mod chart;
#[cfg(test)]
pub(crate) mod checks;
mod collapse;
mod deepen;
mod fan;
pub mod incision;
mod smooth;
pub mod stroke;
pub mod swept;
pub(crate) mod wall_grid;
pub mod wound;

pub use crate::geometry::predicates::segment_meets_triangle;
pub use blade::{Blade, PathSample, ToolPose};
pub use cells::{FaceKind, corners_of_kind};
pub use deepen::deepen;
pub use incision::{Incised, IncisionError, IncisionParams, incise};
pub use stroke::{StrokeOutcome, open_stroke};
pub use swept::{SIGMA_ROOM, SweptSurface, cut_pairs, visit_crossing_pairs};
pub use wound::{WallColumn, Wound};
