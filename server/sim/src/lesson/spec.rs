//! Lesson files (TOML): what the trainee is asked to do and how it is judged. Every key is
//! range-checked with a message that names it; unknown keys are rejected. The keys are
//! documented in docs/LESSONS.md.

use serde::Deserialize;
use thiserror::Error;

use crate::geometry::predicates::distance_sq_to_segment;
use crate::math::Vec3;

/// Why a lesson was rejected.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum LessonError {
    /// Not valid TOML, a key of the wrong type, or an unknown key.
    #[error("{file}: {message}")]
    Parse {
        /// Lesson file.
        file: String,
        /// The parser's message, with line and column.
        message: String,
    },
    /// A value is out of range, inconsistent with another, or does not fit the organ.
    #[error("{file}: {key}: {message}")]
    Invalid {
        /// Lesson file.
        file: String,
        /// Dotted key, e.g. `incision[0].depth_mm`.
        key: String,
        /// What is wrong and what is allowed.
        message: String,
    },
}

/// A lesson as written (SI units), checked but not yet laid on an organ
/// ([`super::Plan::new`] does that).
#[derive(Debug, Clone, PartialEq)]
pub struct LessonSpec {
    /// Short name (`liver-straight`).
    pub name: String,
    /// What the trainee is asked to do, for people.
    pub description: String,
    /// A built-in scene's name or a scene file (relative to the lesson file).
    pub scene: String,
    /// Longest the exercise may take (s), from the blade's first entry to its last exit.
    pub time_limit_s: f64,
    /// The planned incisions.
    pub incisions: Vec<IncisionSpec>,
    /// Structures the blade must not cut.
    pub no_go: Vec<NoGoSpec>,
    /// Force limits.
    pub force: ForceLimits,
    /// What it takes to pass.
    pub pass: PassCriteria,
}

/// One planned incision.
#[derive(Debug, Clone, PartialEq)]
pub struct IncisionSpec {
    /// Name, for reports.
    pub name: String,
    /// Its path on the organ, before projection (m, mesh coordinates).
    pub path: PathSpec,
    /// Target depth below the surface (m).
    pub depth_m: f64,
    /// Allowed depth error either way (m).
    pub depth_tolerance_m: f64,
    /// Allowed distance of the cut from the path, across it (m).
    pub deviation_m: f64,
}

/// An incision's path as written.
#[derive(Debug, Clone, PartialEq)]
pub enum PathSpec {
    /// Straight pieces through these points (m).
    Polyline(Vec<Vec3>),
    /// A cubic Bézier curve by its four control points (m).
    Bezier([Vec3; 4]),
}

/// A structure inside the organ that must not be cut (a vessel, a duct, a nerve).
#[derive(Debug, Clone, PartialEq)]
pub struct NoGoSpec {
    /// Name, for reports and events.
    pub name: String,
    /// Its shape (m).
    pub shape: NoGoShape,
    /// A blade edge within this distance of the structure is in contact with it (m).
    pub contact_margin_m: f64,
}

/// A no-go structure's shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NoGoShape {
    /// A ball.
    Sphere {
        /// Centre (m).
        centre: Vec3,
        /// Radius (m).
        radius: f64,
    },
    /// A capsule round the segment from `from` to `to`: a vessel or duct.
    Tube {
        /// One end of its axis (m).
        from: Vec3,
        /// The other end (m).
        to: Vec3,
        /// Radius (m).
        radius: f64,
    },
}

impl NoGoShape {
    /// Distance from `p` to the structure's surface (negative inside).
    pub fn distance(&self, p: &Vec3) -> f64 {
        match *self {
            Self::Sphere { centre, radius } => (p - centre).norm() - radius,
            Self::Tube { from, to, radius } => {
                distance_sq_to_segment(p, &from, &to).sqrt() - radius
            }
        }
    }

    /// Distance from the segment `a`–`b` to the structure's surface (negative when it
    /// passes inside).
    pub fn segment_distance(&self, a: &Vec3, b: &Vec3) -> f64 {
        match *self {
            Self::Sphere { centre, radius } => {
                distance_sq_to_segment(&centre, a, b).sqrt() - radius
            }
            Self::Tube { from, to, radius } => segment_segment_distance(a, b, &from, &to) - radius,
        }
    }
}

impl NoGoShape {
    /// Distance from the triangle `tri` to the structure's surface (negative when the
    /// triangle reaches inside).
    pub fn triangle_distance(&self, tri: &[Vec3; 3]) -> f64 {
        use crate::geometry::predicates::closest_point_on_triangle;
        match *self {
            Self::Sphere { centre, radius } => {
                (centre - closest_point_on_triangle(&centre, tri)).norm() - radius
            }
            Self::Tube { from, to, radius } => segment_triangle_distance(&from, &to, tri) - radius,
        }
    }
}

