//! Scripted blade trajectories: the offline `scalpel cut`, Table 1 and the scripted device.
//!
//! A script is a list of keyframes (time, tip position, edge direction); the pose between
//! two keyframes is interpolated linearly in position and spherically in orientation. The
//! default script is the paper's Fig. 9 experiment adapted to the scene: the blade comes
//! down on the top of the organ at 5 mm/s, cuts 10 mm deep along the organ's long axis for
//! 60 mm (at most 60 % of the organ's length), following the top surface, and comes out.
//!
//! Script files are TOML, in millimetres and seconds:
//!
//! ```toml
//! [[keyframe]]
//! t_s = 0.0
//! tip_mm = [-30.0, 0.0, 40.0]
//! edge = [0.0, 0.0, 1.0]     # from the tip toward the back of the blade (any length)
//! facing = [1.0, 0.0, 0.0]   # optional: where the sharp side faces (across the edge)
//!
//! [[keyframe]]
//! t_s = 3.0
//! tip_mm = [-30.0, 0.0, 25.0]
//! ```
//! A keyframe without `edge` (or `facing`) keeps the previous one's. Without any `facing`
//! the blade's flat is the plane of the edge and the x axis turned with the edge (for an
//! upright blade: facing +x); it matters for a stab, whose slit runs from the edge back
//! across the flat. The same in CSV (`.csv`; `facing` in three more columns,
//! `facing_x,facing_y,facing_z`, when the header has them):
//!
//! ```text
//! t_s,tip_x_mm,tip_y_mm,tip_z_mm,edge_x,edge_y,edge_z
//! 0.0,-30.0,0.0,40.0,0.0,0.0,1.0
//! 3.0,-30.0,0.0,25.0,,,
//! ```

use serde::Deserialize;
use thiserror::Error;

use crate::cut::ToolPose;
use crate::geometry::TriMesh;
use crate::math::Vec3;
use crate::scene::file::readable_number;

/// Default blade speed (m/s), the paper's Fig. 9.
pub const DEFAULT_SPEED_M_PER_S: f64 = 0.005;
/// Default stroke length (m).
pub const DEFAULT_STROKE_M: f64 = 0.060;
/// Default cut depth (m).
pub const DEFAULT_DEPTH_M: f64 = 0.010;
/// Most keyframes a script file may have.
pub const MAX_KEYFRAMES: usize = 100_000;

/// The fastest a script's tip may move between keyframes (m/s): a surgeon's quickest hand
/// motions stay under 1 m/s; faster is a teleport, which the force model would read as a
/// cut kilometres long.
pub const MAX_TIP_SPEED_M_PER_S: f64 = 2.0;
/// The header line of a CSV script.
pub const CSV_HEADER: &str = "t_s,tip_x_mm,tip_y_mm,tip_z_mm,edge_x,edge_y,edge_z";
/// The columns a CSV script may add after [`CSV_HEADER`]: where the blade faces.
pub const CSV_FACING_COLUMNS: &str = "facing_x,facing_y,facing_z";

/// One keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keyframe {
    /// Time (s).
    pub t_s: f64,
    /// Blade pose.
    pub pose: ToolPose,
}

/// A blade trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct CutScript {
    /// Keyframes in increasing time.
    pub keyframes: Vec<Keyframe>,
    /// What the script does, for reports.
    pub description: String,
}

