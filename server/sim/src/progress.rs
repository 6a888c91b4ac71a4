//! Build progress: the stages of turning a scene into a model, reported to an observer.
//! The sim has no clock; a caller that wants timings or a progress bar reads its own clock
//! when a stage starts.

/// Stages of a scene build, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BuildStage {
    /// Generating a built-in organ or importing the mesh file.
    LoadMesh,
    /// Mesh validation and repairs.
    Validate,
    /// Remeshing a surface with poor triangles.
    Remesh,
    /// Choosing the spacing for a target point count.
    SolveSpacing,
    /// Cell-clipped volumes and point selection.
    Sample,
    /// Neighbour lists.
    Neighbours,
    /// Surface embedding.
    Embed,
    /// Planning a sampling's time step (`scene::real_time`).
    PlanSampling,
}

impl BuildStage {
    /// Short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::LoadMesh => "load_mesh",
            Self::Validate => "validate",
            Self::Remesh => "remesh",
            Self::SolveSpacing => "solve_spacing",
            Self::Sample => "sample",
            Self::Neighbours => "neighbours",
            Self::Embed => "embed",
            Self::PlanSampling => "plan_sampling",
        }
    }
}

/// Told when each stage starts. Called between stages only, so it costs nothing measurable.
pub trait BuildObserver {
    /// A stage starts now.
    fn stage(&mut self, stage: BuildStage);
}

/// An observer that ignores progress.
pub struct Silent;

impl BuildObserver for Silent {
    fn stage(&mut self, _stage: BuildStage) {}
}
