//! A started station as its main thread holds it: what it reports at the start, its control
//! and status loop (instructors' commands, faults, the device, the remote feed, status
//! lines), and its shut-down.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use scalpel_proto::wire::EventKind;
use scalpel_sim::scene::BuiltScene;

use crate::device_monitor::{DeviceEvent, DeviceMonitor};
use crate::faults::{FaultTable, Transition};
use crate::journal;
use crate::realtime;

use super::commands::{CommandDesk, Moment};
use super::remote_feed::RemoteFeed;
use super::startup::{Started, Threads};
use super::{RunSummary, StationEvent, StationParams, StationReport, StatusLine, station_tick};

/// A started station, as the main thread holds it while it runs.
pub(super) struct Station<'a> {
    pub(super) params: &'a StationParams,
    pub(super) stop: Arc<AtomicBool>,
    // Field order is drop order: the threads' handles, then the monitor, then the network
    // endpoint.
    pub(super) threads: Threads,
    pub(super) monitor: Option<DeviceMonitor>,
    pub(super) network: Option<crate::net::Network>,
    /// Why some real-time request was not granted.
    pub(super) warnings: Vec<String>,
}

impl Station<'_> {
    /// Reports what runs and what is off, the station clock, and the warnings.
    pub(super) fn report_start(
        &self,
        started: &Started,
        memory_locked: bool,
        other_cpus: &[usize],
        mut report: impl FnMut(&StationReport),
    ) {
        let Station {
            params,
            network,
            monitor,
            threads,
            warnings,
            ..
        } = self;
        let Started {
            fifo_priority,
            pinned_cpu,
            sim_pinned,
            sim_threads,
            frames_running,
            ..
        } = *started;
        let (haptic_thread, t0) = (&threads.haptic_thread, threads.t0);
        let threads = match sim_threads {
            1 => "simulation thread".to_string(),
            n => format!("simulation on {n} threads"),
        };
        let mut running = vec![if sim_pinned {
            format!("{threads} (CPUs {other_cpus:?})")
        } else {
            threads
        }];
        let mut off = Vec::new();
        if haptic_thread.is_some() {
            running.push(format!(
                "haptic thread {} Hz ({}, memory {}{})",
                params.haptic_hz,
                if fifo_priority > 0 {
                    format!("SCHED_FIFO {fifo_priority}")
                } else {
                    "normal scheduling".into()
                },
                if memory_locked {
                    "locked"
                } else {
                    "not locked"
                },
                pinned_cpu.map_or(String::new(), |c| format!(", CPU {c} to itself"))
            ));
            running.push(if params.monitor_device {
                "shared-memory device with its force-out thread".into()
            } else {
                "in-process scripted device".into()
            });
        } else {
            off.push("haptic thread (the scene has no haptics)".to_string());
        }
        if frames_running {
            running.push(format!("render frames {} Hz", params.frame_hz));
        } else {
            off.push("render frames".into());
        }
        if monitor.is_some() {
            running.push("shared-memory monitor".into());
        }
        match &network {
            Some(n) => running.push(format!("network endpoint on {}", n.local_addr)),
            None => off.push("network endpoint (no observers)".into()),
        }
        report(&StationReport::Event(StationEvent {
            uptime_s: realtime::monotonic_s() - t0,
            event: format!(
                "runs: {}; off: {}",
                running.join(", "),
                if off.is_empty() {
                    "nothing".to_string()
                } else {
                    off.join(", ")
                }
            ),
        }));
        // Instructors schedule on the station clock; a tool on this machine that logs
        // CLOCK_MONOTONIC (a device trace, a renderer) lines up with it through this.
        report(&StationReport::Event(StationEvent {
            uptime_s: realtime::monotonic_s() - t0,
            event: format!(
                "clock: station tick 0 is CLOCK_MONOTONIC {} ns",
                (t0 * 1e9).round() as u64
            ),
        }));
        for w in warnings {
            report(&StationReport::Event(StationEvent {
                uptime_s: realtime::monotonic_s() - t0,
                event: format!("warning: {w}"),
            }));
        }
    }

    /// Runs the main thread's loop until `stop` (instructors' commands, faults, device
    /// events, the remote feed, status lines), then writes out the audit's last refusals.
    pub(super) fn status_loop(
        &mut self,
        scene: &BuiltScene,
        mut report: impl FnMut(&StationReport),
    ) {
        let Station {
            params,
            stop,
            network,
            monitor,
            threads:
                Threads {
                    t0,
                    haptic_thread,
                    sim_thread,
                    commands_journal,
                    status_out,
                    faults_to_haptic,
                    faults_to_sim,
                    counters,
                    ..
                },
            ..
        } = self;
        let t0 = *t0;
        let mut next = t0 + params.status_interval_s;
        let mut window_start = t0;
        let mut remote = RemoteFeed::for_lesson(params.lesson.as_ref());
        let mut desk = CommandDesk::new(scene.spec.features.stiff_mode);
        let mut stream_lost = false;
        // The table the threads have (rebuilt only when the book changes).
        let mut table = FaultTable::default();
        while !stop.load(Ordering::Relaxed) {
            // Every 10 ms: instructors' commands are answered within that.
            realtime::sleep_until(next.min(realtime::monotonic_s() + 0.01));
            let now = realtime::monotonic_s();
            let sim_now = *status_out.read();
            let tick = station_tick(now - t0);
            let mut table_changed = false;
            if let Some(n) = &network {
                // Refused connections, said or summed up by the endpoint.
                while let Ok(line) = n.log.try_recv() {
                    report(&StationReport::Event(StationEvent {
                        uptime_s: now - t0,
                        event: line,
                    }));
                }
                table_changed |= desk.answer(
                    n,
                    &Moment {
                        sim: &sim_now,
                        uptime_s: now - t0,
                        tick,
                    },
                    commands_journal,
                    &mut report,
                );
            }
            for transition in desk.book.advance(tick) {
                table_changed = true;
                let (kind, text) = match transition {
                    Transition::Applied(t) => (EventKind::FaultApplied, format!("{t}: applied")),
                    Transition::Ended(t) => (EventKind::FaultCleared, t),
                };
                remote.event(network, &sim_now, now - t0, kind, &text);
                report(&StationReport::Event(StationEvent {
                    uptime_s: now - t0,
                    event: text,
                }));
            }
            if table_changed {
                table = desk.book.table();
                faults_to_haptic.write(table);
                faults_to_sim.write(table);
            }
            if let Some(n) = &network {
                let lost = table.stream_lost(tick);
                if lost != stream_lost {
                    stream_lost = lost;
                    n.feeds.stream_lost.send_replace(lost);
                }
            }
            if let Some(m) = &mut *monitor
                && let Some(change) = m.poll(now - t0)
                && params.monitor_device
            {
                let (kind, text) = said(change, m.dead_nodes_cleaned());
                remote.event(network, &sim_now, now - t0, kind, &text);
                report(&StationReport::Event(StationEvent {
                    uptime_s: now - t0,
                    event: text,
                }));
            }
            if let Some(n) = &network {
                remote.publish(
                    n,
                    &sim_now,
                    now - t0,
                    counters,
                    monitor
                        .as_ref()
                        .filter(|_| params.monitor_device)
                        .is_none_or(|m| m.connected())
                        && params.haptics,
                );
            }
            if now >= next {
                let line = StatusLine {
                    uptime_s: now - t0,
                    haptic: params
                        .haptics
                        .then(|| counters.take_window(now - window_start)),
                    sim: *status_out.read(),
                    device_connected: monitor
                        .as_ref()
                        .filter(|_| params.monitor_device)
                        .map(|m| m.connected()),
                    dead_nodes_cleaned: monitor.as_ref().map_or(0, |m| m.dead_nodes_cleaned()),
                };
                if let Some(h) = &line.haptic {
                    remote.window = Some(*h);
                }
                report(&StationReport::Status(Box::new(line)));
                window_start = now;
                next += params.status_interval_s;
            }
            if haptic_thread.as_ref().is_some_and(|h| h.is_finished()) || sim_thread.is_finished() {
                stop.store(true, Ordering::Relaxed);
            }
        }
        let now = realtime::monotonic_s();
        let sim_now = *status_out.read();
        let at = Moment {
            sim: &sim_now,
            uptime_s: now - t0,
            tick: station_tick(now - t0),
        };
        desk.close(&at, commands_journal, &mut report);
    }

    /// Joins the threads, stops the network endpoint, closes the journal with its footer
    /// and sums up the run.
    pub(super) fn shut_down(
        self,
        fifo_priority: i32,
        memory_locked: bool,
    ) -> anyhow::Result<RunSummary> {
        let Station {
            network,
            threads:
                Threads {
                    haptic_thread,
                    sim_thread,
                    writer,
                    sim_done,
                    journal_dropped,
                    mut status_out,
                    counters,
                    ..
                },
            warnings,
            ..
        } = self;
        let haptic_result = match haptic_thread {
            Some(h) => h.join(),
            None => Ok(()),
        };
        if let Some(n) = network {
            n.stop();
        }
        let sim_result = sim_thread.join();
        sim_done.store(true, Ordering::Release);
        let sim_status = *status_out.read();
        // The journal is flushed whatever happened: a session that failed is the one to replay.
        let mut file = match writer {
            Some(w) => Some(
                w.join()
                    .map_err(|_| anyhow::anyhow!("the journal writer panicked"))??,
            ),
            None => None,
        };
        let (Ok(()), Ok(state_hash)) = (haptic_result, sim_result) else {
            if let Some(f) = &mut file {
                std::io::Write::flush(f)?;
            }
            anyhow::bail!("a station thread panicked (the journal has the inputs up to it)");
        };
        if let Some(f) = &mut file {
            std::io::Write::write_all(f, journal::footer(sim_status.ticks, state_hash).as_bytes())?;
            std::io::Write::flush(f)?;
        }
        Ok(RunSummary {
            haptic_ticks: counters.total_ticks.load(Ordering::Relaxed),
            deadline_misses: counters.total_misses.load(Ordering::Relaxed),
            poses_dropped: counters.ring_full.load(Ordering::Relaxed),
            sim: sim_status,
            state_hash,
            journal_dropped: journal_dropped.load(Ordering::Relaxed),
            fifo_priority,
            memory_locked,
            warnings,
        })
    }
}

/// How a change of the device reads in the log and to remote observers.
fn said(change: DeviceEvent, dead_nodes_cleaned: u64) -> (EventKind, String) {
    match change {
        DeviceEvent::Connected(name) => (
            EventKind::DeviceConnected,
            format!("device connected ({name})"),
        ),
        DeviceEvent::Refused(name, why) => {
            (EventKind::Notice, format!("device {name} refused: {why}"))
        }
        DeviceEvent::Lost => (
            EventKind::DeviceLost,
            format!(
                "device lost (dead nodes cleaned so far: {dead_nodes_cleaned}); the force fades to zero"
            ),
        ),
    }
}
