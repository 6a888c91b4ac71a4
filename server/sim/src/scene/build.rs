//! From a scene description to a built model: load or generate the surface, place it,
//! validate it, sample the interior.

use thiserror::Error;

use super::real_time::{SamplingPlan, build_for_real_time};
use super::{MeshSource, SceneSpec};
use crate::geometry::remesh::remesh_isotropic;
use crate::geometry::{
    MeshFormat, MeshImportError, MeshStats, MeshValidationError, MeshWarning, ValidatedMesh,
    ValidationOptions, import_mesh, validate,
};
use crate::model::{CoupledModel, ModelBuildError, SpacingRule};
use crate::progress::{BuildObserver, BuildStage};

/// A scene ready to simulate.
#[derive(Debug, Clone)]
pub struct BuiltScene {
    /// What was asked for.
    pub spec: SceneSpec,
    /// Repairs and observations made on the surface.
    pub mesh_warnings: Vec<MeshWarning>,
    /// Measures of the validated surface.
    pub mesh_stats: MeshStats,
    /// The coupled model.
    pub model: CoupledModel,
    /// How a real-time sampling rule chose the point count (`SpacingRule::RealTime` with the
    /// explicit solver); `None` for a fixed spacing or count.
    pub sampling_plan: Option<SamplingPlan>,
    /// Where the body starts under gravity: found by the first simulation of it and kept
    /// (a settle takes seconds), `pipeline::Simulation::new`.
    pub start: std::sync::OnceLock<super::supports::StartState>,
}

