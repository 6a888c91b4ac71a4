//! Scenes from disk: a built-in name or a scene file, and the mesh file a scene names (the
//! simulation crate does no I/O). Shared by the server and the `scalpel` tools.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use scalpel_sim::geometry::MeshFormat;
use scalpel_sim::pipeline::CutScript;
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{self, BuiltScene, MeshSource, PreparedSurface, SceneSpec};

use crate::input_file::{
    SCRIPT_MAX_BYTES, TOML_MAX_BYTES, check_regular, read_capped, read_text_capped,
};
use crate::scene_budget::SceneBudget;

/// Reads the mesh file a scene names (if any), refusing files over the scene's size cap
/// before reading them.
pub fn read_mesh_bytes(spec: &SceneSpec) -> anyhow::Result<Option<Vec<u8>>> {
    let MeshSource::File(path) = &spec.mesh.source else {
        return Ok(None);
    };
    // Check the extension before touching the file, so a wrong one gets the format message.
    MeshFormat::from_file_name(&path.display().to_string())?;
    let len = check_regular(path)
        .with_context(|| format!("cannot open mesh file {}", path.display()))?
        .len();
    if len > spec.mesh.limits.max_file_bytes {
        bail!(
            "{}: file is {len} bytes, over the limit of {}; decimate the mesh or raise mesh.max_file_mb",
            path.display(),
            spec.mesh.limits.max_file_bytes
        );
    }
    // Counted while reading too: the size on disk may change, or lie.
    let bytes = read_capped(path, spec.mesh.limits.max_file_bytes)
        .with_context(|| format!("cannot read mesh file {}", path.display()))?;
    Ok(Some(bytes))
}

/// Reads a scene file (TOML).
pub fn read_scene_file(path: &Path) -> anyhow::Result<SceneSpec> {
    let text = read_text_capped(path, TOML_MAX_BYTES)
        .with_context(|| format!("cannot read scene file {}", path.display()))?;
    Ok(SceneSpec::from_toml(&text, path)?)
}

/// Reads a blade script file (TOML keyframes, or CSV for a `.csv` name).
pub fn load_script(path: &Path) -> anyhow::Result<CutScript> {
    let text = read_text_capped(path, SCRIPT_MAX_BYTES)
        .with_context(|| format!("cannot read script {}", path.display()))?;
    Ok(CutScript::from_file_text(
        &text,
        &path.display().to_string(),
    )?)
}

/// A built-in scene name or a scene file, built as a station runs it (cutting on).
pub fn load_scene(name: &str) -> anyhow::Result<BuiltScene> {
    load_station_scene(name).map(|(scene, _)| scene)
}

/// [`load_scene`], and a note for the station's start when the scene file had cutting off
/// (a station turns it on: what it renders is the blade's force).
pub fn load_station_scene(name: &str) -> anyhow::Result<(BuiltScene, Option<String>)> {
    let (surface, note) = prepare_station_scene(name)?;
    Ok((scene::build_model(surface, &mut Silent)?, note))
}

/// [`load_station_scene`] if the scene's estimated footprint is within `budget`; refused
/// before its interior is sampled otherwise.
pub fn load_station_scene_within(
    name: &str,
    budget: &SceneBudget,
) -> anyhow::Result<(BuiltScene, Option<String>)> {
    let (surface, note) = prepare_station_scene(name)?;
    budget
        .check(&surface.spec.name, &surface.footprint())
        .map_err(anyhow::Error::msg)?;
    Ok((scene::build_model(surface, &mut Silent)?, note))
}

/// The first part of [`load_station_scene`]: the scene read, its surface loaded and
/// validated, cutting on — what its footprint is estimated from.
pub fn prepare_station_scene(name: &str) -> anyhow::Result<(PreparedSurface, Option<String>)> {
    let mut spec = match scene::builtin(name) {
        Some(spec) => spec,
        None => {
            let path = PathBuf::from(name);
            if MeshFormat::from_file_name(name).is_ok() {
                bail!(
                    "'{name}' is a mesh file: a station runs a built-in scene ({}) or a scene file that names the mesh ([mesh] file = \"{name}\", docs/SCENES.md)",
                    scene::BUILTIN_SCENES.join(", ")
                );
            }
            if !path.exists() {
                bail!(
                    "'{name}' is neither a built-in scene ({}) nor an existing scene file",
                    scene::BUILTIN_SCENES.join(", ")
                );
            }
            read_scene_file(&path)?
        }
    };
    let bytes = read_mesh_bytes(&spec)?;
    // A station cuts: the force model and the blade contact are what it renders.
    let note = (!spec.features.cutting).then(|| {
        format!(
            "{name} has features.cutting off; a station always cuts (its force is the blade's): on"
        )
    });
    spec.features.cutting = true;
    Ok((
        scene::prepare_surface(&spec, bytes.as_deref(), &mut Silent)?,
        note,
    ))
}

/// A built-in lesson's name or a lesson file (docs/LESSONS.md), its scene resolved as a
/// station names scenes: a built-in scene's name, or a scene file's path relative to the
/// lesson file's folder joined onto that folder.
pub fn load_lesson(name: &str) -> anyhow::Result<scalpel_sim::lesson::LessonSpec> {
    use scalpel_sim::lesson::{LessonSpec, builtin_lesson};
    if let Some(spec) = builtin_lesson(name) {
        return Ok(spec);
    }
    let path = Path::new(name);
    let mut spec = LessonSpec::from_toml(&lesson_text(name)?, name)?;
    if scene::builtin(&spec.scene).is_none() {
        let scene = Path::new(&spec.scene);
        if scene.is_relative()
            && let Some(dir) = path.parent()
        {
            spec.scene = dir.join(scene).display().to_string();
        }
    }
    Ok(spec)
}

/// The TOML text of the lesson `name` (built-in, or a file), as a station journals it.
pub fn lesson_text(name: &str) -> anyhow::Result<String> {
    if let Some((_, text)) = scalpel_sim::lesson::BUILTIN
        .iter()
        .find(|(n, _)| *n == name)
    {
        return Ok(text.to_string());
    }
    read_text_capped(Path::new(name), TOML_MAX_BYTES).with_context(|| {
        format!(
            "{name} is neither a built-in lesson (scalpel lesson list) nor a readable lesson file"
        )
    })
}

/// Whether two scene names a station would take (built-in names or files) are one scene.
pub fn same_scene(a: &str, b: &str) -> bool {
    if a == b {
        return true;
    }
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}
