//! The live terminal view of `scalpel observe` (ratatui): the station's figures (haptic
//! rate, jitter, deadline misses, force, cut, device), the force and the jitter over the
//! last 20 seconds as charts, and the events as they come. `q`, Esc or Ctrl-C quits.
//! The view is a pure function of [`Dashboard`], so a test renders it into a buffer.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use ratatui::Frame;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::symbols::Marker;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Axis, Block, Chart, Dataset, GraphType, List, ListItem, Paragraph};
use scalpel_client::remote::{Observer, Update, Welcome};
use scalpel_proto::wire::{Event, EventKind, LessonPlan, LessonScore, Metrics};

/// Seconds of history in the charts.
const HISTORY_S: f64 = 20.0;
/// Events kept.
const EVENTS: usize = 200;

/// What the view shows.
#[derive(Debug, Clone)]
pub struct Dashboard {
    /// Who we are and where.
    pub welcome: Welcome,
    /// The latest figures.
    pub metrics: Option<Metrics>,
    /// (uptime s, force N) over the last [`HISTORY_S`].
    pub force: VecDeque<(f64, f64)>,
    /// (uptime s, jitter p99 ms).
    pub jitter: VecDeque<(f64, f64)>,
    /// The latest events, oldest first.
    pub events: VecDeque<Event>,
    /// Frames received so far, and per second over the last second.
    pub frames: u64,
    /// See `frames`.
    pub frames_per_s: f64,
    /// The connection's end, when it ended.
    pub closed: Option<String>,
    /// The lesson the station runs, and the trainee's running score.
    pub lesson: Option<Box<LessonPlan>>,
    /// See `lesson`.
    pub score: Option<LessonScore>,
    /// The blade tip seen from above (mm), from the frames, for the plan's view.
    pub tool_path: VecDeque<(f64, f64)>,
}

/// Tool positions kept for the plan's view.
const TOOL_PATH: usize = 4000;

impl Dashboard {
    /// An empty view for a new connection.
    pub fn new(welcome: Welcome) -> Self {
        Self {
            welcome,
            metrics: None,
            force: VecDeque::new(),
            jitter: VecDeque::new(),
            events: VecDeque::new(),
            frames: 0,
            frames_per_s: 0.0,
            closed: None,
            lesson: None,
            score: None,
            tool_path: VecDeque::new(),
        }
    }

    /// Takes one update in.
    pub fn update(&mut self, update: &Update) {
        match update {
            Update::Metrics(m) => {
                self.metrics = Some(*m);
                for (series, value) in [
                    (&mut self.force, f64::from(m.force_n)),
                    (&mut self.jitter, f64::from(m.jitter_p99_ms)),
                ] {
                    series.push_back((m.uptime_s, value));
                    while series
                        .front()
                        .is_some_and(|(t, _)| m.uptime_s - t > HISTORY_S)
                    {
                        series.pop_front();
                    }
                }
            }
            Update::Event(e) => {
                self.events.push_back(e.clone());
                if self.events.len() > EVENTS {
                    self.events.pop_front();
                }
            }
            Update::Frame(f) => {
                self.frames += 1;
                if let Some(t) = &f.tool {
                    self.tool_path
                        .push_back((f64::from(t.tip_m[0]) * 1e3, f64::from(t.tip_m[1]) * 1e3));
                    if self.tool_path.len() > TOOL_PATH {
                        self.tool_path.pop_front();
                    }
                }
            }
            Update::Lesson(l) => self.lesson = Some(l.clone()),
            Update::Score(s) => self.score = Some(*s),
        }
    }
}

fn event_style(kind: EventKind) -> Style {
    match kind {
        EventKind::FaultApplied => Style::new().fg(Color::Red).add_modifier(Modifier::BOLD),
        EventKind::FaultCleared => Style::new().fg(Color::Green),
        EventKind::DeviceLost => Style::new().fg(Color::Red),
        EventKind::DeviceConnected => Style::new().fg(Color::Green),
        EventKind::Rupture | EventKind::CutStarted => Style::new().fg(Color::Yellow),
        EventKind::Notice => Style::new().fg(Color::Gray),
        EventKind::ForceWarning | EventKind::NoGoContact => Style::new().fg(Color::Yellow),
        EventKind::ForceCritical | EventKind::NoGoCut => {
            Style::new().fg(Color::Red).add_modifier(Modifier::BOLD)
        }
    }
}

