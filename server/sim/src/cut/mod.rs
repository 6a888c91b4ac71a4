//! Cutting: the virtual scalpel, the swept cut surface and the visibility criterion.

pub mod blade;
pub mod swept;

pub use blade::{Blade, ToolPose};
pub use swept::{SweptSurface, cut_pairs, segment_meets_triangle};
