//! Scene files (TOML). Every key is optional except a mesh source; unknown keys are
//! rejected, and every value is range-checked with a message that names the key. A file may
//! start from a built-in scene with `extends = "liver"` and change only what it lists.
//! The keys are documented in docs/SCENES.md.

mod supports;

use std::path::Path;

use serde::Deserialize;
use thiserror::Error;

use super::{BuiltinMesh, Integrator, MeshSource, RemeshRule, SceneSpec, builtin, for_mesh_file};
use crate::geometry::LengthUnit;
use crate::model::{MAX_POINTS, SpacingRule};

/// Why a scene file was rejected.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum SceneError {
    /// Not valid TOML, a key of the wrong type, or an unknown key.
    #[error("{file}: {message}")]
    Parse {
        /// Scene file.
        file: String,
        /// The parser's message, with line and column.
        message: String,
    },
    /// A value is out of range or inconsistent with another.
    #[error("{file}: {key}: {message}")]
    Invalid {
        /// Scene file.
        file: String,
        /// Dotted key, e.g. `material.poisson_ratio`.
        key: String,
        /// What is wrong and what is allowed.
        message: String,
    },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    name: Option<String>,
    description: Option<String>,
    extends: Option<String>,
    mesh: Option<RawMesh>,
    material: Option<RawMaterial>,
    sampling: Option<RawSampling>,
    features: Option<RawFeatures>,
    tool: Option<RawTool>,
    force: Option<RawForce>,
    solver: Option<RawSolver>,
    loads: Option<supports::RawLoads>,
    supports: Option<supports::RawSupports>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMesh {
    builtin: Option<String>,
    file: Option<String>,
    units: Option<LengthUnit>,
    scale: Option<Scale>,
    rotate_deg: Option<[f64; 3]>,
    translate_mm: Option<[f64; 3]>,
    max_triangles: Option<usize>,
    max_file_mb: Option<f64>,
    check_self_intersections: Option<bool>,
    remesh: Option<RawRemesh>,
}