/// Shortest distance between the segment `a`–`b` and the triangle `tri`.
fn segment_triangle_distance(a: &Vec3, b: &Vec3, tri: &[Vec3; 3]) -> f64 {
    use crate::geometry::predicates::closest_point_on_triangle;
    // Through the triangle: zero.
    let n = (tri[1] - tri[0]).cross(&(tri[2] - tri[0]));
    let (da, db) = ((a - tri[0]).dot(&n), (b - tri[0]).dot(&n));
    if da * db < 0.0 {
        let x = a + (b - a) * (da / (da - db));
        if (closest_point_on_triangle(&x, tri) - x).norm() <= 1e-12 {
            return 0.0;
        }
    }
    let ends = [a, b]
        .iter()
        .map(|p| (closest_point_on_triangle(p, tri) - *p).norm())
        .fold(f64::INFINITY, f64::min);
    (0..3)
        .map(|k| segment_segment_distance(a, b, &tri[k], &tri[(k + 1) % 3]))
        .fold(ends, f64::min)
}

/// Shortest distance between two segments (Ericson, Real-Time Collision Detection §5.1.9).
fn segment_segment_distance(p1: &Vec3, q1: &Vec3, p2: &Vec3, q2: &Vec3) -> f64 {
    let (d1, d2, r) = (q1 - p1, q2 - p2, p1 - p2);
    let (a, e, f) = (d1.norm_squared(), d2.norm_squared(), d2.dot(&r));
    const EPS: f64 = 1e-18;
    let (s, t) = if a <= EPS && e <= EPS {
        (0.0, 0.0)
    } else if a <= EPS {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(&r);
        if e <= EPS {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(&d2);
            let denom = a * e - b * b;
            let mut s = if denom > EPS {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (b * s + f) / e;
            if t < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            }
            (s, t)
        }
    };
    ((p1 + d1 * s) - (p2 + d2 * t)).norm()
}

/// The force limits of a lesson (N, on the force the device is sent).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceLimits {
    /// Above it the force is excessive: a warning event.
    pub warning_n: f64,
    /// Above it the tissue is being torn: a critical event.
    pub critical_n: f64,
}

