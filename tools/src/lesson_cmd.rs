//! `scalpel lesson ...` (list, show, script, try) and `scalpel report`: lessons, scripted
//! trainees, and the scored report of a session (docs/LESSONS.md).

use std::path::Path;

use anyhow::{Context, bail};
use scalpel_server::{journal, scene_file};
use scalpel_sim::lesson::{BUILTIN, LessonSpec, Plan, Trainee, trainee_script};
use scalpel_sim::pipeline::{SIMULATION_TICK_S, Simulation, start_surface};
use scalpel_sim::scene::BuiltScene;

use crate::lesson_report::{ScoredSession, summary};

/// `scalpel lesson list`.
pub fn list(json: bool) -> anyhow::Result<()> {
    let lessons: Vec<LessonSpec> = BUILTIN
        .iter()
        .map(|(name, _)| scene_file::load_lesson(name))
        .collect::<anyhow::Result<_>>()?;
    if json {
        let rows: Vec<_> = lessons
            .iter()
            .map(|l| {
                serde_json::json!({
                    "name": l.name, "scene": l.scene, "description": l.description,
                    "incisions": l.incisions.len(), "no_go": l.no_go.len(),
                })
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        for l in &lessons {
            println!("{:<18} {:<10} {}", l.name, l.scene, l.description);
        }
    }
    Ok(())
}

/// The lesson `name` laid on its scene, built as a station builds it.
fn lay(name: &str) -> anyhow::Result<(Plan, BuiltScene)> {
    let spec = scene_file::load_lesson(name)?;
    let scene = scene_file::load_scene(&spec.scene)
        .with_context(|| format!("lesson {name}: its scene {}", spec.scene))?;
    let plan = Plan::new(spec, &scene.model.surface, name)?;
    Ok((plan, scene))
}

/// `scalpel lesson show LESSON`.
pub fn show(name: &str, json: bool) -> anyhow::Result<()> {
    let (plan, _) = lay(name)?;
    let spec = &plan.spec;
    let incisions: Vec<_> = plan
        .incisions
        .iter()
        .map(|c| {
            let (a, b) = (c.samples[0].at * 1e3, c.samples[c.samples.len() - 1].at * 1e3);
            let mid = &c.samples[c.samples.len() / 2];
            let (m, n) = (mid.at * 1e3, mid.out);
            serde_json::json!({
                "name": c.name, "length_mm": (c.length_m * 1e4).round() / 10.0,
                "samples": c.samples.len(), "depth_mm": c.depth_m * 1e3,
                "depth_tolerance_mm": c.depth_tolerance_m * 1e3, "deviation_mm": c.deviation_m * 1e3,
                "start_mm": [a.x, a.y, a.z], "end_mm": [b.x, b.y, b.z],
                "middle_mm": [m.x, m.y, m.z], "middle_normal": [n.x, n.y, n.z],
            })
        })
        .collect();
    let no_go: Vec<_> = spec.no_go.iter().map(|g| g.name.clone()).collect();
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "name": spec.name, "scene": spec.scene, "description": spec.description,
                "time_limit_s": spec.time_limit_s, "planned_length_mm": plan.length_m * 1e3,
                "incisions": incisions, "no_go": no_go,
                "warning_n": spec.force.warning_n, "critical_n": spec.force.critical_n,
            }))?
        );
    } else {
        println!("{} on {}: {}", spec.name, spec.scene, spec.description);
        for c in &plan.incisions {
            println!(
                "  {}: {:.1} mm on the surface, {:.1} ± {:.1} mm deep, within {:.1} mm",
                c.name,
                c.length_m * 1e3,
                c.depth_m * 1e3,
                c.depth_tolerance_m * 1e3,
                c.deviation_m * 1e3
            );
        }
        for g in &spec.no_go {
            println!("  no-go: {}", g.name);
        }
        println!(
            "  force: warning {:.1} N, critical {:.1} N; time limit {:.0} s",
            spec.force.warning_n, spec.force.critical_n, spec.time_limit_s
        );
    }
    Ok(())
}

fn trainee(name: &str) -> anyhow::Result<Trainee> {
    Trainee::from_name(name)
        .with_context(|| format!("no trainee {name:?}: one of careful, hesitant, careless"))
}

/// `scalpel lesson script LESSON --trainee T --out F`: a mock-device script.
pub fn script(name: &str, who: &str, out: &Path) -> anyhow::Result<()> {
    let (plan, scene) = lay(name)?;
    let script = trainee_script(&plan, &start_surface(&scene), trainee(who)?);
    std::fs::write(out, script.to_toml()).with_context(|| format!("writing {}", out.display()))?;
    println!(
        "{}: {} keyframes, {:.1} s",
        out.display(),
        script.keyframes.len(),
        script.duration_s()
    );
    Ok(())
}