/// Why a script was rejected.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ScriptError {
    /// Not valid TOML, or a key of the wrong type or unknown.
    #[error("{file}: {message}")]
    Parse {
        /// Script file.
        file: String,
        /// The parser's message, with line and column.
        message: String,
    },
    /// A keyframe is inconsistent.
    #[error("{file}: keyframe {index}: {message}")]
    Invalid {
        /// Script file.
        file: String,
        /// 1-based keyframe number.
        index: usize,
        /// What is wrong.
        message: String,
    },
    /// The scene has no top surface to cut along.
    #[error("the default cut needs a surface under the stroke: {0}")]
    NoSurface(String),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScript {
    keyframe: Vec<RawKeyframe>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawKeyframe {
    t_s: f64,
    tip_mm: [f64; 3],
    edge: Option<[f64; 3]>,
    facing: Option<[f64; 3]>,
}

impl CutScript {
    /// Parses a script file's text; `file` names it in messages.
    pub fn from_toml(text: &str, file: &str) -> Result<Self, ScriptError> {
        let raw: RawScript = toml::from_str(text).map_err(|e| ScriptError::Parse {
            file: file.to_string(),
            message: e.to_string(),
        })?;
        Self::from_raw(&raw, file)
    }

    /// Parses a CSV script: a header line `t_s,tip_x_mm,tip_y_mm,tip_z_mm,edge_x,edge_y,edge_z`
    /// (optionally followed by `,facing_x,facing_y,facing_z`) then one keyframe per line;
    /// the edge (and facing) columns may be left empty to keep the previous keyframe's.
    /// `file` names it in messages.
    pub fn from_csv(text: &str, file: &str) -> Result<Self, ScriptError> {
        let parse_error = |line: usize, message: String| ScriptError::Parse {
            file: file.to_string(),
            message: format!("line {line}: {message}"),
        };
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty());
        let header = lines.next().map(|(_, l)| l.trim()).unwrap_or("");
        let columns = match header.strip_prefix(CSV_HEADER) {
            Some("") => 7,
            Some(rest) if rest.strip_prefix(',') == Some(CSV_FACING_COLUMNS) => 10,
            _ => {
                return Err(parse_error(
                    1,
                    format!(
                        "the header must be `{CSV_HEADER}`, or that and `,{CSV_FACING_COLUMNS}`"
                    ),
                ));
            }
        };
        let mut keyframe = Vec::new();
        for (n, line) in lines {
            if keyframe.len() > MAX_KEYFRAMES {
                break;
            }
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if cells.len() != columns {
                return Err(parse_error(
                    n + 1,
                    format!("{columns} columns expected, found {}", cells.len()),
                ));
            }
            let number = |k: usize| {
                cells[k].parse::<f64>().map_err(|_| {
                    parse_error(
                        n + 1,
                        format!("column {}: {:?} is not a number", k + 1, cells[k]),
                    )
                })
            };
            // Three columns from `k`: all empty keeps the previous keyframe's.
            let direction = |k: usize| {
                if cells[k..k + 3].iter().all(|c| c.is_empty()) {
                    Ok(None)
                } else {
                    Ok(Some([number(k)?, number(k + 1)?, number(k + 2)?]))
                }
            };
            keyframe.push(RawKeyframe {
                t_s: number(0)?,
                tip_mm: [number(1)?, number(2)?, number(3)?],
                edge: direction(4)?,
                facing: if columns == 10 { direction(7)? } else { None },
            });
        }
        Self::from_raw(&RawScript { keyframe }, file)
    }

    /// A script file's text: CSV if its name ends in `.csv`, TOML otherwise (the caller
    /// reads the file: `scalpel_server::scene_file::load_script`).
    pub fn from_file_text(text: &str, file: &str) -> Result<Self, ScriptError> {
        if std::path::Path::new(file)
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
        {
            Self::from_csv(text, file)
        } else {
            Self::from_toml(text, file)
        }
    }

    fn from_raw(raw: &RawScript, file: &str) -> Result<Self, ScriptError> {
        // A unit vector along `v`, scaled first so that neither 1e-200 nor 1e200 is lost.
        // (`amax` skips a NaN: checked first.)
        let direction = |v: [f64; 3]| {
            let v = Vec3::from(v);
            let largest = v.amax();
            (v.iter().all(|c| c.is_finite()) && largest > 0.0).then(|| (v / largest).normalize())
        };
        let invalid = |index: usize, message: String| ScriptError::Invalid {
            file: file.to_string(),
            index: index + 1,
            message,
        };
        if raw.keyframe.len() < 2 {
            return Err(ScriptError::Parse {
                file: file.to_string(),
                message: format!(
                    "a script needs at least 2 [[keyframe]] tables, found {}",
                    raw.keyframe.len()
                ),
            });
        }
        if raw.keyframe.len() > MAX_KEYFRAMES {
            return Err(invalid(
                MAX_KEYFRAMES,
                format!("at most {MAX_KEYFRAMES} keyframes"),
            ));
        }
        let mut keyframes = Vec::with_capacity(raw.keyframe.len());
        let mut edge: Option<Vec3> = None;
        let mut facing: Option<Vec3> = None;
        // As written, for messages.
        let (mut edge_given, mut facing_given) = ([0.0; 3], [0.0; 3]);
        for (index, k) in raw.keyframe.iter().enumerate() {
            if !k.t_s.is_finite() || k.t_s < 0.0 || k.t_s > 86_400.0 {
                return Err(invalid(
                    index,
                    format!(
                        "t_s = {} must be within 0..=86400 s",
                        readable_number(k.t_s)
                    ),
                ));
            }
            if let Some(prev) = keyframes.last().map(|k: &Keyframe| k.t_s)
                && k.t_s <= prev
            {
                return Err(invalid(
                    index,
                    format!(
                        "t_s = {} must be after the previous keyframe's {}",
                        readable_number(k.t_s),
                        readable_number(prev)
                    ),
                ));
            }
            if k.tip_mm.iter().any(|c| !c.is_finite() || c.abs() > 1e4) {
                return Err(invalid(
                    index,
                    format!("tip_mm = {:?} must be finite and within ±10 m", k.tip_mm),
                ));
            }
            if let Some(e) = k.edge {
                edge_given = e;
                edge = Some(direction(e).ok_or_else(|| {
                    invalid(
                        index,
                        format!("edge = {e:?} must be a finite, non-zero direction"),
                    )
                })?);
            }
            let Some(e) = edge else {
                return Err(invalid(
                    index,
                    "the first keyframe needs an edge direction".into(),
                ));
            };
            if let Some(f) = k.facing {
                facing_given = f;
                facing = Some(direction(f).ok_or_else(|| {
                    invalid(
                        index,
                        format!("facing = {f:?} must be a finite, non-zero direction"),
                    )
                })?);
            }
            // (Checked on every keyframe: a kept `facing` must also be across a new edge.)
            if let Some(f) = facing {
                let square = f - e * (f.dot(&e) / e.norm_squared());
                if !f.iter().all(|c| c.is_finite()) || square.norm() < 1e-3 * f.norm() {
                    return Err(invalid(
                        index,
                        format!(
                            "facing = {facing_given:?} must be a direction across the edge {edge_given:?}"
                        ),
                    ));
                }
            }
            let tip = Vec3::from(k.tip_mm) * 1e-3;
            if let Some(prev) = keyframes.last() {
                let speed = (tip - prev.pose.tip_m).norm() / (k.t_s - prev.t_s);
                if speed > MAX_TIP_SPEED_M_PER_S {
                    return Err(invalid(
                        index,
                        format!(
                            "the tip moves {:.1} mm in {} s from the previous keyframe ({speed:.3e} m/s): at most {MAX_TIP_SPEED_M_PER_S} m/s, a hand's quickest",
                            (tip - prev.pose.tip_m).norm() * 1e3,
                            readable_number(k.t_s - prev.t_s)
                        ),
                    ));
                }
            }
            keyframes.push(Keyframe {
                t_s: k.t_s,
                pose: match facing {
                    Some(f) => ToolPose::facing(tip, e, f),
                    None => ToolPose::pointing(tip, e),
                },
            });
        }
        Ok(Self {
            keyframes,
            description: format!("script {file}"),
        })
    }

    /// The default cut for a surface (see the module documentation).
    pub fn default_for(surface: &TriMesh) -> Result<Self, ScriptError> {
        Self::stroke_for(
            surface,
            DEFAULT_STROKE_M,
            DEFAULT_DEPTH_M,
            DEFAULT_SPEED_M_PER_S,
        )
    }

    /// A straight stroke along the surface's long horizontal axis through its centre, at
    /// most `length_m` long (and 60 % of the organ), `depth_m` deep (at most 30 % of the
    /// thickness at the centre), at `speed` m/s, following the top surface. A shape with no
    /// surface above its centre is cut on the nearby part of its top that has the room.
    pub fn stroke_for(
        surface: &TriMesh,
        length_m: f64,
        depth_m: f64,
        speed: f64,
    ) -> Result<Self, ScriptError> {
        let bbox = surface.bbox();
        let (lo, hi) = (Vec3::from(bbox.min), Vec3::from(bbox.max));
        let size = hi - lo;
        let centre = (hi + lo) * 0.5;
        let axis = if size.x >= size.y {
            Vec3::x()
        } else {
            Vec3::y()
        };
        let along = axis.dot(&size);
        // Through the middle of the top seen from above: the centre of the bounding box, or
        // on a shape with nothing above it (a muscle sheet curved round a joint) a point of
        // the top near it with room for the stroke; the stroke stays where the top goes on
        // smoothly.
        let wanted = length_m.min(0.6 * along);
        let over_centre = vertical_extent(surface, centre.x, centre.y).map(|_| {
            (
                centre,
                smooth_top_room(surface, &centre, &axis, 0.5 * wanted),
            )
        });
        let (centre, half_room) = match over_centre {
            Some(found) if found.1 >= 0.125 * wanted => found,
            _ => roomiest_top_near(surface, &centre, &axis, 0.5 * wanted)
                .ok_or_else(|| ScriptError::NoSurface("no surface facing up to cut into".into()))?,
        };
        let length = wanted.min(2.0 * half_room);
        if length < 0.25 * wanted {
            return Err(ScriptError::NoSurface(format!(
                "the top near the centre goes on smoothly for {:.0} mm at most, too short for \
                 a {:.0} mm stroke",
                length * 1e3,
                wanted * 1e3
            )));
        }
        let depth = stroke_depth(surface, &centre, depth_m).ok_or_else(|| {
            ScriptError::NoSurface("no tissue under the top at the stroke's centre".into())
        })?;
        let start = centre - axis * (length * 0.5);
        if vertical_extent(surface, start.x, start.y).is_none() {
            return Err(ScriptError::NoSurface(
                "no surface under the start of the stroke".into(),
            ));
        }
        let mut keyframes = Vec::new();
        let stroke = Stroke {
            start,
            axis,
            length,
            depth,
            clearance: 0.005,
            plunge_speed: speed,
            speed,
        };
        stroke.push_onto(surface, &mut keyframes, 0.0);
        Ok(Self {
            keyframes,
            description: format!(
                "{:.0} mm stroke along {}, {:.1} mm deep, {:.1} mm/s",
                length * 1e3,
                if axis.x > 0.5 { "x" } else { "y" },
                depth * 1e3,
                speed * 1e3
            ),
        })
    }

    /// A lab session: `strokes` straight cuts one after the other, at places and headings
    /// drawn from `seed` over the top of the organ (the middle 70 % of its bounding box
    /// seen from above), each 10–18 % of the organ's long side, 5–10 mm deep (at most 30 %
    /// of the thickness at its middle and half the tissue under the top), following the top
    /// at 8 mm/s; the blade goes in and comes out at 10 mm/s, facing along the stroke, and
    /// takes a second, 10 mm above the organ, to the next. Strokes fall on earlier wounds
    /// as they happen to (crossings, parallel cuts). A place whose top does not go on
    /// smoothly for the stroke's length is drawn again (up to 100 times, then the session
    /// is a stroke shorter); an error if no stroke fits at all.
    pub fn session_for(surface: &TriMesh, strokes: usize, seed: u64) -> Result<Self, ScriptError> {
        const CLEARANCE_M: f64 = 0.010;
        const STROKE_SPEED: f64 = 0.008;
        const PLUNGE_SPEED: f64 = 0.010;
        const TRAVEL_S: f64 = 1.0;
        let bbox = surface.bbox();
        let (lo, hi) = (Vec3::from(bbox.min), Vec3::from(bbox.max));
        let size = hi - lo;
        let long_side = size.x.max(size.y);
        let mut state = seed;
        let mut uniform = move |a: f64, b: f64| a + (b - a) * unit_random(&mut state);
        let mut keyframes: Vec<Keyframe> = Vec::new();
        let mut t = 0.0;
        let mut made = 0;
        for _ in 0..strokes {
            let found = (0..100).find_map(|_| {
                let centre = Vec3::new(
                    uniform(lo.x + 0.15 * size.x, hi.x - 0.15 * size.x),
                    uniform(lo.y + 0.15 * size.y, hi.y - 0.15 * size.y),
                    0.0,
                );
                let heading = uniform(0.0, std::f64::consts::TAU);
                let axis = Vec3::new(heading.cos(), heading.sin(), 0.0);
                let length = uniform(0.10, 0.18) * long_side;
                let depth_wanted = uniform(0.005, 0.010);
                // The top must go on smoothly for the length (to a millimetre).
                let half = 0.5 * length;
                if smooth_top_room(surface, &centre, &axis, half) < half - 0.001 {
                    return None;
                }
                let depth = stroke_depth(surface, &centre, depth_wanted)?;
                Some((centre - axis * half, axis, length, depth))
            });
            let Some((start, axis, length, depth)) = found else {
                continue;
            };
            made += 1;
            if made > 1 {
                t += TRAVEL_S;
            }
            let stroke = Stroke {
                start,
                axis,
                length,
                depth,
                clearance: CLEARANCE_M,
                plunge_speed: PLUNGE_SPEED,
                speed: STROKE_SPEED,
            };
            t = stroke.push_onto(surface, &mut keyframes, t);
        }
        if made == 0 {
            return Err(ScriptError::NoSurface(
                "no place on the top goes on smoothly for a stroke".into(),
            ));
        }
        Ok(Self {
            keyframes,
            description: format!("a session of {made} strokes (seed {seed})"),
        })
    }

    /// Duration (s).
    pub fn duration_s(&self) -> f64 {
        self.keyframes.last().map_or(0.0, |k| k.t_s)
    }

    /// The ticks of `dt` that play the whole script: tick k takes the pose at k·dt, and
    /// the last one the pose at (or just past) the end. What `scalpel cut` runs, and the
    /// cut regression tests with it.
    pub fn tick_count(&self, dt: f64) -> usize {
        (self.duration_s() / dt).ceil() as usize + 1
    }

    /// The script as a TOML script file ([`CutScript::from_toml`] reads it back to within
    /// the printed digits: nanometres, nanoseconds).
    pub fn to_toml(&self) -> String {
        use std::fmt::Write as _;
        let mut s = format!("# {}\n", self.description.replace('\n', " "));
        for k in &self.keyframes {
            let (tip, q) = (k.pose.tip_m * 1e3, k.pose.orientation);
            let (edge, facing) = (q * Vec3::z(), q * Vec3::x());
            let _ = writeln!(
                s,
                "\n[[keyframe]]\nt_s = {:.9}\ntip_mm = [{:.6}, {:.6}, {:.6}]\n\
                 edge = [{:.9}, {:.9}, {:.9}]\nfacing = [{:.9}, {:.9}, {:.9}]",
                k.t_s, tip.x, tip.y, tip.z, edge.x, edge.y, edge.z, facing.x, facing.y, facing.z
            );
        }
        s
    }

    /// The pose at time `t` (held at the ends).
    pub fn pose_at(&self, t: f64) -> ToolPose {
        let k = &self.keyframes;
        let i = k.partition_point(|f| f.t_s <= t);
        if i == 0 {
            return k[0].pose;
        }
        if i >= k.len() {
            return k[k.len() - 1].pose;
        }
        let (a, b) = (&k[i - 1], &k[i]);
        let s = ((t - a.t_s) / (b.t_s - a.t_s)).clamp(0.0, 1.0);
        ToolPose {
            tip_m: a.pose.tip_m.lerp(&b.pose.tip_m, s),
            orientation: a
                .pose
                .orientation
                .try_slerp(&b.pose.orientation, s, 1e-9)
                .unwrap_or(if s < 0.5 {
                    a.pose.orientation
                } else {
                    b.pose.orientation
                }),
        }
    }
}

