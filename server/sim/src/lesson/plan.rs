//! A lesson laid on its organ: each planned incision resampled along its length and projected
//! onto the surface (rest space), with the surface's outward normal and the path's tangent
//! at every sample, so that the scorer measures a cut against the surface it was made in.

use super::spec::{IncisionSpec, LessonError, LessonSpec, NoGoShape, PathSpec};
use crate::geometry::TriMesh;
use crate::geometry::predicates::{
    closest_point_on_triangle, distance_sq_to_segment, nearest_on_segment,
};
use crate::math::Vec3;

/// Spacing of a plan's samples along its path (m).
pub const SAMPLE_M: f64 = 0.5e-3;
/// Farthest a written path point may lie from the organ's surface (m).
const MAX_OFF_SURFACE_M: f64 = 0.020;
/// Longest planned incision (m).
const MAX_LENGTH_M: f64 = 1.0;
/// Longest plan, all incisions together (m): 2 000 samples, the scorer's pass over them
/// (the nearest piece of path each cutting tick, the band for each new Σ triangle) tens of
/// microseconds at most.
pub const MAX_TOTAL_LENGTH_M: f64 = 1.0;
/// Samples each side averaged into a sample's normal: the surface's facets smoothed over
/// about 4 mm, so a path over a coarse mesh does not turn its blade at every edge.
const NORMAL_SMOOTHING: usize = 8;

/// One sample of a planned incision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanSample {
    /// On the surface (m, rest space).
    pub at: Vec3,
    /// The surface's outward unit normal there.
    pub out: Vec3,
    /// The path's unit direction there.
    pub tangent: Vec3,
    /// Arc length from the path's start (m).
    pub s_m: f64,
    /// The surface triangle it lies on and its barycentric coordinates there: where the
    /// same material is on the surface as the organ rests or deforms ([`PlanSample::on`]).
    pub triangle: u32,
    /// Barycentric coordinates in `triangle`.
    pub bary: [f64; 3],
}

impl PlanSample {
    /// Where the sample's material is on `surface` (the rest surface's vertices moved,
    /// e.g. the organ resting on its supports), with the outward unit normal there.
    pub fn on(&self, surface: &TriMesh) -> (Vec3, Vec3) {
        let [a, b, c] = surface.corners(self.triangle as usize);
        let at = a * self.bary[0] + b * self.bary[1] + c * self.bary[2];
        let out = surface
            .doubled_area_normal(self.triangle as usize)
            .try_normalize(1e-30)
            .unwrap_or(self.out);
        (at, out)
    }
}

/// A planned incision on the organ.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedIncision {
    /// Name, for reports.
    pub name: String,
    /// Samples every [`SAMPLE_M`] or so along the projected path.
    pub samples: Vec<PlanSample>,
    /// Projected length (m).
    pub length_m: f64,
    /// Target depth (m).
    pub depth_m: f64,
    /// Allowed depth error (m).
    pub depth_tolerance_m: f64,
    /// Allowed distance from the path (m).
    pub deviation_m: f64,
}

/// The point of a plan nearest a given point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OnPlan {
    /// Which incision.
    pub incision: usize,
    /// The sample nearest the nearest point of the path (the nearer end of its piece).
    pub sample: usize,
    /// Distance from the path (m).
    pub distance_m: f64,
}

/// A lesson laid on its organ.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The lesson as written.
    pub spec: LessonSpec,
    /// Its incisions on the surface.
    pub incisions: Vec<PlannedIncision>,
    /// Total planned length (m).
    pub length_m: f64,
    /// The widest allowed deviation of its incisions (m): the band Σ is judged against.
    pub widest_deviation_m: f64,
    /// The planned band's area, Σ length × deviation (m²): the scale of cut area off it.
    pub band_area_m2: f64,
}

