//! The coupled model (paper §2, physics.md §1.2–1.3, §5.3): the surface triangle mesh for
//! rendering, interior meshless points on a regular lattice for deformation, their rest
//! neighbourhoods, and the embedding that makes the surface follow the points.

pub mod cell_volume;
pub mod embedding;
pub mod lattice;
pub mod neighbours;
pub(crate) mod rows;

use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use cell_volume::Lattice;
pub use embedding::{Blockers, EmbeddingStats, SurfaceEmbedding};
pub use neighbours::{Kernel, NeighbourCapacityError, Neighbourhoods, RestGrid};

use crate::geometry::TriMesh;
use crate::math::Vec3;
use crate::progress::{BuildObserver, BuildStage};

/// How the interior is sampled.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SamplingParams {
    /// Lattice spacing, given or solved for.
    pub spacing: SpacingRule,
    /// Support radius over spacing, h/s (default 2; useful range 1.5–2.5, physics.md §1.2).
    pub support_ratio: f64,
    /// A lattice cell becomes a point when at least this fraction of it is inside the organ;
    /// smaller slivers give their volume to a neighbour (a point with a sliver of mass
    /// would need a tiny time step).
    pub min_cell_fraction: f64,
    /// Free neighbour slots kept per point for virtual points added by cuts.
    pub neighbour_headroom: usize,
}

impl Default for SamplingParams {
    fn default() -> Self {
        Self {
            spacing: SpacingRule::RealTime { most_points: 2000 },
            support_ratio: 2.0,
            min_cell_fraction: 0.1,
            neighbour_headroom: 16,
        }
    }
}

/// The lattice spacing, or the point count to solve it for.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SpacingRule {
    /// Fixed spacing (m).
    Spacing(f64),
    /// Solve the spacing so that about this many points are kept.
    TargetPoints(usize),
    /// About `most_points`, or fewer where a 1 ms tick of the whole body would not be real
    /// time (`scene::real_time`; the model alone takes it as `TargetPoints(most_points)`).
    RealTime {
        /// Points sampled when the tick affords them.
        most_points: usize,
    },
}

/// Largest number of interior points a build accepts.
pub const MAX_POINTS: usize = 4_000_000;

/// Why the model could not be built.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ModelBuildError {
    /// The spacing would need an unreasonable lattice.
    #[error(
        "spacing {spacing_mm:.4e} mm needs more than the {limit} lattice cells allowed over the organ; use a larger spacing or fewer target points"
    )]
    LatticeTooLarge {
        /// Spacing tried (mm).
        spacing_mm: f64,
        /// Cells it would need.
        cells: usize,
        /// The limit.
        limit: usize,
    },
    /// Too many points.
    #[error("{points} interior points exceed the limit of {limit}; use a larger spacing")]
    TooManyPoints {
        /// Points.
        points: usize,
        /// The limit.
        limit: usize,
    },
    /// No lattice cell is inside the organ.
    #[error(
        "no interior point fits: the organ is thinner than the spacing {spacing_mm:.3} mm; use a smaller spacing"
    )]
    NoPoints {
        /// Spacing tried (mm).
        spacing_mm: f64,
    },
    /// A sampling parameter is out of range.
    #[error("sampling: {0}")]
    BadParameter(String),
}

/// The interior meshless points.
#[derive(Debug, Clone, PartialEq)]
pub struct InteriorPoints {
    /// Rest positions X_i (m).
    pub rest: Vec<Vec3>,
    /// Rest volumes V_i (m³).
    pub volume_m3: Vec<f64>,
    /// Masses m_i = ρ V_i (kg).
    pub mass_kg: Vec<f64>,
    /// Lattice coordinates (i, j, k).
    pub lattice_coords: Vec<[u32; 3]>,
}

impl InteriorPoints {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.rest.len()
    }

    /// True when there are none.
    pub fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }
}

/// Surface mesh + interior points + neighbourhoods + embedding, all in rest space (m, kg).
#[derive(Debug, Clone)]
pub struct CoupledModel {
    /// The rest surface (validated: closed, manifold, outward).
    pub surface: TriMesh,
    /// Interior points.
    pub points: InteriorPoints,
    /// The lattice the points were taken from.
    pub lattice: Lattice,
    /// MLS kernel (support h).
    pub kernel: Kernel,
    /// Rest-space grid for radius queries.
    pub grid: RestGrid,
    /// Neighbour lists N(i).
    pub neighbours: Neighbourhoods,
    /// Surface vertices in the meshless field.
    pub embedding: SurfaceEmbedding,
    /// Enclosed volume of the surface (m³).
    pub mesh_volume_m3: f64,
    /// Slivers merged into neighbours during sampling.
    pub merged_slivers: usize,
}

/// Figures of a built model, for reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModelSummary {
    /// Interior points.
    pub points: usize,
    /// Lattice spacing (mm).
    pub spacing_mm: f64,
    /// Support radius h (mm).
    pub support_mm: f64,
    /// Lattice dimensions.
    pub lattice_dims: [usize; 3],
    /// Σ V_i (ml).
    pub points_volume_ml: f64,
    /// Surface volume (ml).
    pub mesh_volume_ml: f64,
    /// (Σ V_i − V_mesh) / V_mesh.
    pub volume_error: f64,
    /// Σ m_i (g).
    pub mass_g: f64,
    /// Fewest neighbours of any point.
    pub min_neighbours: usize,
    /// Mean neighbours.
    pub mean_neighbours: f64,
    /// Most neighbours.
    pub max_neighbours: usize,
    /// Points with fewer than 4 neighbours (candidates for orphan handling).
    pub weak_points: usize,
    /// Slivers merged into neighbours.
    pub merged_slivers: usize,
    /// Embedding of the surface.
    pub embedding: EmbeddingStats,
}

