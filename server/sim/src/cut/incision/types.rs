//! What an incision takes and gives: the shape parameters, the re-triangulated surface and
//! why an incision can fail.

use serde::Serialize;
use thiserror::Error;

use crate::geometry::TriMesh;
use crate::geometry::topology::SurfaceCheck;

use crate::cut::cells::FaceKind;
use crate::cut::wound::Wound;

/// Shape parameters of an incision.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct IncisionParams {
    /// Largest half-opening as a fraction of the path length (physics.md §5.1: 0.15).
    pub opening_ratio: f64,
    /// Half-opening per unit cut depth, k_open (physics.md §5.1: 0.2–0.4).
    pub gape_factor: f64,
    /// Minimum angle the refinement aims for (degrees); the tests require ≥ 15°.
    pub refine_angle_deg: f64,
}

impl IncisionParams {
    /// The widest half-opening physics.md §5.1 gives a path `length` long, `depth` deep.
    pub(super) fn opening_for(&self, length: f64, depth: f64) -> f64 {
        (self.opening_ratio * length).min(self.gape_factor * depth)
    }

    /// The incision of the physical cut (cutting-physics.md §4): closed in rest space —
    /// both lips on Σ within a hairline of 0.1 mm at most (they stay two curves for the
    /// triangulation) — so the gap the eye sees is the field's: the blade, gravity and the
    /// supports. [`Self::default`] is physics.md §5.1's lens, drawn open.
    pub fn closed() -> Self {
        Self {
            opening_ratio: 0.005,
            gape_factor: 0.01,
            ..Self::default()
        }
    }
}

impl Default for IncisionParams {
    fn default() -> Self {
        Self {
            opening_ratio: 0.15,
            gape_factor: 0.3,
            refine_angle_deg: 25.0,
        }
    }
}

/// The re-triangulated surface.
#[derive(Debug, Clone)]
pub struct Incised {
    /// Rest positions and triangles.
    pub mesh: TriMesh,
    /// Kind of every triangle.
    pub kinds: Vec<FaceKind>,
    /// For every vertex, the input vertex it is (`None` for new vertices).
    pub source: Vec<Option<u32>>,
    /// Triangles created by this incision (skin, wall and lid).
    pub created: Vec<u32>,
    /// The wounds in this surface (the earlier ones and this one's).
    pub wounds: Vec<Wound>,
    /// Largest turn between consecutive lip segments in the incision's tangent plane
    /// (degrees).
    pub lip_max_turn_deg: f64,
    /// Smallest angle of the created skin and wall triangles (degrees).
    pub min_angle_deg: f64,
    /// Half-opening w_o (m).
    pub opening_m: f64,
    /// Deepest wall (m).
    pub depth_m: f64,
    /// Path length L (m).
    pub length_m: f64,
}

/// A vertex map through two edits: `source` maps the vertices after the second edit to
/// those before it, `earlier` those to the vertices before the first.
pub(crate) fn source_through(source: &[Option<u32>], earlier: &[Option<u32>]) -> Vec<Option<u32>> {
    source
        .iter()
        .map(|s| s.and_then(|v| earlier[v as usize]))
        .collect()
}

/// Why an incision could not be made (the surface is left as it was).
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum IncisionError {
    /// Too short to open.
    #[error(
        "the path is {length_mm:.2} mm long, shorter than it opens ({min_mm:.2} mm: a tenth of a local edge, a sixteenth of its depth)"
    )]
    TooShort {
        /// Path length (mm).
        length_mm: f64,
        /// Shortest path that opens (mm).
        min_mm: f64,
    },
    /// No skin under the path.
    #[error("no skin triangles under the path")]
    NoRegion,
    /// The region around the path is not a disk (a pinch, a hole, or it wraps around).
    #[error(
        "the region around the path is not a disk ({loops} boundary loops, pinched: {pinched})"
    )]
    NotDisk {
        /// Boundary loops found.
        loops: usize,
        /// A boundary vertex with two boundary edges leaving it.
        pinched: bool,
    },
    /// The path leaves the region (it runs off the part of the surface facing n̄).
    #[error("the path leaves the region facing its mean normal")]
    PathOutsideRegion,
    /// The constrained triangulation failed.
    #[error("triangulation failed: {0}")]
    Triangulation(String),
    /// The re-triangulated surface would not be closed, edge-manifold and consistently
    /// oriented (drawn, or as the envelope blade contact sees): refused, the surface kept.
    #[error("the incised surface would not be sound ({which}: {check:?})")]
    Unsound {
        /// "drawn" (skin and walls) or "envelope" (skin and lids).
        which: &'static str,
        /// What the check found.
        check: SurfaceCheck,
    },
}