impl Plan {
    /// Lays `spec` on `surface` (the scene's rest surface, m); `file` names the lesson in
    /// errors. Refused: a path point farther than 20 mm from the surface, a path whose
    /// projection jumps (it would fold onto another part of the organ), a path longer than
    /// a metre, a no-go structure nowhere near the organ.
    pub fn new(spec: LessonSpec, surface: &TriMesh, file: &str) -> Result<Self, LessonError> {
        let invalid = |key: String, message: String| LessonError::Invalid {
            file: file.to_string(),
            key,
            message,
        };
        let mut incisions = Vec::with_capacity(spec.incisions.len());
        for (i, inc) in spec.incisions.iter().enumerate() {
            incisions.push(lay(inc, surface, |k, m| {
                invalid(format!("incision[{i}]{k}"), m)
            })?);
        }
        let bbox = surface.bbox();
        let (lo, hi) = (Vec3::from(bbox.min), Vec3::from(bbox.max));
        for (i, n) in spec.no_go.iter().enumerate() {
            let centre = (lo + hi) * 0.5;
            let inside_box =
                |p: &Vec3| (0..3).all(|a| p[a] >= lo[a] - 1e-3 && p[a] <= hi[a] + 1e-3);
            let touches = match n.shape {
                // The ball reaches within the box's circumscribed ball.
                NoGoShape::Sphere { centre: c, radius } => {
                    inside_box(&c) || (c - centre).norm() < (hi - lo).norm() * 0.5 + radius
                }
                NoGoShape::Tube { from, to, .. } => {
                    inside_box(&from)
                        || inside_box(&to)
                        || inside_box(
                            &(from + (to - from) * nearest_on_segment(&centre, &from, &to)),
                        )
                }
            };
            if !touches {
                return Err(invalid(
                    format!("no_go[{i}]"),
                    format!(
                        "'{}' lies outside the organ (its bounding box is {:.0}..{:.0}, \
                         {:.0}..{:.0}, {:.0}..{:.0} mm)",
                        n.name,
                        lo.x * 1e3,
                        hi.x * 1e3,
                        lo.y * 1e3,
                        hi.y * 1e3,
                        lo.z * 1e3,
                        hi.z * 1e3
                    ),
                ));
            }
        }
        let length_m: f64 = incisions.iter().map(|c| c.length_m).sum();
        if length_m > MAX_TOTAL_LENGTH_M {
            return Err(invalid(
                "incision".into(),
                format!(
                    "the incisions are {:.0} mm long in all (at most {:.0} mm)",
                    length_m * 1e3,
                    MAX_TOTAL_LENGTH_M * 1e3
                ),
            ));
        }
        let widest_deviation_m = incisions.iter().map(|c| c.deviation_m).fold(0.0, f64::max);
        let band_area_m2 = incisions.iter().map(|c| c.length_m * c.deviation_m).sum();
        Ok(Self {
            spec,
            incisions,
            length_m,
            widest_deviation_m,
            band_area_m2,
        })
    }

    /// The plan's point nearest `p`, over every incision.
    pub fn nearest(&self, p: &Vec3) -> Option<OnPlan> {
        let mut best: Option<OnPlan> = None;
        for (i, inc) in self.incisions.iter().enumerate() {
            for (k, w) in inc.samples.windows(2).enumerate() {
                let q = w[0].at + (w[1].at - w[0].at) * nearest_on_segment(p, &w[0].at, &w[1].at);
                let d = (p - q).norm();
                if best.is_none_or(|b| d < b.distance_m) {
                    let sample = if (q - w[1].at).norm() < (q - w[0].at).norm() {
                        k + 1
                    } else {
                        k
                    };
                    best = Some(OnPlan {
                        incision: i,
                        sample,
                        distance_m: d,
                    });
                }
            }
        }
        best
    }

    /// Distance from `p` to the planned cut: the ribbon each incision's path sweeps going
    /// down its surface normal to its target depth plus tolerance (m).
    pub fn distance_to_band(&self, p: &Vec3) -> f64 {
        let mut best = f64::INFINITY;
        for inc in &self.incisions {
            let reach = inc.depth_m + inc.depth_tolerance_m;
            for s in &inc.samples {
                let bottom = s.at - s.out * reach;
                let d = distance_sq_to_segment(p, &s.at, &bottom).sqrt();
                best = best.min(d);
            }
        }
        best
    }
}

