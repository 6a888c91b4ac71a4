//! Lessons: what a trainee is asked to cut, and the metrics and score of how it was cut,
//! read from the simulation (docs/LESSONS.md).
//!
//! A lesson ([`LessonSpec`], TOML) plans incisions on an organ's surface with a target depth
//! and an allowed deviation, names structures inside that must not be cut, and sets force
//! limits, a time limit and pass criteria. [`Plan`] lays it on the scene's rest surface;
//! [`Scorer`] reads every tick (live on a station's simulation thread, or replaying a
//! journal) and gives the [`Metrics`] and score at any moment; [`trainee_script`] performs a
//! lesson as a scripted careful, hesitant or careless trainee.

mod plan;
mod score;
mod spec;
mod trainee;

pub use plan::{OnPlan, Plan, PlanSample, PlannedIncision, SAMPLE_M};
pub use score::{EVENT_ROOM, LessonEvent, LessonEventKind, Metrics, Scorer, Shortfalls};
pub use spec::{
    ForceLimits, IncisionSpec, LessonError, LessonSpec, NoGoShape, NoGoSpec, PassCriteria, PathSpec,
};
pub use trainee::{Trainee, trainee_script};

/// The built-in lessons: (name, TOML text), one for each cutting organ.
pub const BUILTIN: [(&str, &str); 3] = [
    (
        "liver-straight",
        include_str!("builtin/liver-straight.toml"),
    ),
    (
        "shoulder-curved",
        include_str!("builtin/shoulder-curved.toml"),
    ),
    (
        "cerebroma-margin",
        include_str!("builtin/cerebroma-margin.toml"),
    ),
];

/// The built-in lesson `name`, parsed.
pub fn builtin_lesson(name: &str) -> Option<LessonSpec> {
    BUILTIN.iter().find(|(n, _)| *n == name).map(|(n, text)| {
        LessonSpec::from_toml(text, &format!("builtin:{n}"))
            .expect("the built-in lessons parse (tested)")
    })
}

#[cfg(test)]
mod tests;
