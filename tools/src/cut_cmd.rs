//! `scalpel cut`: a scripted cut, offline, with everything it produced written out.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use scalpel_client::render::{Camera, RenderOptions, SurfaceView, render};
use scalpel_sim::cut::FaceKind;
use scalpel_sim::geometry::TriMesh;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::CutScript;
use scalpel_sim::scene::{BuiltScene, Features, SceneSpec};

use crate::cutrun::{self, CutMetrics, CutRun};
use crate::plot::{self, Series};
use crate::{TargetArgs, export, load};

/// Colours of the render: skin, wound wall (linear RGB).
const PALETTE: [[f32; 3]; 2] = [[0.50, 0.14, 0.11], [0.93, 0.62, 0.52]];

/// The most strokes a session may have: each keeps its figures (about 1 MB of them) and
/// takes seconds of simulated time.
pub const MAX_SESSION_STROKES: usize = 1000;

/// What a run plays.
pub enum ScriptChoice {
    /// The scene's default stroke.
    Default,
    /// A script file.
    File(PathBuf),
    /// A session of strokes drawn from a seed.
    Session {
        /// Strokes.
        strokes: usize,
        /// Seed.
        seed: u64,
    },
}

/// The script of a run.
pub fn script_for(scene: &BuiltScene, choice: &ScriptChoice) -> anyhow::Result<CutScript> {
    let surface = &scalpel_sim::pipeline::start_surface(scene);
    Ok(match choice {
        ScriptChoice::Default => CutScript::default_for(surface)?,
        ScriptChoice::File(path) => scalpel_server::scene_file::load_script(path)?,
        ScriptChoice::Session { strokes, seed } => {
            anyhow::ensure!(
                (1..=MAX_SESSION_STROKES).contains(strokes),
                "--strokes must be 1 to {MAX_SESSION_STROKES} (a lab session is tens), got {strokes}"
            );
            CutScript::session_for(surface, *strokes, *seed)?
        }
    })
}

/// The scene `target` names, as a cutting station cuts it: a bare mesh file gets the
/// station's cutting features (a scene file chooses its own); an error if it does not cut.
pub fn cutting_spec(target: &TargetArgs) -> anyhow::Result<SceneSpec> {
    let mut spec = load::resolve(target)?;
    if load::is_bare_mesh(target) {
        let station = Features::CUTTING_STATION;
        spec.features.cutting = true;
        spec.features.virtual_points = station.virtual_points;
        spec.features.ripple = station.ripple;
    }
    if !spec.features.cutting {
        bail!(
            "scene '{}' does not cut (features.cutting = false); cutting scenes: liver, shoulder, cerebroma, and any mesh file",
            spec.name
        );
    }
    Ok(spec)
}

/// Runs `script` on the built scene with a progress bar (on a terminal), and says once on
/// stderr — terminal or not — when the run will take long: a stiff scene's single tick can
/// take minutes.
pub fn run_with_progress(
    scene: &BuiltScene,
    script: &CutScript,
    threads: usize,
    snapshot_every: usize,
) -> anyhow::Result<CutRun> {
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let bar = ProgressBar::hidden();
    let done_ticks = AtomicUsize::new(0);
    let finished = AtomicBool::new(false);
    let total = script.tick_count(cutrun::TICK_S);
    std::thread::scope(|scope| {
        scope.spawn(|| say_the_pace(&done_ticks, total, &finished, &bar));
        let run = cutrun::run_cut(scene, script, threads, snapshot_every, |done, total| {
            if done == 1 {
                bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
                bar.set_length(total as u64);
                bar.set_style(
                    ProgressStyle::with_template("cutting {bar:40} {pos}/{len} ticks {eta}")
                        .unwrap_or_else(|_| ProgressStyle::default_bar()),
                );
            }
            // Every tick (indicatif limits the redrawing itself).
            bar.set_position(done as u64);
            done_ticks.store(done, Ordering::Relaxed);
        });
        finished.store(true, Ordering::Relaxed);
        bar.finish_and_clear();
        run
    })
}

