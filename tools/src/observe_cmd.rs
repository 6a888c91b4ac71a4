//! `scalpel observe ADDR --certs DIR --name NAME [--frames] [--seconds S] [--plain | --json]`:
//! a remote observer in the terminal. On a terminal, a live view (`observe_tui`: figures,
//! force and jitter charts, events); with `--plain` or when the output is not a terminal, a
//! line of figures a second and events as they happen; with `--json`, every update as a
//! JSON line (docs/PROTOCOL.md, "Remote clients").

use std::time::{Duration, Instant};

use anyhow::Context;
use scalpel_client::remote::{Observer, Update};
use scalpel_proto::wire::{LessonPlan, LessonScore};

use crate::remote_target::RemoteTarget;

/// What to observe and how.
pub struct ObserveArgs<'a> {
    /// The server, and this observer's certificate.
    pub target: &'a RemoteTarget,
    /// Ask for frames.
    pub frames: bool,
    /// Stop after this long.
    pub seconds: Option<f64>,
    /// JSON lines.
    pub json: bool,
    /// Lines of text even on a terminal.
    pub plain: bool,
}

/// Runs the observer.
pub fn run(args: &ObserveArgs<'_>) -> anyhow::Result<()> {
    let addr = args.target.socket_addr()?;
    RemoteTarget::runtime()?.block_on(observe(args, addr))
}

async fn observe(args: &ObserveArgs<'_>, addr: std::net::SocketAddr) -> anyhow::Result<()> {
    let t = args.target;
    let mut observer = Observer::connect(addr, &t.server_name, &t.credentials(), &t.name)
        .await
        .with_context(|| format!("cannot observe {}", t.addr))?;
    let w = observer.0.welcome().clone();
    let live = !args.json && !args.plain && std::io::IsTerminal::is_terminal(&std::io::stdout());
    if live {
        // Frames for the frame rate figure: the view is an observer's, like any other.
        observer
            .0
            .subscribe(if args.frames { 30.0 } else { 0.0 })
            .await?;
        let result = crate::observe_tui::run(&mut observer, args.seconds).await;
        observer.0.close_and_wait().await;
        return result;
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({"welcome": {"station": w.station, "scene": w.scene, "role": format!("{:?}", w.role), "identity": w.identity}})
        );
    } else {
        println!(
            "observing station {} (scene {}) as {} ({:?})",
            w.station, w.scene, w.identity, w.role
        );
    }
    if args.frames {
        observer.0.subscribe(30.0).await?;
    }
    let started = Instant::now();
    let end = args.seconds.map(|s| started + Duration::from_secs_f64(s));
    let mut frames = 0u64;
    let mut last_line = Instant::now() - Duration::from_secs(1);
    let mut last_score = last_line;
    let mut lesson = None;
    loop {
        let left = end.map(|e| e.saturating_duration_since(Instant::now()));
        if left == Some(Duration::ZERO) {
            break;
        }
        let update = match left {
            Some(l) => match tokio::time::timeout(l, observer.0.next()).await {
                Ok(u) => u,
                Err(_) => break,
            },
            None => observer.0.next().await,
        };
        let Some(update) = update else {
            println!("connection closed: {}", observer.0.closed().await);
            break;
        };
        match update {
            Update::Metrics(m) => {
                if args.json {
                    println!("{}", serde_json::json!({ "metrics": m }));
                } else if last_line.elapsed() >= Duration::from_secs(1) {
                    last_line = Instant::now();
                    println!(
                        "{:7.1} s  tick {}  haptic {:6.1} Hz  jitter p99 {:.3} ms  misses {}  force {:.2} N{}  cut {:.1} mm  {} points{}  frames {}",
                        m.uptime_s,
                        m.sim_tick,
                        m.haptic_rate_hz,
                        m.jitter_p99_ms,
                        m.deadline_misses,
                        m.force_n,
                        if m.faded { " (faded)" } else { "" },
                        m.cut_length_mm,
                        m.active_points,
                        if m.device_connected {
                            ""
                        } else {
                            "  no device"
                        },
                        frames
                    );
                }
            }
            Update::Event(e) => {
                if args.json {
                    println!("{}", serde_json::json!({ "event": e }));
                } else {
                    println!("{:7.1} s  event {:?}: {}", e.uptime_s, e.kind, e.detail);
                }
            }
            Update::Lesson(plan) => {
                if args.json {
                    println!("{}", serde_json::json!({ "lesson": plan }));
                } else {
                    println!("{}", lesson_line(&plan));
                }
                lesson = Some(plan);
            }
            Update::Score(s) => {
                if args.json {
                    println!("{}", serde_json::json!({ "score": s }));
                } else if lesson.is_some() && last_score.elapsed() >= Duration::from_secs(1) {
                    last_score = Instant::now();
                    println!(
                        "{:7.1} s  score {:.0} {}  {}",
                        started.elapsed().as_secs_f64(),
                        s.score,
                        if s.passed { "pass" } else { "not passing" },
                        score_line(&s)
                    );
                }
            }
            Update::Frame(f) => {
                frames += 1;
                if args.json {
                    let wound = f.topology.materials.iter().filter(|&&m| m == 1).count();
                    println!(
                        "{}",
                        serde_json::json!({"frame": {"frame": f.frame, "sim_tick": f.sim_tick, "vertices": f.positions.len(), "triangles": f.topology.triangles.len(), "wound_triangles": wound, "tool": f.tool.is_some()}})
                    );
                }
            }
        }
    }
    observer.0.close_and_wait().await;
    Ok(())
}

/// The lesson in a line: its name, trainee, incisions and limits.
fn lesson_line(plan: &LessonPlan) -> String {
    let incisions: Vec<String> = plan
        .incisions
        .iter()
        .map(|c| {
            let length: f32 = c
                .points_mm
                .windows(2)
                .map(|w| {
                    (0..3)
                        .map(|k| (w[1][k] - w[0][k]).powi(2))
                        .sum::<f32>()
                        .sqrt()
                })
                .sum();
            format!(
                "{} {:.0} mm, {:.1} ± {:.1} mm deep, within {:.1} mm",
                c.name, length, c.depth_mm, c.depth_tolerance_mm, c.deviation_mm
            )
        })
        .collect();
    let no_go: Vec<&str> = plan.no_go.iter().map(|g| g.name.as_str()).collect();
    format!(
        "lesson {} (trainee {}): {}; no-go: {}; force {:.1}/{:.1} N; {:.0} s",
        plan.name,
        if plan.trainee.is_empty() {
            "not named"
        } else {
            &plan.trainee
        },
        incisions.join("; "),
        if no_go.is_empty() {
            "none".to_string()
        } else {
            no_go.join(", ")
        },
        plan.warning_n,
        plan.critical_n,
        plan.time_limit_s
    )
}

/// The running metrics in a line (docs/LESSONS.md, "Metrics").
pub fn score_line(s: &LessonScore) -> String {
    format!(
        "path {:.1} mm RMS, depth {:.1} mm RMS, {:.0} % done, {} strokes, {:.1} s, \
         force over limits {}/{}, no-go {} touched {} cut",
        s.rms_deviation_mm,
        s.rms_depth_error_mm,
        s.completed_percent,
        s.strokes,
        s.time_s,
        s.warning_events,
        s.critical_events,
        s.no_go_contacts,
        s.no_go_cuts
    )
}