/// One straight stroke that follows the top of the surface.
struct Stroke {
    /// Where it starts, seen from above (its z is not used).
    start: Vec3,
    /// Unit horizontal direction.
    axis: Vec3,
    length: f64,
    /// Below the top (m).
    depth: f64,
    /// Height above the top where the blade starts and ends (m).
    clearance: f64,
    /// Speed going in and out, and along (m/s).
    plunge_speed: f64,
    speed: f64,
}

impl Stroke {
    /// Appends its keyframes from time `t`, upright and facing along the stroke (its back
    /// trails, as a hand holds it): down from above the start, along the top sampled every
    /// 5 mm, and out; returns the time at its end.
    fn push_onto(&self, surface: &TriMesh, keyframes: &mut Vec<Keyframe>, mut t: f64) -> f64 {
        let top_at = |x: &Vec3| vertical_extent(surface, x.x, x.y).map(|(top, _)| top);
        let (start, depth) = (self.start, self.depth);
        let mut push = |tip: Vec3, t: f64| {
            keyframes.push(Keyframe {
                t_s: t,
                pose: ToolPose::facing(tip, Vec3::z(), self.axis),
            })
        };
        let top0 = top_at(&start).unwrap_or(start.z);
        let above = Vec3::new(start.x, start.y, top0 + self.clearance);
        push(above, t);
        let mut last = Vec3::new(start.x, start.y, top0 - depth);
        t += (last - above).norm() / self.plunge_speed;
        push(last, t);
        let samples = ((self.length / 0.005).ceil() as usize).max(2);
        for k in 1..=samples {
            let x = start + self.axis * (self.length * k as f64 / samples as f64);
            let tip = Vec3::new(x.x, x.y, top_at(&x).unwrap_or(last.z + depth) - depth);
            t += (tip - last).norm() / self.speed;
            push(tip, t);
            last = tip;
        }
        let out = Vec3::new(last.x, last.y, last.z + depth + self.clearance);
        t += (out - last).norm() / self.plunge_speed;
        push(out, t);
        t
    }
}