/// Draws the view into `frame`.
pub fn draw(frame: &mut Frame, d: &Dashboard) {
    let [header, figures, charts, events] = Layout::vertical([
        Constraint::Length(1),
        // Three lines of figures (four with a lesson) in a border.
        Constraint::Length(if d.lesson.is_some() { 6 } else { 5 }),
        Constraint::Min(8),
        Constraint::Length(8),
    ])
    .areas(frame.area());
    let w = &d.welcome;
    let state = match &d.closed {
        Some(why) => Span::styled(format!("  closed: {why}"), Style::new().fg(Color::Red)),
        None => Span::raw("  q quits"),
    };
    frame.render_widget(
        Paragraph::new(Line::from(vec![
            Span::styled(
                format!("scalpel · station {} · scene {}", w.station, w.scene),
                Style::new().add_modifier(Modifier::BOLD),
            ),
            Span::raw(format!("  as {} ({:?})", w.identity, w.role)),
            state,
        ])),
        header,
    );
    draw_figures(frame, figures, d);
    let [force, jitter] =
        Layout::horizontal([Constraint::Percentage(60), Constraint::Percentage(40)]).areas(charts);
    draw_series(frame, force, "force sent (N)", &d.force, Color::Cyan, 1.0);
    match &d.lesson {
        Some(plan) => draw_plan(frame, jitter, plan, &d.tool_path),
        None => draw_series(
            frame,
            jitter,
            "jitter p99 (ms)",
            &d.jitter,
            Color::Magenta,
            0.05,
        ),
    }
    let items: Vec<ListItem> = d
        .events
        .iter()
        .rev()
        .take(usize::from(events.height.saturating_sub(2)))
        .map(|e| {
            ListItem::new(Line::from(vec![
                Span::raw(format!("{:8.1} s  ", e.uptime_s)),
                Span::styled(format!("{:?}", e.kind), event_style(e.kind)),
                Span::raw(format!("  {}", e.detail)),
            ]))
        })
        .collect();
    frame.render_widget(
        List::new(items).block(Block::bordered().title("events (newest first)")),
        events,
    );
}

fn draw_figures(frame: &mut Frame, area: Rect, d: &Dashboard) {
    let lines = match &d.metrics {
        None => vec![Line::from("waiting for the station's first figures…")],
        Some(m) => {
            let warn = |bad: bool| {
                if bad {
                    Style::new().fg(Color::Red).add_modifier(Modifier::BOLD)
                } else {
                    Style::new()
                }
            };
            vec![
                Line::from(vec![
                    Span::raw(format!(
                        "uptime {:7.1} s   station tick {}   simulation tick {}   ",
                        m.uptime_s, m.station_tick, m.sim_tick
                    )),
                    Span::styled(
                        if m.device_connected {
                            "device connected"
                        } else {
                            "NO DEVICE"
                        },
                        warn(!m.device_connected),
                    ),
                ]),
                Line::from(vec![
                    Span::styled(
                        format!("haptic {:7.1} Hz", m.haptic_rate_hz),
                        warn(m.haptic_rate_hz < 990.0),
                    ),
                    Span::raw(format!("   jitter p99 {:.3} ms   ", m.jitter_p99_ms)),
                    Span::styled(
                        format!("deadline misses {}", m.deadline_misses),
                        warn(m.deadline_misses > 0),
                    ),
                ]),
                Line::from(vec![
                    Span::raw(format!("force {:5.2} N ", m.force_n)),
                    Span::styled(if m.faded { "(faded)" } else { "" }, warn(m.faded)),
                    Span::raw(format!(
                        "   cut {:.1} mm   {} points   frames {} ({:.0}/s)",
                        m.cut_length_mm, m.active_points, d.frames, d.frames_per_s
                    )),
                ]),
            ]
        }
    };
    let mut lines = lines;
    if let (Some(_), Some(s)) = (&d.lesson, &d.score) {
        lines.push(Line::from(vec![
            Span::styled(
                format!(
                    "score {:3.0} {}",
                    s.score,
                    if s.passed { "pass" } else { "not passing" }
                ),
                if s.passed {
                    Style::new().fg(Color::Green).add_modifier(Modifier::BOLD)
                } else {
                    Style::new().fg(Color::Yellow)
                },
            ),
            Span::raw(format!("   {}", crate::observe_cmd::score_line(s))),
        ]));
    }
    frame.render_widget(
        Paragraph::new(lines).block(Block::bordered().title("station")),
        area,
    );
}

