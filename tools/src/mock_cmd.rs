//! `scalpel mock-device --station S [--script FILE | --scene NAME] [--out forces.csv]`:
//! the scripted haptic device over shared memory, at a true 1 kHz, recording every force it
//! receives.

use std::io::Write as _;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use scalpel_client::mock_device::{MockDevice, MockOptions, MockTick};
use scalpel_sim::pipeline::CutScript;

/// Header of the force recording.
pub const FORCE_CSV_HEADER: &str = "t_s,seq,tip_x_mm,tip_y_mm,tip_z_mm,fx_n,fy_n,fz_n,force_age_ms,force_flags,server_tick,pose_seq,lateness_ms,latency_ms";

/// What to run.
pub struct MockArgs<'a> {
    /// Station name.
    pub station: &'a str,
    /// Script file (TOML or CSV).
    pub script: Option<&'a Path>,
    /// Scene whose demo cut to play when there is no script.
    pub scene: &'a str,
    /// Force recording.
    pub out: Option<&'a Path>,
    /// Run options.
    pub options: MockOptions,
    /// JSON summary.
    pub json: bool,
}

/// Runs the mock device.
pub fn run(args: &MockArgs<'_>) -> anyhow::Result<()> {
    scalpel_proto::shm::quiet_logging();
    let script = match args.script {
        Some(path) => scalpel_server::scene_file::load_script(path)?,
        None => {
            let scene = scalpel_server::scene_file::load_scene(args.scene)?;
            CutScript::default_for(&scalpel_sim::pipeline::start_surface(&scene))?
        }
    };
    let mut out = match args.out {
        Some(path) => {
            let mut w = std::io::BufWriter::new(
                std::fs::File::create(path)
                    .with_context(|| format!("cannot create {}", path.display()))?,
            );
            writeln!(w, "{FORCE_CSV_HEADER}")?;
            Some(w)
        }
        None => None,
    };
    let stop = Arc::new(AtomicBool::new(false));
    let on_signal = stop.clone();
    ctrlc::set_handler(move || on_signal.store(true, Ordering::Relaxed))
        .context("cannot install the Ctrl-C handler")?;
    let mut device = MockDevice::open(args.station)?;
    if !args.json {
        println!(
            "mock device at station {}: {} ({:.1} s), {} Hz",
            args.station,
            script.description,
            script.duration_s(),
            args.options.rate_hz
        );
    }
    // The first failed write is kept and reported after the run.
    let mut write_error = None;
    let summary = device.run(&script, &args.options, &stop, |t: &MockTick| {
        if let Some(w) = &mut out
            && write_error.is_none()
            && let Err(e) = writeln!(
                w,
                "{:.3},{},{:.4},{:.4},{:.4},{:.5},{:.5},{:.5},{:.3},{},{},{},{:.4},{}",
                t.t_s,
                t.seq,
                t.tip_m[0] * 1e3,
                t.tip_m[1] * 1e3,
                t.tip_m[2] * 1e3,
                t.force_n[0],
                t.force_n[1],
                t.force_n[2],
                t.force_age_s.min(1e6) * 1e3,
                t.force_flags,
                t.server_tick,
                t.pose_seq,
                t.lateness_s * 1e3,
                t.latency_s
                    .map_or(String::new(), |l| format!("{:.4}", l * 1e3))
            )
        {
            write_error = Some(e);
        }
    })?;
    if let Some(e) = write_error {
        return Err(e).context("writing the force recording");
    }
    if let Some(w) = &mut out {
        w.flush()?;
    }
    let latency = quantiles_ms(&summary.latencies_s);
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "ticks": summary.ticks,
                "late_ticks": summary.late_ticks,
                "rate_hz": summary.rate_hz,
                "forces_received": summary.forces_received,
                "forces_rejected": summary.forces_rejected,
                "max_force_n": summary.max_force_n,
                "fifo_priority": summary.fifo_priority,
                "lag_p50_ticks": summary.lag_p50_ticks,
                "lag_p99_ticks": summary.lag_p99_ticks,
                "skipped": summary.skipped,
                "stale_ticks": summary.stale_ticks,
                "receive_errors": summary.receive_errors,
                "latency_ms": latency.map(|(p50, p99, max)| serde_json::json!({"p50": p50, "p99": p99, "max": max})),
            })
        );
    } else {
        println!(
            "sent {} poses at {:.1} Hz ({} woke a period late), received {} forces ({} rejected), largest {:.3} N; pose-to-force lag p50 {} p99 {} ticks; SCHED_FIFO {}",
            summary.ticks,
            summary.rate_hz,
            summary.late_ticks,
            summary.forces_received,
            summary.forces_rejected,
            summary.max_force_n,
            summary.lag_p50_ticks,
            summary.lag_p99_ticks,
            summary.fifo_priority
        );
        if summary.late_ticks + summary.stale_ticks + summary.receive_errors > 0 {
            println!(
                "late wake-ups {} (skipped {} samples), ticks with a stale force {}, receive errors {}",
                summary.late_ticks, summary.skipped, summary.stale_ticks, summary.receive_errors
            );
        }
        if let Some((p50, p99, max)) = latency {
            println!("pose-to-force latency: p50 {p50:.3} ms, p99 {p99:.3} ms, max {max:.3} ms");
        }
    }
    Ok(())
}

/// Median, 99th percentile and largest of `samples` (s), in ms.
pub fn quantiles_ms(samples: &[f64]) -> Option<(f64, f64, f64)> {
    crate::stats::Quantiles::of(samples).map(|q| (q.p50 * 1e3, q.p99 * 1e3, q.max * 1e3))
}