/// Says once when the run will take long: a tick that has run for [`SLOW_TICK_S`], or, after
/// that long, the ticks left projected to take over a minute at the pace since the last
/// look (a cut's approach ticks are free, its ticks in the tissue are not).
fn say_the_pace(
    done: &std::sync::atomic::AtomicUsize,
    total: usize,
    finished: &std::sync::atomic::AtomicBool,
    bar: &ProgressBar,
) {
    use std::sync::atomic::Ordering;
    use std::time::{Duration, Instant};
    const SLOW_TICK_S: f64 = 3.0;
    let mut last = (0, Instant::now());
    while !finished.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(50));
        let now = done.load(Ordering::Relaxed);
        let waited = last.1.elapsed().as_secs_f64();
        let message = if now == last.0 {
            if waited < SLOW_TICK_S {
                continue;
            }
            format!(
                "scalpel: tick {} of {total} has run for {waited:.0} s: this scene is too stiff (or too fine) for its time step (`scalpel scene inspect` shows the sub-steps a tick plans); Ctrl-C stops",
                now + 1
            )
        } else {
            if waited < SLOW_TICK_S {
                continue;
            }
            let per_tick = waited / (now - last.0) as f64;
            let left = per_tick * (total - now) as f64;
            last = (now, Instant::now());
            if left <= 60.0 {
                continue;
            }
            format!(
                "scalpel: at this pace the {} ticks left take about {:.0} min ({:.1} ms a tick; `scalpel scene inspect` shows the sub-steps a tick plans); Ctrl-C stops",
                total - now,
                left / 60.0,
                per_tick * 1e3
            )
        };
        bar.suspend(|| eprintln!("{message}"));
        return;
    }
}

/// The surface's bounding box as "x0..x1 × y0..y1 × z0..z1" in mm.
fn bbox_mm(surface: &TriMesh) -> String {
    let b = surface.bbox();
    (0..3)
        .map(|i| format!("{:.0}..{:.0}", b.min[i] * 1e3, b.max[i] * 1e3))
        .collect::<Vec<_>>()
        .join(" × ")
}

/// `scalpel cut`.
pub fn run(
    target: &TargetArgs,
    script: &ScriptChoice,
    out: &Path,
    mesh_format: &str,
    threads: usize,
    json: bool,
) -> anyhow::Result<()> {
    let spec = cutting_spec(target)?;
    let timed = load::build_with_progress(&spec)?;
    let scene = &timed.scene;
    // (On stderr: what was done to the surface before cutting it, such as a scan remeshed.)
    for w in &scene.mesh_warnings {
        eprintln!("mesh: {w}");
    }
    let script = script_for(scene, script)?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    // What the run writes, checked before it runs (a folder in the way failed after it).
    let outputs = [
        "metrics.json".to_string(),
        "force.csv".into(),
        "force.png".into(),
        format!("incision.{mesh_format}"),
        "incision.png".into(),
    ];
    for name in &outputs {
        let path = out.join(name);
        if path.is_dir() {
            bail!(
                "{} is a folder: the run writes a file there",
                path.display()
            );
        }
    }
    let run = run_with_progress(scene, &script, threads, 0)?;
    let metrics = cutrun::metrics(scene, &run, spec.force.ripple_wavelength_m);
    // The figures first: whatever fails later, they are kept.
    let metrics_path = out.join("metrics.json");
    std::fs::write(&metrics_path, serde_json::to_string_pretty(&metrics)?)
        .with_context(|| format!("cannot write {}", metrics_path.display()))?;
    if metrics.cut_steps == 0 {
        eprintln!(
            "scalpel: the blade never reached the tissue ({}); the organ spans {} mm",
            script.description,
            bbox_mm(&scene.model.surface)
        );
    }

    let csv = out.join("force.csv");
    write_csv(&run, &csv)?;
    let plot_path = out.join("force.png");
    plot_force(&run, &spec.name, &plot_path)?;
    let (drawn, kinds) = run.sim.current_surface().drawn();
    let mesh_path = out.join(format!("incision.{mesh_format}"));
    export::write_cut_surface(
        &drawn,
        &kinds,
        &format!("scalpel cut {}: skin and wound walls", spec.name),
        &mesh_path,
    )?;
    let render_path = out.join("incision.png");
    render_incision(&run, &render_path)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&metrics)?);
    } else {
        print!("{}", text_report(&spec.name, &script, &metrics));
        println!(
            "wrote {}, {}, {}, {}, {}",
            csv.display(),
            plot_path.display(),
            mesh_path.display(),
            render_path.display(),
            metrics_path.display()
        );
    }
    Ok(())
}

