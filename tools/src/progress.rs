//! A progress bar on stderr for builds, shown only once a stage has run for more than a
//! second: quick builds print nothing extra, slow ones say what they are doing.

use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use scalpel_sim::progress::BuildStage;

const STAGES: [BuildStage; 7] = [
    BuildStage::LoadMesh,
    BuildStage::Validate,
    BuildStage::Remesh,
    BuildStage::SolveSpacing,
    BuildStage::Sample,
    BuildStage::Neighbours,
    BuildStage::Embed,
];

/// How long a stage runs before the bar appears.
const SHOW_AFTER: Duration = Duration::from_secs(1);

struct Shared {
    stage_started: Instant,
    visible: bool,
    done: bool,
}

/// Shows build stages as a bar once one of them takes longer than [`SHOW_AFTER`].
pub struct StageProgress {
    bar: ProgressBar,
    shared: Arc<Mutex<Shared>>,
    watcher: Option<thread::JoinHandle<()>>,
}

impl StageProgress {
    /// A progress display for building the scene `name`.
    pub fn new(name: &str) -> Self {
        let bar =
            ProgressBar::with_draw_target(Some(STAGES.len() as u64), ProgressDrawTarget::hidden());
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} building {prefix} [{bar:20}] {pos}/{len} {msg} ({elapsed})",
            )
            .expect("the template is valid")
            .progress_chars("=> "),
        );
        bar.set_prefix(name.to_string());
        let shared = Arc::new(Mutex::new(Shared {
            stage_started: Instant::now(),
            visible: false,
            done: false,
        }));
        let watcher = {
            let bar = bar.clone();
            let shared = Arc::clone(&shared);
            thread::spawn(move || {
                loop {
                    thread::park_timeout(Duration::from_millis(100));
                    let mut s = shared.lock().unwrap_or_else(|e| e.into_inner());
                    if s.done {
                        return;
                    }
                    if !s.visible && s.stage_started.elapsed() > SHOW_AFTER {
                        s.visible = true;
                        bar.set_draw_target(ProgressDrawTarget::stderr());
                        bar.enable_steady_tick(Duration::from_millis(120));
                    }
                }
            })
        };
        Self {
            bar,
            shared,
            watcher: Some(watcher),
        }
    }

    /// A stage starts.
    pub fn stage(&mut self, stage: BuildStage) {
        let position = STAGES.iter().position(|s| *s == stage).unwrap_or(0);
        self.bar.set_position(position as u64);
        self.bar.set_message(stage.name());
        self.shared
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .stage_started = Instant::now();
    }

    /// The build is over: remove the bar.
    pub fn finish(&mut self) {
        self.shared.lock().unwrap_or_else(|e| e.into_inner()).done = true;
        if let Some(w) = self.watcher.take() {
            w.thread().unpark();
            let _ = w.join();
        }
        self.bar.finish_and_clear();
    }
}

impl Drop for StageProgress {
    fn drop(&mut self) {
        self.finish();
    }
}