/// Why a scene could not be built.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum SceneBuildError {
    /// The mesh file could not be read.
    #[error(transparent)]
    Import(#[from] MeshImportError),
    /// The surface was rejected.
    #[error(transparent)]
    Validate(#[from] MeshValidationError),
    /// The interior could not be sampled.
    #[error("scene '{scene}': {error}")]
    Model {
        /// Scene name.
        scene: String,
        /// The model error.
        error: ModelBuildError,
    },
    /// A support of the scene holds nothing of the body.
    #[error("scene '{scene}': {message}")]
    Supports {
        /// Scene name.
        scene: String,
        /// Which support and why.
        message: String,
    },
    /// The scene names a mesh file, but no bytes were given for it.
    #[error("scene '{scene}': its mesh is the file {path}; read the file and pass its bytes")]
    MissingMeshBytes {
        /// Scene name.
        scene: String,
        /// The file.
        path: String,
    },
}

/// `validated` remeshed to edges of `target_m`, validated again (self-intersections
/// included, whatever the scene says), with a warning that says what changed; as it was,
/// with a warning that says why, if the remeshed surface would have more than
/// `options.max_triangles` triangles, fails validation, or needed repairs (the remesher's
/// surface must need none).
fn remeshed(
    mut validated: ValidatedMesh,
    target_m: f64,
    source: &str,
    options: &ValidationOptions,
) -> ValidatedMesh {
    let strict = ValidationOptions {
        check_self_intersections: true,
        ..options.clone()
    };
    // (An equilateral triangle of side L has area √3/4·L².)
    let expected = validated.mesh.area() / (3f64.sqrt() / 4.0 * target_m * target_m);
    let outcome = if expected > options.max_triangles as f64 {
        Err(format!(
            "about {expected:.0} triangles, over the limit of {} (mesh.max_triangles); give a \
             longer edge",
            options.max_triangles
        ))
    } else {
        remesh_isotropic(&validated.mesh, target_m)
            .map_err(|e| e.to_string())
            .and_then(|(mesh, report)| {
                let again = validate(mesh, source, &strict).map_err(|e| e.to_string())?;
                match again.warnings.iter().find(|w| w.is_repair()) {
                    Some(w) => Err(format!("its surface needed a repair ({w})")),
                    None => Ok((again, report)),
                }
            })
    };
    let mut warnings = std::mem::take(&mut validated.warnings);
    match outcome {
        // (Observations of the shape, such as its size, were made on the first pass.)
        Ok((again, report)) => {
            warnings.push(MeshWarning::Remeshed(report));
            ValidatedMesh { warnings, ..again }
        }
        Err(reason) => {
            warnings.push(MeshWarning::RemeshRefused {
                target_edge_m: target_m,
                reason,
            });
            ValidatedMesh {
                warnings,
                ..validated
            }
        }
    }
}

/// A scene's surface, loaded, placed, validated and (if poor) remeshed: what is known before
/// the interior is sampled, and all that [`super::footprint::estimate`] needs.
#[derive(Debug, Clone)]
pub struct PreparedSurface {
    /// What was asked for.
    pub spec: SceneSpec,
    /// The surface.
    pub validated: ValidatedMesh,
}

impl PreparedSurface {
    /// What the scene will cost a station once built (points, memory, tick).
    pub fn footprint(&self) -> super::footprint::Footprint {
        super::footprint::estimate(&self.spec, &self.validated.mesh)
    }
}

/// Builds `spec`. For a file mesh, `mesh_bytes` holds the file's content (the sim does no
/// I/O); for a built-in shape it is ignored. [`prepare_surface`] then [`build_model`].
pub fn build_scene(
    spec: &SceneSpec,
    mesh_bytes: Option<&[u8]>,
    observer: &mut dyn BuildObserver,
) -> Result<BuiltScene, SceneBuildError> {
    build_model(prepare_surface(spec, mesh_bytes, observer)?, observer)
}

/// The first part of a build: the surface, before the interior is sampled (a caller may
/// check the scene's [`PreparedSurface::footprint`] against its budget before going on).
pub fn prepare_surface(
    spec: &SceneSpec,
    mesh_bytes: Option<&[u8]>,
    observer: &mut dyn BuildObserver,
) -> Result<PreparedSurface, SceneBuildError> {
    observer.stage(BuildStage::LoadMesh);
    let (mut mesh, source) = match &spec.mesh.source {
        MeshSource::Builtin(shape) => (shape.generate(), format!("builtin:{}", shape.name())),
        MeshSource::File(path) => {
            let name = path.display().to_string();
            let bytes = mesh_bytes.ok_or_else(|| SceneBuildError::MissingMeshBytes {
                scene: spec.name.clone(),
                path: name.clone(),
            })?;
            let format = MeshFormat::from_file_name(&name)?;
            let mesh = import_mesh(bytes, format, &name, spec.mesh.units, &spec.mesh.limits)?;
            (mesh, name)
        }
    };
    let transform = spec.mesh.transform;
    if !transform.is_identity() {
        mesh.map_positions(|p| transform.apply(&p));
        if transform.mirrors() {
            // A mirror turns the winding inside out; undo that so validation sees no inversion.
            mesh.flip_all();
        }
    }

    observer.stage(BuildStage::Validate);
    let options = ValidationOptions {
        max_triangles: spec.mesh.limits.max_triangles,
        check_self_intersections: spec.mesh.check_self_intersections,
    };
    let mut validated = validate(mesh, &source, &options)?;
    if let Some(target) = spec.mesh.remesh.target_for(&validated.stats) {
        observer.stage(BuildStage::Remesh);
        validated = remeshed(validated, target, &source, &options);
    }
    Ok(PreparedSurface {
        spec: spec.clone(),
        validated,
    })
}

/// The second part of a build: the interior sampled, the model made.
pub fn build_model(
    surface: PreparedSurface,
    observer: &mut dyn BuildObserver,
) -> Result<BuiltScene, SceneBuildError> {
    let PreparedSurface { spec, validated } = surface;
    let built = match spec.sampling.spacing {
        SpacingRule::RealTime { most_points } => {
            build_for_real_time(&validated.mesh, &spec, most_points, observer)
        }
        _ => CoupledModel::build(
            validated.mesh,
            &spec.sampling,
            spec.material.density_kg_m3,
            observer,
        )
        .map(|model| (model, None)),
    };
    let (model, sampling_plan) = built.map_err(|error| SceneBuildError::Model {
        scene: spec.name.clone(),
        error,
    })?;
    spec.supports
        .check_holds(&model.points.rest, &model.surface.positions)
        .map_err(|message| SceneBuildError::Supports {
            scene: spec.name.clone(),
            message,
        })?;
    Ok(BuiltScene {
        spec,
        mesh_warnings: validated.warnings,
        mesh_stats: validated.stats,
        model,
        sampling_plan,
        start: std::sync::OnceLock::new(),
    })
}
