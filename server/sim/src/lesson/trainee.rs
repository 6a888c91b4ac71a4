//! Scripted trainees: blade trajectories that perform a lesson as a careful, a hesitant and a
//! careless trainee would, for the mock device and the tests (docs/LESSONS.md, "Scripted
//! trainees"). Each follows the plan's samples with the blade's edge along the surface's
//! outward normal, facing along the path.

use super::plan::{Plan, PlannedIncision};
use crate::cut::ToolPose;
use crate::geometry::TriMesh;
use crate::math::Vec3;
use crate::pipeline::script::{CutScript, Keyframe};

/// Which trainee.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trainee {
    /// On the path, at the target depth, at 5 mm/s, in one stroke an incision.
    Careful,
    /// Shallow by half the tolerance, slow (3 mm/s), wavering by 40 % of the allowed
    /// deviation, and stopping halfway for 1.5 s out of the tissue before going on.
    Hesitant,
    /// Deep by two and a half tolerances, fast (15 mm/s), wandering by 1.5 allowed
    /// deviations, and stopping at three quarters of each path.
    Careless,
}

impl Trainee {
    /// Every trainee.
    pub const ALL: [Self; 3] = [Self::Careful, Self::Hesitant, Self::Careless];

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Careful => "careful",
            Self::Hesitant => "hesitant",
            Self::Careless => "careless",
        }
    }

    /// The trainee of a name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    fn manner(self) -> Manner {
        match self {
            Self::Careful => Manner {
                depth_tolerances: 0.0,
                wander_deviations: 0.0,
                wavelength_m: 0.02,
                speed: 0.005,
                plunge_speed: 0.005,
                stop_at: None,
                reach: 1.0,
            },
            Self::Hesitant => Manner {
                depth_tolerances: -0.5,
                wander_deviations: 0.4,
                wavelength_m: 0.02,
                speed: 0.003,
                plunge_speed: 0.004,
                stop_at: Some((0.5, 1.5)),
                reach: 1.0,
            },
            Self::Careless => Manner {
                depth_tolerances: 2.5,
                wander_deviations: 1.5,
                wavelength_m: 0.025,
                speed: 0.015,
                plunge_speed: 0.02,
                stop_at: None,
                reach: 0.75,
            },
        }
    }
}

/// How a trainee cuts.
struct Manner {
    /// Depth off the target, in depth tolerances (+ deeper).
    depth_tolerances: f64,
    /// Amplitude of a sideways wave, in allowed deviations.
    wander_deviations: f64,
    wavelength_m: f64,
    speed: f64,
    plunge_speed: f64,
    /// Lift out at this share of the path and wait this long (s) before going in again.
    stop_at: Option<(f64, f64)>,
    /// Share of each path cut.
    reach: f64,
}

/// Height above the surface where the blade starts, ends and travels (m).
const CLEARANCE_M: f64 = 0.010;
/// Keyframes along the path every this many plan samples (2 mm).
const KEY_EVERY: usize = 4;
/// Seconds between one incision's end and the next's start.
const TRAVEL_S: f64 = 1.0;

/// The script of `who` performing `plan` on the organ as it is at the start: `surface`, the
/// plan's rest surface with its vertices where the organ rests on its supports
/// (`pipeline::start_surface`). The plan marks material; the hand goes where it lies.
pub fn trainee_script(plan: &Plan, surface: &TriMesh, who: Trainee) -> CutScript {
    let manner = who.manner();
    let mut keyframes = Vec::new();
    let mut t = 0.0;
    for (i, inc) in plan.incisions.iter().enumerate() {
        if i > 0 {
            t += TRAVEL_S;
        }
        let last = ((inc.samples.len() - 1) as f64 * manner.reach).round() as usize;
        match manner.stop_at {
            None => t = stroke(inc, surface, &manner, 0, last, &mut keyframes, t),
            Some((share, wait_s)) => {
                let mid = (last as f64 * share).round() as usize;
                t = stroke(inc, surface, &manner, 0, mid, &mut keyframes, t);
                // Back in a little behind where it stopped, as a hand finds its place.
                let back = mid.saturating_sub(4);
                t = stroke(
                    inc,
                    surface,
                    &manner,
                    back,
                    last,
                    &mut keyframes,
                    t + wait_s,
                );
            }
        }
    }
    CutScript {
        keyframes,
        description: format!("a {} trainee on lesson {}", who.name(), plan.spec.name),
    }
}

/// Samples either side over which a hand's blade keeps its tilt (10 mm): it follows the
/// organ's curve, not each facet of its mesh (a blade turned 10° in 0.4 s in the tissue,
/// as facet normals turn it, cuts sideways with its whole width).
const TILT_SAMPLES: usize = 20;

/// Each sample where its material is on `surface`, with the outward normal smoothed over
/// [`TILT_SAMPLES`] each side and the path's direction there.
fn placed(inc: &PlannedIncision, surface: &TriMesh) -> Vec<(Vec3, Vec3, Vec3)> {
    let on: Vec<(Vec3, Vec3)> = inc.samples.iter().map(|s| s.on(surface)).collect();
    let n = on.len();
    (0..n)
        .map(|k| {
            let (lo, hi) = (
                k.saturating_sub(TILT_SAMPLES),
                (k + TILT_SAMPLES).min(n - 1),
            );
            let out = on[lo..=hi]
                .iter()
                .map(|p| p.1)
                .sum::<Vec3>()
                .try_normalize(1e-12)
                .unwrap_or(on[k].1);
            let along = on[(k + 4).min(n - 1)].0 - on[k.saturating_sub(4)].0;
            let tangent = (along - out * along.dot(&out))
                .try_normalize(1e-12)
                .unwrap_or(inc.samples[k].tangent);
            (on[k].0, out, tangent)
        })
        .collect()
}

/// One stroke over samples `from..=to`: down from above, along, and out; returns its end.
fn stroke(
    inc: &PlannedIncision,
    surface: &TriMesh,
    manner: &Manner,
    from: usize,
    to: usize,
    keyframes: &mut Vec<Keyframe>,
    mut t: f64,
) -> f64 {
    let depth = inc.depth_m + manner.depth_tolerances * inc.depth_tolerance_m;
    let placed = placed(inc, surface);
    let here = |k: usize| placed[k];
    let tip_at = |k: usize| {
        let (at, out, tangent) = here(k);
        let across = tangent.cross(&out);
        let wave = manner.wander_deviations
            * inc.deviation_m
            * (std::f64::consts::TAU * inc.samples[k].s_m / manner.wavelength_m).sin();
        at + across * wave - out * depth
    };
    let pose = |k: usize, tip: Vec3| {
        let (_, out, tangent) = here(k);
        ToolPose::facing(tip, out, tangent)
    };
    let above = tip_at(from) + here(from).1 * (depth + CLEARANCE_M);
    keyframes.push(Keyframe {
        t_s: t,
        pose: pose(from, above),
    });
    let mut last = tip_at(from);
    t += (last - above).norm() / manner.plunge_speed;
    keyframes.push(Keyframe {
        t_s: t,
        pose: pose(from, last),
    });
    let mut k = from;
    while k < to {
        k = (k + KEY_EVERY).min(to);
        let tip = tip_at(k);
        t += (tip - last).norm() / manner.speed;
        keyframes.push(Keyframe {
            t_s: t,
            pose: pose(k, tip),
        });
        last = tip;
    }
    let out = last + here(to).1 * (depth + CLEARANCE_M);
    t += (out - last).norm() / manner.plunge_speed;
    keyframes.push(Keyframe {
        t_s: t,
        pose: pose(to, out),
    });
    t
}
