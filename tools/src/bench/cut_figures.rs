//! `scalpel bench cut-figures`: the physical cut's force curve on each organ beside the
//! formula's (issue 41, "Measured"), and the incision as it opens: renders at a quarter,
//! half, three quarters and the end of the stroke and two seconds after the blade left.

use std::path::Path;

use anyhow::Context;
use plotters::style::RGBColor;
use scalpel_client::render::{Image, RenderOptions};
use scalpel_sim::force::CutPhase;
use scalpel_sim::pipeline::{CutScript, Keyframe, start_surface};
use scalpel_sim::scene::BuiltScene;

use crate::bench::cutting::organ_spec;
use crate::cut_cmd::{self, incision_camera, render_drawn};
use crate::cutrun::{self, CutRun};
use crate::plot::{self, Series};
use crate::{export, load};

/// The organs drawn.
const ORGANS: [&str; 3] = ["liver", "shoulder", "cerebroma"];
/// How long the script holds the blade out of the tissue at its end (s).
const AFTER_S: f64 = 2.0;
/// A surface kept every this many ticks, for the renders.
const SNAPSHOT_EVERY: usize = 50;
/// Each panel of a sequence (pixels).
const PANEL: (u32, u32) = (480, 360);
/// The physical cut's colour, and the formula's grey.
const PHYSICAL: RGBColor = RGBColor(200, 30, 30);
const FORMULA: RGBColor = RGBColor(160, 160, 160);

/// The built-in organ `name`, with the physical cut (on its own stiffening) or the formula.
fn organ(name: &str, fracture: bool) -> anyhow::Result<BuiltScene> {
    let spec = organ_spec(name, fracture.then_some(None))?;
    Ok(load::build_with_progress(&spec)?.scene)
}

/// The organ's default stroke, then the blade held where it ended for [`AFTER_S`].
fn stroke_and_after(scene: &BuiltScene) -> anyhow::Result<CutScript> {
    let mut script = CutScript::default_for(&start_surface(scene))?;
    let last = *script.keyframes.last().context("an empty script")?;
    script.keyframes.push(Keyframe {
        t_s: last.t_s + AFTER_S,
        ..last
    });
    script.description += &format!(", then {AFTER_S} s out of the tissue");
    Ok(script)
}

/// `scalpel bench cut-figures --out DIR`.
pub fn cut_figures(out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    for name in ORGANS {
        let formula_scene = organ(name, false)?;
        let script = stroke_and_after(&formula_scene)?;
        let formula = cut_cmd::run_with_progress(&formula_scene, &script, 1, 0)?;
        let physical_scene = organ(name, true)?;
        let physical = cut_cmd::run_with_progress(&physical_scene, &script, 1, SNAPSHOT_EVERY)?;
        let plot_path = out.join(format!("cut-force-{name}.png"));
        plot_forces(name, &physical, &formula, &plot_path)?;
        let sequence_path = out.join(format!("cut-sequence-{name}.png"));
        let at = render_sequence(&physical, &sequence_path)?;
        let m = cutrun::metrics(
            &physical_scene,
            &physical,
            physical_scene.spec.force.ripple_wavelength_m,
        );
        println!(
            "{name}: {} (physical cut: steady {:.2} N at {:.1} mm; panels at ticks {at:?}); wrote {} and {}",
            script.description,
            m.steady_force_n,
            m.steady_depth_mm,
            plot_path.display(),
            sequence_path.display()
        );
    }
    Ok(())
}

/// |F| against travel: the physical cut, and the formula's in grey.
fn plot_forces(name: &str, physical: &CutRun, formula: &CutRun, path: &Path) -> anyhow::Result<()> {
    let curve = |run: &CutRun| -> Vec<(f64, f64)> {
        run.rows
            .iter()
            .map(|r| (r.travel_m * 1e3, r.force_mag_n))
            .collect()
    };
    let formula = Series {
        label: "the formula's (J_c·d + friction + ripple)".into(),
        points: curve(formula),
    };
    let physical = Series {
        label: "fracture by energy: the tissue's push".into(),
        points: curve(physical),
    };
    plot::lines_coloured(
        path,
        &format!("{name}: force on the blade, fracture by energy (formula in grey)"),
        "blade travel (mm)",
        "force (N)",
        &[(&formula, FORMULA), (&physical, PHYSICAL)],
    )
}

/// The ticks the sequence shows: a quarter, half, three quarters and the end of the time
/// the blade cut (first to last tick in the tissue), and the run's end.
fn sequence_ticks(run: &CutRun) -> Option<[usize; 5]> {
    let cutting: Vec<usize> = (0..run.rows.len())
        .filter(|&k| run.rows[k].in_tissue && run.rows[k].phase == CutPhase::Cutting)
        .collect();
    let (&first, &last) = (cutting.first()?, cutting.last()?);
    let at = |f: f64| first + ((last - first) as f64 * f).round() as usize;
    Some([at(0.25), at(0.5), at(0.75), last, run.rows.len() - 1])
}

/// Renders the sequence side by side with one camera (the one `incision.png` takes),
/// each panel the kept surface nearest its tick; returns the ticks drawn.
fn render_sequence(run: &CutRun, path: &Path) -> anyhow::Result<Vec<usize>> {
    let ticks = sequence_ticks(run).context("the blade never cut")?;
    let camera = incision_camera(run);
    let options = RenderOptions {
        width: PANEL.0,
        height: PANEL.1,
        ..RenderOptions::default()
    };
    let mut panels = Vec::new();
    let mut drawn_at = Vec::new();
    for tick in ticks {
        let snap = run
            .snapshots
            .iter()
            .min_by_key(|s| s.tick.abs_diff(tick))
            .context("no surface was kept")?;
        panels.push(render_drawn(&snap.mesh, &snap.kinds, &camera, &options)?);
        drawn_at.push(snap.tick);
    }
    export::save_png(&side_by_side(&panels), path)?;
    Ok(drawn_at)
}

/// Images of one height side by side.
fn side_by_side(panels: &[Image]) -> Image {
    let height = panels.iter().map(|p| p.height).max().unwrap_or(0);
    let width: u32 = panels.iter().map(|p| p.width).sum();
    let mut rgba = vec![0; 4 * width as usize * height as usize];
    let mut x0 = 0usize;
    for p in panels {
        for y in 0..p.height as usize {
            let row = 4 * p.width as usize;
            let from = &p.rgba[y * row..(y + 1) * row];
            let at = 4 * (y * width as usize + x0);
            rgba[at..at + row].copy_from_slice(from);
        }
        x0 += p.width as usize;
    }
    Image {
        width,
        height,
        rgba,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two panels side by side keep their pixels where they were, shifted.
    #[test]
    fn panels_are_laid_side_by_side() {
        let panel = |w: u32, h: u32, v: u8| Image {
            width: w,
            height: h,
            rgba: vec![v; 4 * (w * h) as usize],
        };
        let both = side_by_side(&[panel(2, 3, 10), panel(3, 3, 20)]);
        assert_eq!((both.width, both.height), (5, 3));
        assert_eq!(both.pixel(1, 2), [10; 4]);
        assert_eq!(both.pixel(2, 0), [20; 4]);
        assert_eq!(both.pixel(4, 2), [20; 4]);
    }
}
