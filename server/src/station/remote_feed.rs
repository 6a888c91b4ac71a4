//! What the main thread sends remote observers over the network endpoint: metrics at 10 Hz
//! and events ([`RemoteFeed`], [`send_event`]).

use std::sync::atomic::Ordering;

use scalpel_proto::wire::{Event, EventKind, Metrics};

use super::{HapticCounters, HapticWindow, SimStatus, station_tick};

/// What the main thread tells remote observers: metrics at 10 Hz, and events (its own and
/// the simulation's, from its counters).
#[derive(Default)]
pub(super) struct RemoteFeed {
    /// The last haptic status window (rate, jitter).
    pub(super) window: Option<HapticWindow>,
    last_publish: f64,
    entries: u64,
    ruptures: u64,
    lesson: crate::lesson_feed::LessonEvents,
}

/// Sends an event to the observers (none connected is not an error).
fn send_event(
    network: &crate::net::Network,
    sim: &SimStatus,
    uptime_s: f64,
    kind: EventKind,
    detail: String,
) {
    let _ = network.feeds.events.send(Event {
        sim_tick: sim.ticks,
        uptime_s,
        kind,
        detail,
    });
}

impl RemoteFeed {
    /// The feed of a station running `lesson` (its events name its structures).
    pub(super) fn for_lesson(lesson: Option<&scalpel_sim::lesson::Plan>) -> Self {
        Self {
            lesson: crate::lesson_feed::LessonEvents::new(lesson),
            ..Self::default()
        }
    }

    pub(super) fn event(
        &self,
        network: &Option<crate::net::Network>,
        sim: &SimStatus,
        uptime_s: f64,
        kind: EventKind,
        detail: &str,
    ) {
        if let Some(n) = network {
            send_event(n, sim, uptime_s, kind, detail.to_string());
        }
    }

    pub(super) fn publish(
        &mut self,
        network: &crate::net::Network,
        sim: &SimStatus,
        uptime_s: f64,
        counters: &HapticCounters,
        device_connected: bool,
    ) {
        let send = |kind, detail: String| send_event(network, sim, uptime_s, kind, detail);
        if sim.entries > self.entries {
            self.entries = sim.entries;
            send(EventKind::CutStarted, "the blade entered the tissue".into());
        }
        if sim.ruptures > self.ruptures {
            self.ruptures = sim.ruptures;
            send(
                EventKind::Rupture,
                format!(
                    "rupture: cutting, at {:.2} N on the tool",
                    sim.rupture_force_n
                ),
            );
        }
        if let Some(m) = &sim.lesson {
            for (kind, detail) in self.lesson.since(m) {
                send(kind, detail);
            }
        }
        if uptime_s - self.last_publish < 0.1 {
            return;
        }
        self.last_publish = uptime_s;
        if let Some(m) = &sim.lesson {
            let _ = network
                .feeds
                .score
                .send(Some(crate::lesson_feed::score_message(m, sim.ticks)));
        }
        let w = self.window;
        let metrics = Metrics {
            sim_tick: sim.ticks,
            station_tick: station_tick(uptime_s),
            uptime_s,
            haptic_rate_hz: w.map_or(0.0, |w| w.rate_hz as f32),
            jitter_p99_ms: w.map_or(0.0, |w| w.jitter_p99_ms as f32),
            deadline_misses: counters.total_misses.load(Ordering::Relaxed),
            force_n: f64::from_bits(counters.force_bits.load(Ordering::Relaxed)) as f32,
            faded: counters.watchdog_faded.load(Ordering::Relaxed),
            cut_length_mm: sim.cut_length_mm as f32,
            active_points: sim.active_points as u32,
            device_connected,
        };
        let _ = network.feeds.metrics.send(metrics);
    }
}