fn text_report(name: &str, script: &CutScript, m: &CutMetrics) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "cut {name}: {}", script.description);
    let _ = writeln!(
        s,
        "  {} ticks at 1 kHz, {} with the blade in the tissue",
        m.steps, m.cut_steps
    );
    let _ = writeln!(
        s,
        "  per cut step: surface {:.3} ms median, {:.3} ms p99; internal {:.3} ms median, {:.3} ms p99",
        m.surface_ms.p50, m.surface_ms.p99, m.internal_ms.p50, m.internal_ms.p99
    );
    let _ = writeln!(
        s,
        "  all its work (the re-cut worker's {:.1} ms added to the steps they landed in): {:.3} ms median, {:.3} ms p99, {:.3} ms mean",
        m.recut_worker_ms, m.total_ms.p50, m.total_ms.p99, m.work_per_cut_step_ms
    );
    if let Some(lag) = &m.lip_lag_mm {
        let _ = writeln!(
            s,
            "  the drawn incision trails the blade's entry by {:.1} mm median, {:.1} mm at most",
            lag.p50, lag.max
        );
    }
    if let Some(jump) = m.max_vertex_jump_mm {
        let _ = writeln!(
            s,
            "  the drawn surface jumped {jump:.1} mm at most where the field did not move it ({} tick(s) over 0.5 mm)",
            m.vertex_jumps_over_half_mm
        );
    }
    if let Some(o) = &m.opening_mm {
        let mm = |v: Option<f64>| v.map_or("-".to_string(), |g| format!("{g:.2} mm"));
        let _ = writeln!(
            s,
            "  the lips stand apart {} where the blade enters, {} and {} where it entered one and two seconds before (medians; 0 where no wound is drawn yet)",
            mm(o.at_blade),
            mm(o.after_1s),
            mm(o.after_2s)
        );
    }
    let _ = writeln!(
        s,
        "  force: peak {:.2} N, steady {:.2} N at {:.1} mm deep, ripple ±{:.2} N",
        m.peak_force_n, m.steady_force_n, m.steady_depth_mm, m.ripple_n
    );
    let _ = writeln!(
        s,
        "  steady force per depth {:.3} N/mm (friction {:.2} N of it)",
        m.steady_force_per_depth_n_per_mm, m.steady_friction_n
    );
    if let Some(t) = &m.sawtooth {
        let _ = writeln!(
            s,
            "  sawtooth: {:.1} fractures per 10 mm, mean drop {:.2} N, loading {:.3} N/mm",
            t.drops_per_10mm, t.mean_drop_n, t.loading_slope_n_per_mm
        );
    }
    let _ = writeln!(
        s,
        "  interior: {} pairs cut by {} triangles of Σ, at most {} of {} points integrated, {} left / {} right of the blade",
        m.pairs_removed,
        m.sigma_triangles,
        m.max_active_points,
        m.points,
        m.left_points,
        m.right_points
    );
    match (
        m.min_angle_deg,
        m.lip_max_turn_deg,
        m.wall_depth_mm,
        m.rest_opening_mm,
    ) {
        (Some(angle), Some(turn), Some(depth), Some(opening)) => {
            let _ = writeln!(
                s,
                "  surface: {} incision(s), {} → {} triangles, min angle {angle:.1}°, lip turn ≤ {turn:.1}°, walls ≤ {depth:.1} mm deep, half-opening ≤ {opening:.1} mm, closed {}, manifold {}, oriented {}",
                m.incisions,
                m.triangles_before,
                m.triangles_after,
                m.closed,
                m.manifold,
                m.oriented
            );
        }
        _ => {
            let _ = writeln!(s, "  surface: not opened (the blade never cut far enough)");
        }
    }
    let _ = writeln!(
        s,
        "  time step: {}",
        cutrun::describe_substeps(
            m.substeps_max,
            m.whole_step_mass.as_ref(),
            &m.substep_keeping_mass
        )
    );
    if m.diverged_ticks > 0 || m.rollback_ticks > 0 {
        let _ = writeln!(
            s,
            "  solver: {} tick(s) rolled back and retried with more sub-steps, {} diverged (state restored); attempts rolled back for energy growth {}, speed {}, non-finite values {}; first at tick {}",
            m.rollback_ticks,
            m.diverged_ticks,
            m.guard.energy_growth,
            m.guard.speed,
            m.guard.non_finite,
            m.guard
                .first_tick
                .map_or("-".to_string(), |t| t.to_string())
        );
    }
    s
}