/// `remesh = "auto"`, `"off"`, or a target edge length in mm.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum RawRemesh {
    Word(String),
    EdgeMm(f64),
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum Scale {
    Uniform(f64),
    PerAxis([f64; 3]),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMaterial {
    youngs_modulus_kpa: Option<f64>,
    poisson_ratio: Option<f64>,
    density_kg_m3: Option<f64>,
    damping_per_s: Option<f64>,
    stiffening: Option<f64>,
    prestrain: Option<f64>,
    prestrain_depth_mm: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSampling {
    spacing_mm: Option<f64>,
    target_points: Option<usize>,
    real_time_points: Option<usize>,
    support_ratio: Option<f64>,
    min_cell_fraction: Option<f64>,
    neighbour_headroom: Option<usize>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFeatures {
    cutting: Option<bool>,
    haptics: Option<bool>,
    virtual_points: Option<bool>,
    ripple: Option<bool>,
    volume_term: Option<bool>,
    stiff_mode: Option<bool>,
    frames: Option<bool>,
    observers: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTool {
    blade_length_mm: Option<f64>,
    blade_width_mm: Option<f64>,
    blade_thickness_mm: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawForce {
    rupture_force_n: Option<f64>,
    rupture_displacement_mm: Option<f64>,
    toughness_n_per_mm: Option<f64>,
    fracture_by_energy: Option<bool>,
    crack_tip_stiffening: Option<f64>,
    friction_n: Option<f64>,
    friction_depth_mm: Option<f64>,
    ripple_amplitude: Option<f64>,
    ripple_wavelength_mm: Option<f64>,
    ripple_decay_s: Option<f64>,
    crack_transparency: Option<f64>,
    motion_deadband_mm: Option<f64>,
    max_force_n: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSolver {
    mass_scaling_percent: Option<f64>,
    integrator: Option<String>,
}

/// Checks values against ranges and names the key on failure.
struct Checker<'a> {
    file: &'a str,
}

impl Checker<'_> {
    fn fail(&self, key: &str, message: impl Into<String>) -> SceneError {
        SceneError::Invalid {
            file: self.file.to_string(),
            key: key.to_string(),
            message: message.into(),
        }
    }

    /// Checks `value` against `limit`.
    fn check(&self, key: &str, value: f64, limit: Limit) -> Result<f64, SceneError> {
        let Limit {
            lo,
            hi,
            open_lo,
            unit,
        } = limit;
        let above_lo = if open_lo { value > lo } else { value >= lo };
        if value.is_finite() && above_lo && value <= hi {
            return Ok(value);
        }
        let bracket = if open_lo { "(" } else { "[" };
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        Err(self.fail(
            key,
            format!(
                "{}{unit} is out of range; allowed {bracket}{lo}, {hi}]{unit}",
                readable_number(value)
            ),
        ))
    }

    /// When `value` is given, checks it and stores `value × to_si` in `slot`.
    fn set(
        &self,
        slot: &mut f64,
        value: Option<f64>,
        key: &str,
        limit: Limit,
        to_si: f64,
    ) -> Result<(), SceneError> {
        if let Some(v) = value {
            *slot = self.check(key, v, limit)? * to_si;
        }
        Ok(())
    }
}

/// An allowed range for a number in a scene file, with its unit for messages.
#[derive(Clone, Copy)]
struct Limit {
    lo: f64,
    hi: f64,
    open_lo: bool,
    unit: &'static str,
}

impl Limit {
    /// `(0, hi]`.
    const fn positive(hi: f64, unit: &'static str) -> Self {
        Self {
            lo: 0.0,
            hi,
            open_lo: true,
            unit,
        }
    }

    /// `[lo, hi]`.
    const fn closed(lo: f64, hi: f64, unit: &'static str) -> Self {
        Self {
            lo,
            hi,
            open_lo: false,
            unit,
        }
    }
}

/// mm → m.
const MM: f64 = 1e-3;

/// `v` as people read it in a message: plain, or in exponent form when plain would run to
/// hundreds of digits (`1e200`, `1e-300`).
pub fn readable_number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e9).contains(&v.abs()) {
        v.to_string()
    } else {
        format!("{v:e}")
    }
}

/// The largest force a scene or a server may ever send to a haptic device (N).
pub const MAX_DEVICE_FORCE_N: f64 = 50.0;

impl SceneSpec {
    /// Reads a scene from TOML `text`. `path` is the scene file: it names the file in messages
    /// and relative mesh paths are resolved against its folder.
    pub fn from_toml(text: &str, path: &Path) -> Result<SceneSpec, SceneError> {
        let file = path.display().to_string();
        let raw: RawScene = toml::from_str(text).map_err(|e| SceneError::Parse {
            file: file.clone(),
            message: e.to_string().trim_end().to_string(),
        })?;
        let check = Checker { file: &file };

        let mut spec = match &raw.extends {
            Some(name) => builtin(name).ok_or_else(|| {
                check.fail(
                    "extends",
                    format!(
                        "'{name}' is not a built-in scene; choose one of {}",
                        super::BUILTIN_SCENES.join(", ")
                    ),
                )
            })?,
            None => for_mesh_file(Default::default(), LengthUnit::M),
        };
        if raw.name.as_ref().is_some_and(|n| n.trim().is_empty()) {
            return Err(check.fail(
                "name",
                "must not be empty (leave it out for the file's name)",
            ));
        }
        spec.name = raw.name.clone().unwrap_or_else(|| {
            path.file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or("scene")
                .to_string()
        });
        // A scene that extends a built-in organ but swaps its mesh is no longer that organ:
        // its description must not say it is.
        let mesh_replaced = raw
            .mesh
            .as_ref()
            .is_some_and(|m| m.builtin.is_some() || m.file.is_some());
        if let Some(d) = raw.description {
            spec.description = d;
        } else if raw.extends.is_none() || mesh_replaced {
            spec.description = format!("scene file {file}");
        }

        apply_mesh(
            &mut spec,
            raw.mesh.as_ref(),
            raw.extends.is_some(),
            path,
            &check,
        )?;
        if let Some(m) = &raw.material {
            apply_material(&mut spec, m, &check)?;
        }
        if let Some(s) = &raw.sampling {
            apply_sampling(&mut spec, s, &check)?;
        }
        if let Some(f) = &raw.features {
            apply_features(&mut spec, f)?;
        }
        for (on, name) in [
            (spec.features.virtual_points, "virtual_points"),
            (spec.features.ripple, "ripple"),
        ] {
            if on && !spec.features.cutting {
                return Err(check.fail(
                    &format!("features.{name}"),
                    "only makes sense with features.cutting = true",
                ));
            }
        }
        if let Some(t) = &raw.tool {
            apply_tool(&mut spec, t, &check)?;
        }
        if let Some(f) = &raw.force {
            apply_force(&mut spec, f, &check)?;
        }
        if let Some(s) = &raw.solver {
            apply_solver(&mut spec, s, &check)?;
        }
        if let Some(l) = &raw.loads {
            supports::apply_loads(&mut spec, l, &check)?;
        }
        if let Some(s) = &raw.supports {
            supports::apply_supports(&mut spec, s, &check)?;
        }
        if let Some(why) = spec.supports.unable_to_hold(&spec.loads.gravity) {
            return Err(check.fail("supports", why));
        }
        Ok(spec)
    }
}

/// Applies the scene file's `[material]` table to `spec`.
fn apply_material(
    spec: &mut SceneSpec,
    m: &RawMaterial,
    check: &Checker<'_>,
) -> Result<(), SceneError> {
    let mat = &mut spec.material;
    let key = "material.youngs_modulus_kpa";
    check.set(
        &mut mat.youngs_modulus_pa,
        m.youngs_modulus_kpa,
        key,
        Limit::positive(1.0e6, "kPa"),
        1e3,
    )?;
    if let Some(nu) = m.poisson_ratio
        && nu >= 0.5
        && nu.is_finite()
    {
        return Err(check.fail(
            "material.poisson_ratio",
            format!("{nu} makes the material incompressible (λ = ∞); use at most 0.499"),
        ));
    }
    let key = "material.poisson_ratio";
    check.set(
        &mut mat.poisson_ratio,
        m.poisson_ratio,
        key,
        Limit::closed(0.0, 0.499, ""),
        1.0,
    )?;
    let key = "material.density_kg_m3";
    check.set(
        &mut mat.density_kg_m3,
        m.density_kg_m3,
        key,
        Limit::closed(100.0, 5000.0, "kg/m³"),
        1.0,
    )?;
    let key = "material.damping_per_s";
    check.set(
        &mut mat.damping_per_s,
        m.damping_per_s,
        key,
        Limit::closed(0.0, 1000.0, "1/s"),
        1.0,
    )?;
    let key = "material.stiffening";
    check.set(
        &mut mat.stiffening,
        m.stiffening,
        key,
        Limit::closed(0.0, 100.0, ""),
        1.0,
    )?;
    // Beyond 30 % the small-strain prestress (`mls::prestress`) is no longer the growth
    // metric it stands for.
    check.set(
        &mut mat.prestrain,
        m.prestrain,
        "material.prestrain",
        Limit::closed(0.0, 0.3, ""),
        1.0,
    )?;
    if let Some(depth) = m.prestrain_depth_mm {
        let key = "material.prestrain_depth_mm";
        let depth = check.check(key, depth, Limit::positive(100.0, "mm"))?;
        mat.prestrain_depth_m = Some(depth * 1e-3);
    }
    Ok(())
}

/// Applies the scene file's `[sampling]` table to `spec`.
fn apply_sampling(
    spec: &mut SceneSpec,
    s: &RawSampling,
    check: &Checker<'_>,
) -> Result<(), SceneError> {
    let p = &mut spec.sampling;
    let count = |key: &str, n: usize| {
        if (8..=MAX_POINTS).contains(&n) {
            Ok(n)
        } else {
            Err(check.fail(
                key,
                format!("{n} is out of range; allowed 8 to {MAX_POINTS}"),
            ))
        }
    };
    match (s.spacing_mm, s.target_points, s.real_time_points) {
        (Some(mm), None, None) => {
            let limit = Limit::positive(1000.0, "mm");
            p.spacing = SpacingRule::Spacing(check.check("sampling.spacing_mm", mm, limit)? * MM);
        }
        (None, Some(n), None) => {
            p.spacing = SpacingRule::TargetPoints(count("sampling.target_points", n)?);
        }
        (None, None, Some(n)) => {
            let most_points = count("sampling.real_time_points", n)?;
            p.spacing = SpacingRule::RealTime { most_points };
        }
        (None, None, None) => {}
        _ => {
            return Err(check.fail(
                "sampling",
                "give one of spacing_mm, target_points and real_time_points",
            ));
        }
    }
    let key = "sampling.support_ratio";
    check.set(
        &mut p.support_ratio,
        s.support_ratio,
        key,
        Limit::closed(1.2, 4.0, ""),
        1.0,
    )?;
    let key = "sampling.min_cell_fraction";
    check.set(
        &mut p.min_cell_fraction,
        s.min_cell_fraction,
        key,
        Limit::positive(1.0, ""),
        1.0,
    )?;
    if let Some(h) = s.neighbour_headroom {
        if h > 256 {
            return Err(check.fail(
                "sampling.neighbour_headroom",
                format!("{h} is out of range; allowed 0 to 256"),
            ));
        }
        p.neighbour_headroom = h;
    }
    Ok(())
}

/// Applies the scene file's `[features]` table to `spec`.
fn apply_features(spec: &mut SceneSpec, f: &RawFeatures) -> Result<(), SceneError> {
    let out = &mut spec.features;
    let set = |slot: &mut bool, v: Option<bool>| {
        if let Some(v) = v {
            *slot = v;
        }
    };
    set(&mut out.cutting, f.cutting);
    set(&mut out.haptics, f.haptics);
    set(&mut out.virtual_points, f.virtual_points);
    set(&mut out.ripple, f.ripple);
    set(&mut out.volume_term, f.volume_term);
    set(&mut out.stiff_mode, f.stiff_mode);
    set(&mut out.frames, f.frames);
    set(&mut out.observers, f.observers);
    // Turning cutting off turns off what only cutting uses, unless this file asks
    // for it (then the check below says so): `extends = "liver"` with
    // `cutting = false` is a deformation scene, not three errors one at a time.
    if f.cutting == Some(false) {
        if f.virtual_points.is_none() {
            out.virtual_points = false;
        }
        if f.ripple.is_none() {
            out.ripple = false;
        }
    }
    Ok(())
}

/// Applies the scene file's `[tool]` table to `spec`.
fn apply_tool(spec: &mut SceneSpec, t: &RawTool, check: &Checker<'_>) -> Result<(), SceneError> {
    let tool = &mut spec.tool;
    let mm = |hi| Limit::positive(hi, "mm");
    check.set(
        &mut tool.blade_length_m,
        t.blade_length_mm,
        "tool.blade_length_mm",
        mm(200.0),
        MM,
    )?;
    check.set(
        &mut tool.blade_width_m,
        t.blade_width_mm,
        "tool.blade_width_mm",
        mm(100.0),
        MM,
    )?;
    let key = "tool.blade_thickness_mm";
    check.set(
        &mut tool.blade_thickness_m,
        t.blade_thickness_mm,
        key,
        mm(10.0),
        MM,
    )?;
    Ok(())
}

/// Applies the scene file's `[force]` table to `spec`.
fn apply_force(spec: &mut SceneSpec, f: &RawForce, check: &Checker<'_>) -> Result<(), SceneError> {
    let out = &mut spec.force;
    let newtons = Limit::positive(100.0, "N");
    check.set(
        &mut out.rupture_force_n,
        f.rupture_force_n,
        "force.rupture_force_n",
        newtons,
        1.0,
    )?;
    let key = "force.rupture_displacement_mm";
    check.set(
        &mut out.rupture_displacement_m,
        f.rupture_displacement_mm,
        key,
        Limit::positive(100.0, "mm"),
        MM,
    )?;
    // N/mm → N/m.
    let key = "force.toughness_n_per_mm";
    check.set(
        &mut out.toughness_n_per_m,
        f.toughness_n_per_mm,
        key,
        Limit::closed(0.0, 10.0, "N/mm"),
        1e3,
    )?;
    if let Some(on) = f.fracture_by_energy {
        out.fracture_by_energy = on;
    }
    check.set(
        &mut out.crack_tip_stiffening,
        f.crack_tip_stiffening,
        "force.crack_tip_stiffening",
        Limit::closed(1.0, 1000.0, ""),
        1.0,
    )?;
    check.set(
        &mut out.friction_n,
        f.friction_n,
        "force.friction_n",
        Limit::closed(0.0, 50.0, "N"),
        1.0,
    )?;
    check.set(
        &mut out.friction_depth_m,
        f.friction_depth_mm,
        "force.friction_depth_mm",
        Limit::closed(0.1, 200.0, "mm"),
        MM,
    )?;
    let key = "force.ripple_amplitude";
    check.set(
        &mut out.ripple_amplitude,
        f.ripple_amplitude,
        key,
        Limit::closed(0.0, 0.9, ""),
        1.0,
    )?;
    let key = "force.ripple_wavelength_mm";
    check.set(
        &mut out.ripple_wavelength_m,
        f.ripple_wavelength_mm,
        key,
        Limit::positive(100.0, "mm"),
        MM,
    )?;
    let key = "force.ripple_decay_s";
    check.set(
        &mut out.ripple_decay_s,
        f.ripple_decay_s,
        key,
        Limit::positive(600.0, "s"),
        1.0,
    )?;
    check.set(
        &mut out.crack_transparency,
        f.crack_transparency,
        "force.crack_transparency",
        Limit::closed(0.0, 2.0, ""),
        1.0,
    )?;
    check.set(
        &mut out.motion_deadband_m,
        f.motion_deadband_mm,
        "force.motion_deadband_mm",
        // A reversal holds the heading for twice the deadband at the full cutting
        // force: work the tissue does on the hand.
        Limit::closed(0.0, 0.5, "mm"),
        MM,
    )?;
    check.set(
        &mut out.max_force_n,
        f.max_force_n,
        "force.max_force_n",
        // What a device is ever sent: the server's own limit on it
        // (`output.max_force_n`) stops at 50 N too — no desktop haptic device
        // renders more.
        Limit::positive(MAX_DEVICE_FORCE_N, "N"),
        1.0,
    )?;
    Ok(())
}

/// Applies the scene file's `[solver]` table to `spec`.
fn apply_solver(
    spec: &mut SceneSpec,
    s: &RawSolver,
    check: &Checker<'_>,
) -> Result<(), SceneError> {
    check.set(
        &mut spec.solver.mass_scaling_budget,
        s.mass_scaling_percent,
        "solver.mass_scaling_percent",
        // Beyond a few per cent the inertia of the surface layer, not the tissue,
        // sets how the organ swings.
        Limit::closed(0.0, 10.0, "%"),
        0.01,
    )?;
    if let Some(name) = &s.integrator {
        spec.solver.integrator = match name.as_str() {
            "explicit" => Integrator::Explicit,
            "implicit" if spec.features.stiff_mode => {
                return Err(check.fail(
                    "solver.integrator",
                    "`integrator = \"implicit\"` with `[features] stiff_mode = true`: the stiff \
                     mode is the projective integrator; choose one",
                ));
            }
            "implicit" => Integrator::Implicit,
            other => {
                return Err(check.fail(
                    "solver.integrator",
                    format!(
                        "unknown integrator \"{other}\": expected \"explicit\" or \"implicit\" \
                         (the stiff mode is `[features] stiff_mode = true`)"
                    ),
                ));
            }
        };
    }
    Ok(())
}

fn apply_mesh(
    spec: &mut SceneSpec,
    raw: Option<&RawMesh>,
    extends: bool,
    path: &Path,
    check: &Checker<'_>,
) -> Result<(), SceneError> {
    let Some(m) = raw else {
        if extends {
            return Ok(());
        }
        return Err(check.fail(
            "mesh",
            "no mesh: add a [mesh] table with `builtin = \"liver\"` or `file = \"organ.obj\"`, or `extends = \"liver\"`",
        ));
    };
    match (&m.builtin, &m.file) {
        (Some(_), Some(_)) => return Err(check.fail("mesh", "give `builtin` or `file`, not both")),
        (Some(name), None) => {
            let shape = BuiltinMesh::from_name(name).ok_or_else(|| {
                let known: Vec<&str> = BuiltinMesh::ALL.iter().map(|b| b.name()).collect();
                check.fail(
                    "mesh.builtin",
                    format!("unknown shape '{name}'; choose one of {}", known.join(", ")),
                )
            })?;
            spec.mesh.source = MeshSource::Builtin(shape);
        }
        (None, Some(file)) => {
            let base = path.parent().unwrap_or(Path::new(""));
            spec.mesh.source = MeshSource::File(base.join(file));
        }
        (None, None) if !extends => {
            return Err(check.fail(
                "mesh",
                "give `builtin = \"<shape>\"` or `file = \"<path>\"`",
            ));
        }
        (None, None) => {}
    }
    if let Some(u) = m.units {
        spec.mesh.units = u;
    }
    let t = &mut spec.mesh.transform;
    if let Some(scale) = &m.scale {
        let s = match *scale {
            Scale::Uniform(s) => [s; 3],
            Scale::PerAxis(s) => s,
        };
        for (a, v) in s.iter().enumerate() {
            if !v.is_finite() || *v == 0.0 || v.abs() > 1e6 {
                return Err(check.fail(
                    "mesh.scale",
                    format!(
                        "component {a} is {}; scale factors must be finite, non-zero and at most 1e6",
                        readable_number(*v)
                    ),
                ));
            }
        }
        t.scale = s;
    }
    if let Some(r) = m.rotate_deg {
        for (a, v) in r.iter().enumerate() {
            check.check(
                &format!("mesh.rotate_deg[{a}]"),
                *v,
                Limit::closed(-360.0, 360.0, "°"),
            )?;
        }
        t.rotate_deg = r;
    }
    if let Some(tr) = m.translate_mm {
        for (a, v) in tr.iter().enumerate() {
            check.check(
                &format!("mesh.translate_mm[{a}]"),
                *v,
                Limit::closed(-1e5, 1e5, "mm"),
            )?;
        }
        t.translate_m = tr.map(|v| v * MM);
    }
    if let Some(n) = m.max_triangles {
        if !(4..=50_000_000).contains(&n) {
            return Err(check.fail(
                "mesh.max_triangles",
                format!("{n} is out of range; allowed 4 to 50000000"),
            ));
        }
        spec.mesh.limits.max_triangles = n;
    }
    if let Some(mb) = m.max_file_mb {
        spec.mesh.limits.max_file_bytes =
            (check.check("mesh.max_file_mb", mb, Limit::positive(4096.0, "MB"))? * 1048576.0)
                as u64;
    }
    if let Some(c) = m.check_self_intersections {
        spec.mesh.check_self_intersections = c;
    }
    match &m.remesh {
        None => {}
        Some(RawRemesh::Word(w)) if w == "auto" => spec.mesh.remesh = RemeshRule::Auto,
        Some(RawRemesh::Word(w)) if w == "off" => spec.mesh.remesh = RemeshRule::Off,
        Some(RawRemesh::Word(w)) => {
            return Err(check.fail(
                "mesh.remesh",
                format!("\"{w}\" is not a choice; give \"auto\", \"off\" or an edge length in mm"),
            ));
        }
        Some(RawRemesh::EdgeMm(mm)) => {
            let mm = check.check("mesh.remesh", *mm, Limit::positive(1e4, "mm"))?;
            spec.mesh.remesh = RemeshRule::EdgeM(mm * MM);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