/// The plan from above (grey) and where the blade went (yellow), mm.
fn draw_plan(frame: &mut Frame, area: Rect, plan: &LessonPlan, tool: &VecDeque<(f64, f64)>) {
    let paths: Vec<Vec<(f64, f64)>> = plan
        .incisions
        .iter()
        .map(|c| {
            c.points_mm
                .iter()
                .map(|p| (f64::from(p[0]), f64::from(p[1])))
                .collect()
        })
        .collect();
    let tool: Vec<(f64, f64)> = tool.iter().copied().collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in paths.iter().flatten() {
        lo = [lo[0].min(p.0), lo[1].min(p.1)];
        hi = [hi[0].max(p.0), hi[1].max(p.1)];
    }
    // Room round the plan for a hand that strays; the tool's points beyond it are cut off.
    let margin = 0.25 * (hi[0] - lo[0]).max(hi[1] - lo[1]).max(10.0);
    let (x, y) = (
        [lo[0] - margin, hi[0] + margin],
        [lo[1] - margin, hi[1] + margin],
    );
    let mut data: Vec<Dataset> = paths
        .iter()
        .map(|p| {
            Dataset::default()
                .marker(Marker::Braille)
                .graph_type(GraphType::Line)
                .style(Style::new().fg(Color::Gray))
                .data(p)
        })
        .collect();
    data.push(
        Dataset::default()
            .marker(Marker::Braille)
            .graph_type(GraphType::Scatter)
            .style(Style::new().fg(Color::Yellow))
            .data(&tool),
    );
    let chart = Chart::new(data)
        .block(Block::bordered().title(format!(
            "lesson {}: plan (grey), blade (yellow), mm",
            plan.name
        )))
        .x_axis(
            Axis::default()
                .bounds(x)
                .labels([format!("{:.0}", x[0]), format!("{:.0}", x[1])]),
        )
        .y_axis(
            Axis::default()
                .bounds(y)
                .labels([format!("{:.0}", y[0]), format!("{:.0}", y[1])]),
        );
    frame.render_widget(chart, area);
}

fn draw_series(
    frame: &mut Frame,
    area: Rect,
    title: &str,
    series: &VecDeque<(f64, f64)>,
    color: Color,
    least_top: f64,
) {
    let points: Vec<(f64, f64)> = series.iter().copied().collect();
    let end = points.last().map_or(HISTORY_S, |p| p.0.max(HISTORY_S));
    let top = points
        .iter()
        .map(|p| p.1)
        .fold(least_top, f64::max)
        .max(1e-9)
        * 1.1;
    let data = [Dataset::default()
        .marker(Marker::Braille)
        .graph_type(GraphType::Line)
        .style(Style::new().fg(color))
        .data(&points)];
    let chart = Chart::new(data.to_vec())
        .block(Block::bordered().title(title.to_string()))
        .x_axis(
            Axis::default()
                .bounds([end - HISTORY_S, end])
                .labels([format!("{:.0} s", end - HISTORY_S), format!("{end:.0} s")]),
        )
        .y_axis(
            Axis::default()
                .bounds([0.0, top])
                .labels(["0".to_string(), format!("{top:.2}")]),
        );
    frame.render_widget(chart, area);
}