/// Resamples and projects one incision; `invalid(key suffix, message)` builds its errors.
fn lay(
    inc: &IncisionSpec,
    surface: &TriMesh,
    invalid: impl Fn(&str, String) -> LessonError,
) -> Result<PlannedIncision, LessonError> {
    let (written, key) = match &inc.path {
        PathSpec::Polyline(points) => (points.clone(), ".points_mm"),
        PathSpec::Bezier(c) => (
            (0..=1000)
                .map(|k| {
                    let t = k as f64 / 1000.0;
                    let u = 1.0 - t;
                    c[0] * (u * u * u)
                        + c[1] * (3.0 * u * u * t)
                        + c[2] * (3.0 * u * t * t)
                        + c[3] * (t * t * t)
                })
                .collect(),
            ".bezier_mm",
        ),
    };
    if let PathSpec::Polyline(points) = &inc.path {
        for (k, p) in points.iter().enumerate() {
            let (q, _, _) = nearest_on_surface(surface, p);
            let off = (q - p).norm();
            if off > MAX_OFF_SURFACE_M {
                return Err(invalid(
                    &format!("{key}[{k}]"),
                    format!(
                        "is {:.1} mm from the organ's surface (at most {:.0} mm: a path is \
                         drawn on the surface)",
                        off * 1e3,
                        MAX_OFF_SURFACE_M * 1e3
                    ),
                ));
            }
        }
    }
    let written_length: f64 = written.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    if written_length < 2.0 * SAMPLE_M {
        return Err(invalid(
            key,
            format!(
                "the path is {:.2} mm long: too short to cut",
                written_length * 1e3
            ),
        ));
    }
    if written_length > MAX_LENGTH_M {
        return Err(invalid(
            key,
            format!(
                "the path is {:.0} mm long (at most {:.0} mm)",
                written_length * 1e3,
                MAX_LENGTH_M * 1e3
            ),
        ));
    }
    // Evenly along the written path, onto the surface, and again evenly along what landed
    // there (a slope or a bend spreads the first projection's samples) and onto it.
    let mut projected = Vec::new();
    for pass in 0..2 {
        let along = if pass == 0 {
            written.clone()
        } else {
            projected
                .iter()
                .map(|p: &(Vec3, Vec3, usize)| p.0)
                .collect()
        };
        let length: f64 = along.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        projected.clear();
        for (s, p) in resample(&along, length) {
            let (q, normal, t) = nearest_on_surface(surface, &p);
            if (q - p).norm() > MAX_OFF_SURFACE_M {
                return Err(invalid(
                    key,
                    format!(
                        "{:.0} mm along, the path is {:.1} mm from the organ's surface (at \
                         most {:.0} mm)",
                        s * 1e3,
                        (q - p).norm() * 1e3,
                        MAX_OFF_SURFACE_M * 1e3
                    ),
                ));
            }
            projected.push((q, normal, t));
        }
    }
    for (k, w) in projected.windows(2).enumerate() {
        let gap = (w[1].0 - w[0].0).norm();
        if gap > 6.0 * SAMPLE_M {
            return Err(invalid(
                key,
                format!(
                    "{:.0} mm along, the path's projection onto the surface jumps {:.1} mm: \
                     it folds onto another part of the organ (draw it closer to the surface)",
                    k as f64 * SAMPLE_M * 1e3,
                    gap * 1e3
                ),
            ));
        }
    }
    let projected_length: f64 = projected.windows(2).map(|w| (w[1].0 - w[0].0).norm()).sum();
    if projected_length < 2.0 * SAMPLE_M {
        return Err(invalid(
            key,
            format!(
                "the path lands on the surface {:.2} mm long: too short to cut (a path drawn \
                 across the surface, not into it)",
                projected_length * 1e3
            ),
        ));
    }
    // Where two samples land on one point (a fold), the path's direction is the written
    // one's, square to the normal; failing that, any direction square to it.
    let written_along = written[written.len() - 1] - written[0];
    let square_to = |out: &Vec3, v: Vec3| (v - out * v.dot(out)).try_normalize(1e-12);
    let mut samples = Vec::with_capacity(projected.len());
    let mut s_m = 0.0;
    for k in 0..projected.len() {
        if k > 0 {
            s_m += (projected[k].0 - projected[k - 1].0).norm();
        }
        let (lo, hi) = (
            k.saturating_sub(NORMAL_SMOOTHING),
            (k + NORMAL_SMOOTHING).min(projected.len() - 1),
        );
        let out = projected[lo..=hi]
            .iter()
            .map(|p| p.1)
            .sum::<Vec3>()
            .try_normalize(1e-12)
            .unwrap_or(projected[k].1);
        let (a, b) = (
            projected[k.saturating_sub(1)].0,
            projected[(k + 1).min(projected.len() - 1)].0,
        );
        let along = b - a;
        let tangent = square_to(&out, along)
            .or_else(|| square_to(&out, written_along))
            .or_else(|| square_to(&out, Vec3::x()))
            .unwrap_or_else(Vec3::y);
        let (at, _, triangle) = projected[k];
        samples.push(PlanSample {
            at,
            out,
            tangent,
            s_m,
            triangle: triangle as u32,
            bary: barycentric(&at, &surface.corners(triangle)),
        });
    }
    Ok(PlannedIncision {
        name: inc.name.clone(),
        samples,
        length_m: s_m,
        depth_m: inc.depth_m,
        depth_tolerance_m: inc.depth_tolerance_m,
        deviation_m: inc.deviation_m,
    })
}

