//! `scalpel probe`: a flat punch (or the blade) pressed quasi-statically into the
//! supported organ; the force the tissue puts back on it, its stiffness and the
//! half-space's beside it.

use anyhow::{Context, bail};
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::probe::{ProbeReport, ProbeSpec, probe};
use scalpel_sim::scene::supports::STANDARD_GRAVITY;
use scalpel_sim::solver::contact::ToolShape;
use serde::Serialize;

use crate::{TargetArgs, load};

/// What `scalpel probe --json` prints.
#[derive(Serialize)]
struct ProbeOutput {
    scene: String,
    youngs_kpa: f64,
    poisson_ratio: f64,
    gravity_m_s2: [f64; 3],
    /// Whether the scene had gravity off and standard gravity was used.
    gravity_added: bool,
    #[serde(flatten)]
    report: ProbeReport,
}

/// What to press and how (mm and kPa).
#[derive(clap::Args)]
pub struct ProbeArgs {
    /// Where to press: a point on or near the surface, X,Y,Z in mm (default: the top of
    /// the organ above the middle of its bounding box).
    #[arg(long, allow_hyphen_values = true)]
    pub at: Option<String>,
    /// Punch radius (mm).
    #[arg(long, default_value_t = 5.0)]
    pub radius_mm: f64,
    /// Depth past first touch (mm).
    #[arg(long, default_value_t = 3.0)]
    pub depth_mm: f64,
    /// Static solves on the way down.
    #[arg(long, default_value_t = 6)]
    pub steps: u32,
    /// Press the scene's blade ([tool] sizes), edge first along the scene's x, instead of
    /// the punch.
    #[arg(long)]
    pub blade: bool,
    /// Young's modulus in kPa (overrides the scene's material).
    #[arg(long)]
    pub youngs_kpa: Option<f64>,
    /// Print {force_n, stiffness_n_per_mm, analytic_n_per_mm, contact_points,
    /// max_det_f_loss, curve, ...} as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `scalpel probe`.
pub fn run(target: &TargetArgs, args: &ProbeArgs) -> anyhow::Result<()> {
    let mut spec = load::resolve(target)?;
    if let Some(kpa) = args.youngs_kpa {
        if !(kpa.is_finite() && (0.1..=1000.0).contains(&kpa)) {
            bail!("--youngs-kpa {kpa}: must be within 0.1 to 1000 kPa");
        }
        spec.material.youngs_modulus_pa = kpa * 1e3;
    }
    // On its supports as it rests under gravity: standard gravity when the scene has none.
    let gravity_added = spec.loads.gravity == Vec3::zeros();
    if gravity_added {
        spec.loads.gravity = STANDARD_GRAVITY;
    }
    if let Some(why) = spec.supports.unable_to_hold(&spec.loads.gravity) {
        bail!(
            "scene '{}': {why} (a probe presses a body resting on its supports, under standard gravity when the scene has none)",
            spec.name
        );
    }
    let at = args.at.as_deref().map(parse_point).transpose()?;
    let built = load::build_with_progress(&spec)?;
    let probe_spec = ProbeSpec {
        at: at.map(|x| x * 1e-3),
        axis: None,
        radius_m: args.radius_mm * 1e-3,
        blade: args.blade.then_some(ToolShape::Blade {
            length: spec.tool.blade_length_m,
            width: spec.tool.blade_width_m,
            thickness: spec.tool.blade_thickness_m,
        }),
        depth_m: args.depth_mm * 1e-3,
        steps: args.steps,
    };
    let report = probe(&built.scene, &probe_spec)
        .with_context(|| format!("cannot probe scene '{}'", spec.name))?;
    if args.json {
        let output = ProbeOutput {
            scene: spec.name.clone(),
            youngs_kpa: spec.material.youngs_modulus_pa * 1e-3,
            poisson_ratio: spec.material.poisson_ratio,
            gravity_m_s2: spec.loads.gravity.into(),
            gravity_added,
            report,
        };
        println!("{}", serde_json::to_string_pretty(&output)?);
        return Ok(());
    }
    let [x, y, z] = report.at_mm;
    let tool = match report.radius_mm {
        Some(r) => format!("a {r:.1} mm flat punch"),
        None => "the blade, edge first,".to_string(),
    };
    println!(
        "probe {}: {tool} at ({x:.1}, {y:.1}, {z:.1}) mm, pressed {:.2} mm (E = {:.1} kPa, ν = {:.3}; on its supports under {})",
        spec.name,
        report.depth_mm,
        spec.material.youngs_modulus_pa * 1e-3,
        spec.material.poisson_ratio,
        if gravity_added {
            "standard gravity (the scene has none)"
        } else {
            "the scene's gravity"
        }
    );
    println!(
        "  force {:.4} N; stiffness {:.4} N/mm (secant {:.4}){}",
        report.force_n,
        report.stiffness_n_per_mm,
        report.secant_n_per_mm,
        report.analytic_n_per_mm.map_or(String::new(), |k| format!(
            "; half-space 2aE/(1−ν²) {k:.4} N/mm"
        ))
    );
    println!(
        "  {} of {} surface samples touching, penalty give {:.4} mm, largest volume loss 1 − det F = {:.3}",
        report.contact_points, report.samples, report.max_penetration_mm, report.max_det_f_loss
    );
    println!(
        "  {} Newton / {} CG iterations, residual {:.2e} N{}",
        report.newton_iterations,
        report.cg_iterations,
        report.residual_n,
        if report.converged {
            ""
        } else {
            " (NOT converged)"
        }
    );
    Ok(())
}

/// `X,Y,Z` (mm).
fn parse_point(text: &str) -> anyhow::Result<Vec3> {
    let parts: Vec<f64> = text
        .split(',')
        .map(|s| s.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--at {text:?}: expected X,Y,Z in mm"))?;
    match parts[..] {
        [x, y, z] if parts.iter().all(|v| v.is_finite()) => Ok(Vec3::new(x, y, z)),
        _ => bail!("--at {text:?}: expected three finite numbers X,Y,Z in mm"),
    }
}