fn write_csv(run: &CutRun, path: &Path) -> anyhow::Result<()> {
    let mut s = String::from(
        "t_s,tip_x_mm,tip_y_mm,tip_z_mm,travel_mm,phase,in_tissue,depth_mm,force_n,fx_n,fy_n,fz_n,surface_ms,internal_ms,active_points,substeps,rollbacks,fractured\n",
    );
    for r in &run.rows {
        let phase = serde_json::to_value(r.phase)?;
        let _ = writeln!(
            s,
            "{:.3},{:.4},{:.4},{:.4},{:.4},{},{},{:.4},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{},{},{},{}",
            r.t_s,
            r.tip_m[0] * 1e3,
            r.tip_m[1] * 1e3,
            r.tip_m[2] * 1e3,
            r.travel_m * 1e3,
            phase.as_str().unwrap_or("?"),
            u8::from(r.in_tissue),
            r.depth_m * 1e3,
            r.force_mag_n,
            r.force_n[0],
            r.force_n[1],
            r.force_n[2],
            r.surface_ms,
            r.internal_ms,
            r.active_points,
            r.substeps,
            r.rollbacks,
            u8::from(r.fractured)
        );
    }
    std::fs::write(path, s).with_context(|| format!("cannot write {}", path.display()))
}

fn plot_force(run: &CutRun, name: &str, path: &Path) -> anyhow::Result<()> {
    let points: Vec<(f64, f64)> = run
        .rows
        .iter()
        .map(|r| (r.travel_m * 1e3, r.force_mag_n))
        .collect();
    let formula: Vec<(f64, f64)> = run
        .rows
        .iter()
        .filter_map(|r| r.formula_n.map(|f| (r.travel_m * 1e3, f)))
        .collect();
    plot::lines(
        path,
        &format!("{name}: force on the blade"),
        "blade travel (mm)",
        "force (N)",
        &[
            Series {
                label: "|F| on the tool".into(),
                points,
            },
            Series {
                label: "eq. 19 loading curve it replaced (pressing)".into(),
                points: formula,
            },
        ],
    )
}

/// Draws the final surface from a camera above the wound, looking across it.
pub fn render_incision(run: &CutRun, path: &Path) -> anyhow::Result<()> {
    let (drawn, kinds) = run.sim.current_surface().drawn();
    let image = render_drawn(
        &drawn,
        &kinds,
        &incision_camera(run),
        &RenderOptions::default(),
    )?;
    export::save_png(&image, path)
}

/// A camera above the run's wound at its end (or the blade's path, or the whole surface),
/// looking across it.
pub fn incision_camera(run: &CutRun) -> Camera {
    let (drawn, _) = run.sim.current_surface().drawn();
    let walls = run.sim.current_surface().wall_corners();
    // Aim at the wound, or at the blade's path when the surface was not opened.
    let focus: Vec<Vec3> = if walls.is_empty() {
        run.rows
            .iter()
            .filter(|r| r.in_tissue)
            .map(|r| Vec3::from(r.tip_m))
            .collect()
    } else {
        walls
    };
    let focus = if focus.is_empty() {
        drawn.positions.clone()
    } else {
        focus
    };
    let lo = focus
        .iter()
        .fold(Vec3::repeat(f64::INFINITY), |a, b| a.inf(b));
    let hi = focus
        .iter()
        .fold(Vec3::repeat(f64::NEG_INFINITY), |a, b| a.sup(b));
    let centre = (lo + hi) * 0.5;
    let extent = (hi - lo).norm().max(0.02);
    // Look across the cut: the camera's azimuth is perpendicular to the wound's long axis.
    let along = hi - lo;
    let axis_deg = along.y.atan2(along.x).to_degrees();
    let fov = 40.0;
    let distance = 0.9 * extent / (0.5 * f64::to_radians(fov)).tan();
    Camera::orbit(centre.into(), distance, 55.0, axis_deg - 70.0, fov)
}

/// Draws a drawn surface (skin and walls, walls in their own colour).
pub fn render_drawn(
    drawn: &TriMesh,
    kinds: &[FaceKind],
    camera: &Camera,
    options: &RenderOptions,
) -> anyhow::Result<scalpel_client::render::Image> {
    let positions: Vec<[f64; 3]> = drawn.positions.iter().map(|p| (*p).into()).collect();
    let materials: Vec<u8> = kinds
        .iter()
        .map(|k| u8::from(*k == FaceKind::Wall))
        .collect();
    let image = render(
        &SurfaceView {
            positions: &positions,
            triangles: &drawn.triangles,
            materials: &materials,
        },
        &PALETTE,
        camera,
        options,
    )?;
    Ok(image)
}