/// Points every [`SAMPLE_M`] or so along the polyline `points` of length `length`, with
/// their arc length.
fn resample(points: &[Vec3], length: f64) -> Vec<(f64, Vec3)> {
    let n = ((length / SAMPLE_M).ceil() as usize).max(1);
    let mut out = Vec::with_capacity(n + 1);
    let (mut seg, mut seg_start) = (0, 0.0);
    for k in 0..=n {
        let s = length * k as f64 / n as f64;
        while seg + 2 < points.len() && seg_start + (points[seg + 1] - points[seg]).norm() < s {
            seg_start += (points[seg + 1] - points[seg]).norm();
            seg += 1;
        }
        let (a, b) = (points[seg], points[seg + 1]);
        let len = (b - a).norm();
        let t = if len > 0.0 {
            ((s - seg_start) / len).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push((s, a + (b - a) * t));
    }
    out
}

/// Barycentric coordinates of `p` (in the triangle's plane) in `[a, b, c]`.
fn barycentric(p: &Vec3, [a, b, c]: &[Vec3; 3]) -> [f64; 3] {
    let (v0, v1, v2) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (v0.dot(&v0), v0.dot(&v1), v1.dot(&v1));
    let (d20, d21) = (v2.dot(&v0), v2.dot(&v1));
    let denom = d00 * d11 - d01 * d01;
    if denom.abs() < 1e-300 {
        return [1.0, 0.0, 0.0];
    }
    let v = (d11 * d20 - d01 * d21) / denom;
    let w = (d00 * d21 - d01 * d20) / denom;
    [1.0 - v - w, v, w]
}

/// The surface point nearest `p`, its triangle's outward unit normal, and the triangle.
fn nearest_on_surface(surface: &TriMesh, p: &Vec3) -> (Vec3, Vec3, usize) {
    let mut best = (f64::INFINITY, *p, Vec3::z(), 0);
    for t in 0..surface.triangles.len() {
        let corners = surface.corners(t);
        // A triangle whose box is farther than the best so far cannot hold a nearer point.
        let far = (0..3).any(|a| {
            let lo = corners.iter().map(|c| c[a]).fold(f64::INFINITY, f64::min);
            let hi = corners
                .iter()
                .map(|c| c[a])
                .fold(f64::NEG_INFINITY, f64::max);
            p[a] < lo - best.0 || p[a] > hi + best.0
        });
        if far {
            continue;
        }
        let q = closest_point_on_triangle(p, &corners);
        let d = (q - p).norm();
        if d < best.0 {
            let normal = surface
                .doubled_area_normal(t)
                .try_normalize(1e-30)
                .unwrap_or(Vec3::z());
            best = (d, q, normal, t);
        }
    }
    (best.1, best.2, best.3)
}