impl CoupledModel {
    /// Builds the model on a validated surface with material density `density_kg_m3`.
    pub fn build(
        surface: TriMesh,
        params: &SamplingParams,
        density_kg_m3: f64,
        observer: &mut dyn BuildObserver,
    ) -> Result<Self, ModelBuildError> {
        check_params(params)?;
        let bbox = surface.bbox();
        let spacing = match params.spacing {
            SpacingRule::Spacing(s) => s,
            SpacingRule::TargetPoints(n) | SpacingRule::RealTime { most_points: n } => {
                if n > MAX_POINTS {
                    return Err(ModelBuildError::TooManyPoints {
                        points: n,
                        limit: MAX_POINTS,
                    });
                }
                observer.stage(BuildStage::SolveSpacing);
                lattice::solve_spacing(&surface, n, params.min_cell_fraction).0
            }
        };
        let cells = lattice::lattice_cells(&bbox, spacing);
        if cells > lattice::MAX_LATTICE_CELLS {
            return Err(ModelBuildError::LatticeTooLarge {
                spacing_mm: spacing * 1e3,
                cells,
                limit: lattice::MAX_LATTICE_CELLS,
            });
        }
        observer.stage(BuildStage::Sample);
        let sampling = lattice::sample(&surface, spacing, params.min_cell_fraction);
        if sampling.positions.is_empty() {
            return Err(ModelBuildError::NoPoints {
                spacing_mm: spacing * 1e3,
            });
        }
        if sampling.positions.len() > MAX_POINTS {
            return Err(ModelBuildError::TooManyPoints {
                points: sampling.positions.len(),
                limit: MAX_POINTS,
            });
        }
        let kernel = Kernel {
            support_m: params.support_ratio * spacing,
        };
        observer.stage(BuildStage::Neighbours);
        let grid = RestGrid::build(&sampling.positions, kernel.support_m);
        let neighbours = Neighbourhoods::build(
            &sampling.positions,
            &grid,
            kernel.support_m,
            params.neighbour_headroom,
        );
        observer.stage(BuildStage::Embed);
        let embedding = SurfaceEmbedding::build(&surface, &sampling.positions, &grid, &kernel);
        let mass_kg = sampling.volumes.iter().map(|v| v * density_kg_m3).collect();
        Ok(Self {
            mesh_volume_m3: surface.signed_volume(),
            surface,
            points: InteriorPoints {
                rest: sampling.positions,
                volume_m3: sampling.volumes,
                mass_kg,
                lattice_coords: sampling.coords,
            },
            lattice: sampling.lattice,
            kernel,
            grid,
            neighbours,
            embedding,
            merged_slivers: sampling.merged_slivers,
        })
    }

    /// Figures for reports.
    pub fn summary(&self) -> ModelSummary {
        let points_volume: f64 = self.points.volume_m3.iter().sum();
        let (min_n, mean_n, max_n) = self.neighbours.count_stats();
        let weak = (0..self.neighbours.len())
            .filter(|&i| self.neighbours.of(i).len() < 4)
            .count();
        ModelSummary {
            points: self.points.len(),
            spacing_mm: self.lattice.spacing * 1e3,
            support_mm: self.kernel.support_m * 1e3,
            lattice_dims: self.lattice.dims,
            points_volume_ml: points_volume * 1e6,
            mesh_volume_ml: self.mesh_volume_m3 * 1e6,
            volume_error: (points_volume - self.mesh_volume_m3) / self.mesh_volume_m3,
            mass_g: self.points.mass_kg.iter().sum::<f64>() * 1e3,
            min_neighbours: min_n,
            mean_neighbours: mean_n,
            max_neighbours: max_n,
            weak_points: weak,
            merged_slivers: self.merged_slivers,
            embedding: self.embedding.stats(),
        }
    }
}

fn check_params(p: &SamplingParams) -> Result<(), ModelBuildError> {
    let bad = |m: String| Err(ModelBuildError::BadParameter(m));
    match p.spacing {
        SpacingRule::Spacing(s) if !(s.is_finite() && s > 0.0) => {
            return bad(format!("spacing must be a positive length, got {s} m"));
        }
        SpacingRule::TargetPoints(0) | SpacingRule::RealTime { most_points: 0 } => {
            return bad("target points must be at least 1".into());
        }
        _ => {}
    }
    if !(1.2..=4.0).contains(&p.support_ratio) {
        return bad(format!(
            "support ratio h/s = {} is outside [1.2, 4]; 2 is recommended",
            p.support_ratio
        ));
    }
    if !(0.0..=1.0).contains(&p.min_cell_fraction) || p.min_cell_fraction == 0.0 {
        return bad(format!(
            "min cell fraction {} must be in (0, 1]",
            p.min_cell_fraction
        ));
    }
    Ok(())
}