/// What it takes to pass a lesson.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassCriteria {
    /// Share of the planned length cut to depth within the allowed deviation (0–1).
    pub min_completed: f64,
    /// Largest RMS distance of the cut from the plan (m).
    pub max_rms_deviation_m: f64,
    /// Largest RMS depth error along the path (m).
    pub max_rms_depth_error_m: f64,
    /// Most force events above the critical limit.
    pub max_critical_events: u32,
    /// Most no-go structures cut.
    pub max_no_go_cuts: u32,
    /// Lowest score (0–100).
    pub min_score: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLesson {
    name: String,
    description: Option<String>,
    scene: String,
    time_limit_s: Option<f64>,
    incision: Vec<RawIncision>,
    #[serde(default)]
    no_go: Vec<RawNoGo>,
    force: Option<RawForce>,
    pass: Option<RawPass>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawIncision {
    name: Option<String>,
    points_mm: Option<Vec<[f64; 3]>>,
    bezier_mm: Option<Vec<[f64; 3]>>,
    depth_mm: f64,
    depth_tolerance_mm: Option<f64>,
    deviation_mm: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawNoGo {
    name: String,
    sphere_mm: Option<RawSphere>,
    tube_mm: Option<RawTube>,
    contact_margin_mm: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSphere {
    centre: [f64; 3],
    radius: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTube {
    from: [f64; 3],
    to: [f64; 3],
    radius: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawForce {
    warning_n: Option<f64>,
    critical_n: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPass {
    min_completed_percent: Option<f64>,
    max_rms_deviation_mm: Option<f64>,
    max_rms_depth_error_mm: Option<f64>,
    max_critical_events: Option<u32>,
    max_no_go_cuts: Option<u32>,
    min_score: Option<f64>,
}

/// Defaults (docs/LESSONS.md).
const DEFAULT_TIME_LIMIT_S: f64 = 120.0;
const DEFAULT_WARNING_N: f64 = 4.0;
const DEFAULT_CRITICAL_N: f64 = 6.0;
const DEFAULT_CONTACT_MARGIN_MM: f64 = 1.0;
const DEFAULT_MIN_COMPLETED_PERCENT: f64 = 90.0;
const DEFAULT_MIN_SCORE: f64 = 60.0;

impl LessonSpec {
    /// Parses a lesson file's text; `file` names it in messages.
    pub fn from_toml(text: &str, file: &str) -> Result<Self, LessonError> {
        let raw: RawLesson = toml::from_str(text).map_err(|e| LessonError::Parse {
            file: file.to_string(),
            message: e.to_string(),
        })?;
        let invalid = |key: String, message: String| LessonError::Invalid {
            file: file.to_string(),
            key,
            message,
        };
        let check = |key: &str, v: f64, lo: f64, hi: f64, unit: &str| {
            if v.is_finite() && v > lo && v <= hi {
                Ok(v)
            } else {
                Err(invalid(
                    key.to_string(),
                    format!("{v} is out of range: it must be in ({lo}, {hi}] {unit}"),
                ))
            }
        };
        if raw.name.trim().is_empty() {
            return Err(invalid("name".into(), "must not be empty".into()));
        }
        if raw.scene.trim().is_empty() {
            return Err(invalid(
                "scene".into(),
                "must name a built-in scene or a scene file".into(),
            ));
        }
        let time_limit_s = check(
            "time_limit_s",
            raw.time_limit_s.unwrap_or(DEFAULT_TIME_LIMIT_S),
            0.0,
            3600.0,
            "s",
        )?;
        if raw.incision.is_empty() {
            return Err(invalid(
                "incision".into(),
                "a lesson plans at least one incision ([[incision]])".into(),
            ));
        }
        let mut incisions = Vec::with_capacity(raw.incision.len());
        for (i, r) in raw.incision.iter().enumerate() {
            let key = |k: &str| format!("incision[{i}].{k}");
            let path = match (&r.points_mm, &r.bezier_mm) {
                (Some(points), None) => {
                    if points.len() < 2 {
                        return Err(invalid(
                            key("points_mm"),
                            format!("needs at least 2 points, has {}", points.len()),
                        ));
                    }
                    PathSpec::Polyline(mm_points(points, &key("points_mm"), &invalid)?)
                }
                (None, Some(points)) => {
                    let p = mm_points(points, &key("bezier_mm"), &invalid)?;
                    let Ok(controls) = <[Vec3; 4]>::try_from(p) else {
                        return Err(invalid(
                            key("bezier_mm"),
                            format!(
                                "a cubic Bézier has exactly 4 control points, not {}",
                                points.len()
                            ),
                        ));
                    };
                    PathSpec::Bezier(controls)
                }
                _ => {
                    return Err(invalid(
                        format!("incision[{i}]"),
                        "give its path as exactly one of points_mm or bezier_mm".into(),
                    ));
                }
            };
            let depth_mm = check(&key("depth_mm"), r.depth_mm, 0.0, 100.0, "mm")?;
            let tolerance_mm = check(
                &key("depth_tolerance_mm"),
                r.depth_tolerance_mm.unwrap_or(0.3 * depth_mm),
                0.0,
                depth_mm,
                "mm (at most the depth)",
            )?;
            let deviation_mm = check(
                &key("deviation_mm"),
                r.deviation_mm.unwrap_or(3.0),
                0.0,
                50.0,
                "mm",
            )?;
            incisions.push(IncisionSpec {
                name: r
                    .name
                    .clone()
                    .unwrap_or_else(|| format!("incision {}", i + 1)),
                path,
                depth_m: depth_mm * 1e-3,
                depth_tolerance_m: tolerance_mm * 1e-3,
                deviation_m: deviation_mm * 1e-3,
            });
        }
        let mut no_go = Vec::with_capacity(raw.no_go.len());
        for (i, r) in raw.no_go.iter().enumerate() {
            let key = |k: &str| format!("no_go[{i}].{k}");
            let shape = match (&r.sphere_mm, &r.tube_mm) {
                (Some(s), None) => NoGoShape::Sphere {
                    centre: mm_points(&[s.centre], &key("sphere_mm.centre"), &invalid)?[0],
                    radius: check(&key("sphere_mm.radius"), s.radius, 0.0, 100.0, "mm")? * 1e-3,
                },
                (None, Some(t)) => {
                    let ends = mm_points(&[t.from, t.to], &key("tube_mm"), &invalid)?;
                    if (ends[1] - ends[0]).norm() < 1e-4 {
                        return Err(invalid(
                            key("tube_mm"),
                            "from and to must be at least 0.1 mm apart".into(),
                        ));
                    }
                    NoGoShape::Tube {
                        from: ends[0],
                        to: ends[1],
                        radius: check(&key("tube_mm.radius"), t.radius, 0.0, 100.0, "mm")? * 1e-3,
                    }
                }
                _ => {
                    return Err(invalid(
                        format!("no_go[{i}]"),
                        "give its shape as exactly one of sphere_mm or tube_mm".into(),
                    ));
                }
            };
            let margin_mm = r.contact_margin_mm.unwrap_or(DEFAULT_CONTACT_MARGIN_MM);
            if !(margin_mm.is_finite() && (0.0..=20.0).contains(&margin_mm)) {
                return Err(invalid(
                    key("contact_margin_mm"),
                    format!("{margin_mm} is out of range: it must be in [0, 20] mm"),
                ));
            }
            no_go.push(NoGoSpec {
                name: r.name.clone(),
                shape,
                contact_margin_m: margin_mm * 1e-3,
            });
        }
        let force_raw = raw.force.as_ref();
        let warning_n = check(
            "force.warning_n",
            force_raw
                .and_then(|f| f.warning_n)
                .unwrap_or(DEFAULT_WARNING_N),
            0.0,
            50.0,
            "N",
        )?;
        let critical_n = check(
            "force.critical_n",
            force_raw
                .and_then(|f| f.critical_n)
                .unwrap_or(DEFAULT_CRITICAL_N.max(1.5 * warning_n).min(50.0)),
            0.0,
            50.0,
            "N",
        )?;
        if critical_n <= warning_n {
            return Err(invalid(
                "force.critical_n".into(),
                format!("{critical_n} N must be above force.warning_n ({warning_n} N)"),
            ));
        }
        let pass_raw = raw.pass.as_ref();
        let widest_deviation_mm = incisions.iter().map(|c| c.deviation_m).fold(0.0, f64::max) * 1e3;
        let widest_tolerance_mm = incisions
            .iter()
            .map(|c| c.depth_tolerance_m)
            .fold(0.0, f64::max)
            * 1e3;
        let percent = pass_raw
            .and_then(|p| p.min_completed_percent)
            .unwrap_or(DEFAULT_MIN_COMPLETED_PERCENT);
        if !(percent.is_finite() && (0.0..=100.0).contains(&percent)) {
            return Err(invalid(
                "pass.min_completed_percent".into(),
                format!("{percent} is out of range: it must be in [0, 100] %"),
            ));
        }
        let min_score = pass_raw
            .and_then(|p| p.min_score)
            .unwrap_or(DEFAULT_MIN_SCORE);
        if !(min_score.is_finite() && (0.0..=100.0).contains(&min_score)) {
            return Err(invalid(
                "pass.min_score".into(),
                format!("{min_score} is out of range: it must be in [0, 100]"),
            ));
        }
        let pass = PassCriteria {
            min_completed: percent / 100.0,
            max_rms_deviation_m: check(
                "pass.max_rms_deviation_mm",
                pass_raw
                    .and_then(|p| p.max_rms_deviation_mm)
                    .unwrap_or(widest_deviation_mm),
                0.0,
                50.0,
                "mm",
            )? * 1e-3,
            max_rms_depth_error_m: check(
                "pass.max_rms_depth_error_mm",
                pass_raw
                    .and_then(|p| p.max_rms_depth_error_mm)
                    .unwrap_or(widest_tolerance_mm),
                0.0,
                100.0,
                "mm",
            )? * 1e-3,
            max_critical_events: pass_raw.and_then(|p| p.max_critical_events).unwrap_or(0),
            max_no_go_cuts: pass_raw.and_then(|p| p.max_no_go_cuts).unwrap_or(0),
            min_score,
        };
        Ok(Self {
            name: raw.name,
            description: raw.description.unwrap_or_default(),
            scene: raw.scene,
            time_limit_s,
            incisions,
            no_go,
            force: ForceLimits {
                warning_n,
                critical_n,
            },
            pass,
        })
    }
}

/// Points in mm to metres, every coordinate finite and within a metre of the origin.
fn mm_points(
    points: &[[f64; 3]],
    key: &str,
    invalid: &dyn Fn(String, String) -> LessonError,
) -> Result<Vec<Vec3>, LessonError> {
    points
        .iter()
        .enumerate()
        .map(|(k, p)| {
            if p.iter().all(|c| c.is_finite() && c.abs() <= 1000.0) {
                Ok(Vec3::new(p[0], p[1], p[2]) * 1e-3)
            } else {
                Err(invalid(
                    format!("{key}[{k}]"),
                    format!("{p:?} must be finite and within 1000 mm of the origin"),
                ))
            }
        })
        .collect()
}