/// A number in [0, 1) from a SplitMix64 state (a session's strokes are the same on every
/// machine for a seed).
fn unit_random(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Highest and lowest crossing of the vertical line through (x, y) with the surface.
pub fn vertical_extent(surface: &TriMesh, x: f64, y: f64) -> Option<(f64, f64)> {
    let z = vertical_crossings(surface, x, y);
    match (z.first(), z.last()) {
        (Some(&top), Some(&bottom)) if top > bottom => Some((top, bottom)),
        _ => None,
    }
}

/// Heights where the vertical line through (x, y) meets the surface, highest first; a line
/// through a shared edge or vertex meets it once (the block's centre is a grid vertex).
fn vertical_crossings(surface: &TriMesh, x: f64, y: f64) -> Vec<f64> {
    let bbox = surface.bbox();
    let tolerance = 1e-9 * (Vec3::from(bbox.max) - Vec3::from(bbox.min)).norm();
    let mut z = Vec::new();
    for t in 0..surface.triangles.len() {
        let [a, b, c] = surface.corners(t);
        let d = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if d.abs() < 1e-300 {
            continue;
        }
        let u = ((x - a.x) * (c.y - a.y) - (c.x - a.x) * (y - a.y)) / d;
        let v = ((b.x - a.x) * (y - a.y) - (x - a.x) * (b.y - a.y)) / d;
        if u >= 0.0 && v >= 0.0 && u + v <= 1.0 {
            z.push(a.z + u * (b.z - a.z) + v * (c.z - a.z));
        }
    }
    z.sort_by(|p, q| q.total_cmp(p));
    z.dedup_by(|lower, upper| *upper - *lower <= tolerance);
    z
}

/// Of the upward-facing triangles (normal within 45° of +z) nearest to `x` seen from above,
/// the centroid where the top goes on smoothly furthest along `axis` (up to `wanted` either
/// way), with that reach.
fn roomiest_top_near(surface: &TriMesh, x: &Vec3, axis: &Vec3, wanted: f64) -> Option<(Vec3, f64)> {
    let mut tops: Vec<Vec3> = (0..surface.triangles.len())
        .filter(|&t| {
            surface
                .doubled_area_normal(t)
                .try_normalize(1e-300)
                .is_some_and(|n| n.z > std::f64::consts::FRAC_1_SQRT_2)
        })
        .map(|t| {
            let [a, b, c] = surface.corners(t);
            (a + b + c) / 3.0
        })
        .collect();
    tops.sort_by(|p, q| (p - x).xy().norm().total_cmp(&(q - x).xy().norm()));
    let mut best: Option<(Vec3, f64)> = None;
    // The nearest few dozen: the first with room for the whole stroke, or the roomiest.
    for c in tops.into_iter().take(48) {
        let room = smooth_top_room(surface, &c, axis, wanted);
        if best.is_none_or(|(_, r)| room > r) {
            best = Some((c, room));
        }
        if room >= wanted {
            break;
        }
    }
    best
}

/// How deep a stroke through `centre` (seen from above) may cut, `wanted` at most: a third
/// of the shape's height there, and no more than half the tissue under the top (down to the
/// next surface: a sheet can fold back under itself). `None` if there is no tissue there.
fn stroke_depth(surface: &TriMesh, centre: &Vec3, wanted: f64) -> Option<f64> {
    let crossings = vertical_crossings(surface, centre.x, centre.y);
    let (&[top, below, ..], Some(&bottom)) = (&crossings[..], crossings.last()) else {
        return None;
    };
    Some(wanted.min(0.3 * (top - bottom)).min(0.5 * (top - below)))
}

/// How far (up to `wanted`) either way along `axis` from `centre` the top goes on without a
/// gap or a step (checked every millimetre: a step of more than 2 mm per millimetre is the
/// edge of a fold, not the slope of the top).
fn smooth_top_room(surface: &TriMesh, centre: &Vec3, axis: &Vec3, wanted: f64) -> f64 {
    const STEP_M: f64 = 0.001;
    let top = |s: f64| {
        let x = centre + axis * s;
        vertical_extent(surface, x.x, x.y).map(|(top, _)| top)
    };
    let steps = (wanted / STEP_M).floor() as usize;
    let reach = |sign: f64| {
        let mut last = top(0.0);
        for k in 1..=steps {
            let here = top(sign * k as f64 * STEP_M);
            match (last, here) {
                (Some(a), Some(b)) if (b - a).abs() <= 2.0 * STEP_M => last = here,
                _ => return (k - 1) as f64 * STEP_M,
            }
        }
        wanted
    };
    reach(1.0).min(reach(-1.0))
}

#[cfg(test)]
mod tests;