/// `scalpel lesson try LESSON (--trainee T | --script F) --out DIR`: the run offline,
/// scored and reported as `scalpel report` reports a station's session.
pub fn try_lesson(
    name: &str,
    who: Option<&str>,
    script_file: Option<&Path>,
    out: &Path,
    json: bool,
) -> anyhow::Result<()> {
    let (plan, scene) = lay(name)?;
    let (script, source) = match (who, script_file) {
        (Some(w), None) => (
            trainee_script(&plan, &start_surface(&scene), trainee(w)?),
            format!("the scripted {w} trainee"),
        ),
        (None, Some(f)) => (
            scene_file::load_script(f)?,
            format!("script {}", f.display()),
        ),
        _ => bail!("give exactly one of --trainee or --script"),
    };
    let mut session = ScoredSession::new(plan);
    let mut sim = Simulation::new(&scene);
    scalpel_server::recut_worker::attach(&mut sim);
    sim.prepare(SIMULATION_TICK_S);
    let mut clock = scalpel_sim::pipeline::NoClock;
    for k in 0..script.tick_count(SIMULATION_TICK_S) {
        sim.handle_tool_pose(Some(script.pose_at(k as f64 * SIMULATION_TICK_S)));
        let report = sim.tick(SIMULATION_TICK_S, &mut clock);
        session.observe(&sim, &report, SIMULATION_TICK_S);
    }
    let trainee_name = who.map(|w| format!("scripted {w}"));
    finish(&session, trainee_name, source, out, json)
}

/// Writes the report into `out` and prints it.
fn finish(
    session: &ScoredSession,
    trainee: Option<String>,
    source: String,
    out: &Path,
    json: bool,
) -> anyhow::Result<()> {
    let report = session.report(trainee, source);
    session.write(&report, out)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("{}", summary(&report));
        println!("report: {}", out.join("report.html").display());
    }
    Ok(())
}

/// `scalpel report JOURNAL [--lesson L] --out DIR`: replays a station's session and scores
/// it on its lesson (the one it journaled, or `--lesson`).
pub fn report(file: &Path, lesson: Option<&str>, out: &Path, json: bool) -> anyhow::Result<()> {
    let recorded = journal::read(file)?;
    let session = score_journal(file, &recorded, lesson)?;
    let trainee = recorded.config_string("trainee");
    finish(
        &session,
        trainee,
        format!("journal {}", file.display()),
        out,
        json,
    )
}

/// Replays `recorded` (read from the journal `file`) and scores it on `lesson` (default:
/// the lesson the station journaled; for a version 1 journal, the station's `lesson` read
/// as it is now). Refused when the replay does not end in the live run's state.
pub fn score_journal(
    file: &Path,
    recorded: &journal::Journal,
    lesson: Option<&str>,
) -> anyhow::Result<ScoredSession> {
    let scene = scene_file::load_scene(&recorded.scene)
        .with_context(|| format!("{}: the scene it names", file.display()))?;
    let plan = journal_plan(file, recorded, lesson, &scene)?;
    let mut session = ScoredSession::new(plan);
    let hash = journal::replay_with(
        &scene,
        recorded,
        &mut scalpel_sim::pipeline::NoClock,
        |_, report, sim| session.observe(sim, report, SIMULATION_TICK_S),
    );
    if let Some((_, live)) = recorded.end
        && live != hash
    {
        bail!(
            "{}: the replay ends in state {hash:016x}, the live session in {live:016x}: \
             the journal does not replay this build's simulation",
            file.display()
        );
    }
    Ok(session)
}

/// The plan a journaled session is scored on.
fn journal_plan(
    file: &Path,
    recorded: &journal::Journal,
    lesson: Option<&str>,
    scene: &BuiltScene,
) -> anyhow::Result<Plan> {
    let named = recorded.config_string("lesson");
    if lesson.is_none() && !recorded.lesson.is_empty() {
        // The lesson as the station read it, on the scene it ran (the station checked that
        // the lesson is for it).
        let name = named.unwrap_or_else(|| "journaled".into());
        let mut spec = LessonSpec::from_toml(
            &recorded.lesson,
            &format!("{} (its lesson {name})", file.display()),
        )?;
        spec.scene = recorded.scene.clone();
        return Ok(Plan::new(spec, &scene.model.surface, &name)?);
    }
    let lesson = match lesson.map(str::to_string).or(named) {
        Some(l) => l,
        None => bail!(
            "{}: the station ran no lesson (its `lesson` key is empty): give --lesson",
            file.display()
        ),
    };
    let spec = scene_file::load_lesson(&lesson)?;
    if !scene_file::same_scene(&spec.scene, &recorded.scene) {
        bail!(
            "{}: the session ran scene {:?}, lesson {} is for {:?}",
            file.display(),
            recorded.scene,
            spec.name,
            spec.scene
        );
    }
    Ok(Plan::new(spec, &scene.model.surface, &lesson)?)
}
