//! Turning a command-line target into a built scene: resolve the name or file, read the
//! files (the sim does no I/O), build with progress, and time every stage.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::bail;
use scalpel_server::scene_file::read_mesh_bytes;
use scalpel_sim::geometry::MeshFormat;
use scalpel_sim::model::SpacingRule;
use scalpel_sim::progress::{BuildObserver, BuildStage};
use scalpel_sim::scene::{self, BuiltScene, SceneSpec};

use crate::TargetArgs;
use crate::progress::StageProgress;

/// A built scene with its build time.
pub struct TimedScene {
    /// The scene.
    pub scene: BuiltScene,
    /// Wall time of the whole build (ms).
    pub build_ms: f64,
    /// Wall time per stage (ms), by stage name.
    pub stages_ms: BTreeMap<&'static str, f64>,
}

/// Whether `target` names a bare mesh file (not a built-in scene or a scene file): its
/// scene has every feature off until a command says what it is for.
pub fn is_bare_mesh(target: &TargetArgs) -> bool {
    scene::builtin(&target.target).is_none()
        && !Path::new(&target.target)
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
        && MeshFormat::from_file_name(&target.target).is_ok()
}

/// Resolves a built-in scene name, a scene file or a mesh file into a scene spec, applying
/// the sampling overrides.
pub fn resolve(target: &TargetArgs) -> anyhow::Result<SceneSpec> {
    let mut spec = if let Some(spec) = scene::builtin(&target.target) {
        spec
    } else {
        let path = PathBuf::from(&target.target);
        let is_toml = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
        if is_toml {
            scalpel_server::scene_file::read_scene_file(&path)?
        } else if is_bare_mesh(target) {
            scene::for_mesh_file(path, target.units.into())
        } else if !path.exists() && path.extension().is_none() {
            bail!(
                "'{}' is not a built-in scene ({}), a scene file (.toml) or a mesh file (.obj, .stl, .ply, .vtk)",
                target.target,
                scene::BUILTIN_SCENES.join(", ")
            );
        } else {
            // Let the importer explain which formats it accepts.
            MeshFormat::from_file_name(&target.target)?;
            unreachable!("from_file_name failed above")
        }
    };
    // The bounds a scene file's `[sampling]` has.
    if let Some(mm) = target.spacing_mm {
        if !(mm.is_finite() && mm > 0.0 && mm <= 1000.0) {
            bail!("--spacing-mm must be above 0 and at most 1000 mm, got {mm}");
        }
        spec.sampling.spacing = SpacingRule::Spacing(mm * 1e-3);
    }
    if let Some(n) = target.target_points {
        let most = scalpel_sim::model::MAX_POINTS;
        if !(8..=most).contains(&n) {
            bail!("--target-points must be 8 to {most}, got {n}");
        }
        spec.sampling.spacing = SpacingRule::TargetPoints(n);
    }
    Ok(spec)
}

/// Records when each stage starts.
struct StageClock<'a> {
    marks: Vec<(BuildStage, Instant)>,
    display: &'a mut StageProgress,
}

impl BuildObserver for StageClock<'_> {
    fn stage(&mut self, stage: BuildStage) {
        self.marks.push((stage, Instant::now()));
        self.display.stage(stage);
    }
}

/// Builds `spec` (reading its mesh file first), timing each stage and showing progress on
/// stderr when a stage takes more than a second.
pub fn build_with_progress(spec: &SceneSpec) -> anyhow::Result<TimedScene> {
    let mut display = StageProgress::new(&spec.name);
    let result = build_timed(spec, &mut display);
    display.finish();
    result
}

/// Builds `spec` and times it; `display` sees the stages.
pub fn build_timed(spec: &SceneSpec, display: &mut StageProgress) -> anyhow::Result<TimedScene> {
    let start = Instant::now();
    let bytes = read_mesh_bytes(spec)?;
    let mut clock = StageClock {
        marks: Vec::new(),
        display,
    };
    let scene = scene::build_scene(spec, bytes.as_deref(), &mut clock)?;
    let end = Instant::now();
    let mut stages_ms = BTreeMap::new();
    for (k, (stage, at)) in clock.marks.iter().enumerate() {
        let until = clock.marks.get(k + 1).map_or(end, |m| m.1);
        *stages_ms.entry(stage.name()).or_insert(0.0) += (until - *at).as_secs_f64() * 1e3;
    }
    Ok(TimedScene {
        scene,
        build_ms: (end - start).as_secs_f64() * 1e3,
        stages_ms,
    })
}
