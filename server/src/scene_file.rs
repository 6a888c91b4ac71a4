//! Scenes from disk: a built-in name or a scene file, and the mesh file a scene names (the
//! simulation crate does no I/O). Shared by the server and the `scalpel` tools.

use std::path::PathBuf;

use anyhow::{Context, bail};
use scalpel_sim::geometry::MeshFormat;
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{self, BuiltScene, MeshSource, SceneSpec};

/// Reads the mesh file a scene names (if any), refusing files over the scene's size cap
/// before reading them.
pub fn read_mesh_bytes(spec: &SceneSpec) -> anyhow::Result<Option<Vec<u8>>> {
    let MeshSource::File(path) = &spec.mesh.source else {
        return Ok(None);
    };
    // Check the extension before touching the file, so a wrong one gets the format message.
    MeshFormat::from_file_name(&path.display().to_string())?;
    let len = std::fs::metadata(path)
        .with_context(|| format!("cannot open mesh file {}", path.display()))?
        .len();
    if len > spec.mesh.limits.max_file_bytes {
        bail!(
            "{}: file is {len} bytes, over the limit of {}; decimate the mesh or raise mesh.max_file_mb",
            path.display(),
            spec.mesh.limits.max_file_bytes
        );
    }
    let bytes =
        std::fs::read(path).with_context(|| format!("cannot read mesh file {}", path.display()))?;
    Ok(Some(bytes))
}

/// A built-in scene name or a scene file, built as a station runs it (cutting on).
pub fn load_scene(name: &str) -> anyhow::Result<BuiltScene> {
    let mut spec = match scene::builtin(name) {
        Some(spec) => spec,
        None => {
            let path = PathBuf::from(name);
            let text = std::fs::read_to_string(&path).with_context(|| {
                format!(
                    "'{name}' is neither a built-in scene ({}) nor a readable scene file",
                    scene::BUILTIN_SCENES.join(", ")
                )
            })?;
            SceneSpec::from_toml(&text, &path)?
        }
    };
    let bytes = read_mesh_bytes(&spec)?;
    // A station cuts: the force model and the blade contact are what it renders.
    spec.features.cutting = true;
    Ok(scene::build_scene(&spec, bytes.as_deref(), &mut Silent)?)
}