/// Whether q, Esc or Ctrl-C is among the keys pressed since the last look.
fn quit_pressed() -> std::io::Result<bool> {
    use ratatui::crossterm::event::{self, KeyCode, KeyModifiers};
    let mut quit = false;
    while event::poll(Duration::ZERO)? {
        if let event::Event::Key(k) = event::read()? {
            quit |= matches!(k.code, KeyCode::Char('q') | KeyCode::Esc)
                || (k.code == KeyCode::Char('c') && k.modifiers.contains(KeyModifiers::CONTROL));
        }
    }
    Ok(quit)
}

/// Runs the view until the user quits, `seconds` pass or the connection ends.
pub async fn run(observer: &mut Observer, seconds: Option<f64>) -> anyhow::Result<()> {
    let mut terminal = ratatui::try_init()?;
    let mut d = Dashboard::new(observer.0.welcome().clone());
    let started = Instant::now();
    let mut redraw = tokio::time::interval(Duration::from_millis(100));
    let mut second = (Instant::now(), 0u64);
    let result = loop {
        if seconds.is_some_and(|s| started.elapsed().as_secs_f64() >= s) {
            break Ok(());
        }
        tokio::select! {
            u = observer.0.next(), if d.closed.is_none() => match u {
                Some(u) => d.update(&u),
                None => d.closed = Some(observer.0.closed().await),
            },
            _ = redraw.tick() => {
                if second.0.elapsed() >= Duration::from_secs(1) {
                    d.frames_per_s = (d.frames - second.1) as f64 / second.0.elapsed().as_secs_f64();
                    second = (Instant::now(), d.frames);
                }
                if let Err(e) = terminal.draw(|f| draw(f, &d)) {
                    break Err(e.into());
                }
                // Errors leave the loop (never `?`): the terminal is restored below.
                match quit_pressed() {
                    Ok(false) => {}
                    Ok(true) => break Ok(()),
                    Err(e) => break Err(e.into()),
                }
            }
        }
    };
    ratatui::restore();
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use ratatui::Terminal;
    use ratatui::backend::TestBackend;
    use scalpel_proto::wire::Role;

    #[test]
    fn the_view_shows_the_figures_the_force_and_the_events() {
        let mut d = Dashboard::new(Welcome {
            station: "lab-3".into(),
            scene: "liver".into(),
            role: Role::Observer,
            identity: "eve".into(),
        });
        for k in 0..300 {
            let t = f64::from(k) * 0.1;
            d.update(&Update::Metrics(Metrics {
                sim_tick: k as u64 * 100,
                station_tick: k as u64 * 100 + 7,
                uptime_s: t,
                haptic_rate_hz: 1000.0,
                jitter_p99_ms: 0.02,
                deadline_misses: 2,
                force_n: (t * 0.5).sin() as f32 + 1.5,
                faded: false,
                cut_length_mm: 12.5,
                active_points: 480,
                device_connected: true,
            }));
        }
        d.update(&Update::Event(Event {
            sim_tick: 100,
            uptime_s: 29.0,
            kind: EventKind::FaultApplied,
            detail: "fault 3 device-latency by ann".into(),
        }));
        let mut terminal = Terminal::new(TestBackend::new(110, 30)).unwrap();
        terminal.draw(|f| draw(f, &d)).unwrap();
        let text: String = terminal
            .backend()
            .buffer()
            .content()
            .iter()
            .map(|c| c.symbol())
            .collect();
        for want in [
            "station lab-3",
            "haptic  1000.0 Hz",
            "deadline misses 2",
            "station tick 29907",
            "cut 12.5 mm",
            "force sent (N)",
            "FaultApplied",
            "fault 3 device-latency by ann",
        ] {
            assert!(text.contains(want), "{want:?} is not on the screen");
        }
        // The charts keep 20 s of history.
        assert!(
            d.force.len() <= 201 && d.force.len() >= 199,
            "{}",
            d.force.len()
        );
        // Braille dots of the force line are drawn.
        assert!(text.chars().any(|c| ('\u{2801}'..='\u{28ff}').contains(&c)));
    }
}
