//! Geometry in the plane of an incision's chart: the local frame, distances, polygons, the
//! path as an arc-length polyline and its smoothing.

use spade::{ConstrainedDelaunayTriangulation, HasPosition, Point2};

use crate::math::Vec3;

/// A 2D vertex of the triangulation (spade needs `From<Point2>` to add Steiner points).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct V2(pub(super) Point2<f64>);

impl HasPosition for V2 {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.0
    }
}

impl From<Point2<f64>> for V2 {
    fn from(p: Point2<f64>) -> Self {
        V2(p)
    }
}

pub(super) type Cdt = ConstrainedDelaunayTriangulation<V2>;

/// The local frame of an incision: origin A, e1 along the chord, e2 across, n̄ up.
#[derive(Debug, Clone, Copy)]
pub(super) struct Frame {
    pub(super) origin: Vec3,
    pub(super) e1: Vec3,
    pub(super) e2: Vec3,
}

impl Frame {
    pub(super) fn project(&self, x: &Vec3) -> [f64; 2] {
        let d = x - self.origin;
        [d.dot(&self.e1), d.dot(&self.e2)]
    }
}

pub(super) fn sub2(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

pub(super) fn cross2(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

/// Where on the segment a–b the point p is nearest (t in [0, 1]) and its squared distance.
pub(super) fn nearest_on_segment_2d(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> (f64, f64) {
    let ab = sub2(b, a);
    let ap = sub2(p, a);
    let len2 = ab[0] * ab[0] + ab[1] * ab[1];
    let t = if len2 > 0.0 {
        ((ap[0] * ab[0] + ap[1] * ab[1]) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let d = [ap[0] - t * ab[0], ap[1] - t * ab[1]];
    (t, d[0] * d[0] + d[1] * d[1])
}

pub(super) fn dist_sq_point_segment_2d(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    nearest_on_segment_2d(p, a, b).1
}

/// Barycentric coordinates of p in the 2D triangle.
pub(super) fn barycentric_2d(tri: &[[f64; 2]; 3], p: [f64; 2]) -> Option<[f64; 3]> {
    let d = cross2(sub2(tri[1], tri[0]), sub2(tri[2], tri[0]));
    if d.abs() < 1e-300 {
        return None;
    }
    let u = cross2(sub2(tri[1], p), sub2(tri[2], p)) / d;
    let v = cross2(sub2(tri[2], p), sub2(tri[0], p)) / d;
    Some([u, v, 1.0 - u - v])
}

/// Squared 2D distance from p to a triangle (0 inside).
pub(super) fn dist_sq_point_triangle_2d(tri: &[[f64; 2]; 3], p: [f64; 2]) -> f64 {
    if let Some(b) = barycentric_2d(tri, p)
        && b.iter().all(|&x| x >= 0.0)
    {
        return 0.0;
    }
    (0..3)
        .map(|k| dist_sq_point_segment_2d(p, tri[k], tri[(k + 1) % 3]))
        .fold(f64::INFINITY, f64::min)
}

pub(super) fn segments_intersect_2d(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let d1 = cross2(sub2(b, a), sub2(c, a));
    let d2 = cross2(sub2(b, a), sub2(d, a));
    let d3 = cross2(sub2(d, c), sub2(a, c));
    let d4 = cross2(sub2(d, c), sub2(b, c));
    (d1 > 0.0) != (d2 > 0.0) && (d3 > 0.0) != (d4 > 0.0)
}

/// Squared 2D distance between a segment and a triangle.
pub(super) fn dist_sq_segment_triangle_2d(tri: &[[f64; 2]; 3], a: [f64; 2], b: [f64; 2]) -> f64 {
    if (0..3).any(|k| segments_intersect_2d(a, b, tri[k], tri[(k + 1) % 3])) {
        return 0.0;
    }
    let mut d = dist_sq_point_triangle_2d(tri, a).min(dist_sq_point_triangle_2d(tri, b));
    for k in 0..3 {
        d = d.min(dist_sq_point_segment_2d(tri[k], a, b));
    }
    d
}

pub(super) fn point_in_polygon(poly: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut inside = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + 1) % n]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
    }
    inside
}

/// A polyline parametrised by arc length.
pub(super) struct ArcPolyline {
    pub(super) points: Vec<[f64; 2]>,
    pub(super) arc: Vec<f64>,
}

impl ArcPolyline {
    pub(super) fn new(points: Vec<[f64; 2]>) -> Self {
        let mut arc = vec![0.0];
        for w in points.windows(2) {
            let d = sub2(w[1], w[0]);
            arc.push(arc.last().copied().unwrap_or(0.0) + d[0].hypot(d[1]));
        }
        Self { points, arc }
    }

    pub(super) fn length(&self) -> f64 {
        self.arc.last().copied().unwrap_or(0.0)
    }

    /// Segment index and fraction at arc length u.
    pub(super) fn locate(&self, u: f64) -> (usize, f64) {
        let u = u.clamp(0.0, self.length());
        let i = self
            .arc
            .partition_point(|&a| a <= u)
            .clamp(1, self.arc.len() - 1)
            - 1;
        let seg = self.arc[i + 1] - self.arc[i];
        let f = if seg > 0.0 {
            (u - self.arc[i]) / seg
        } else {
            0.0
        };
        (i, f)
    }

    pub(super) fn at(&self, u: f64) -> [f64; 2] {
        let (i, f) = self.locate(u);
        let (a, b) = (self.points[i], self.points[i + 1]);
        [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])]
    }

    /// The polyline averaged over ±`half` of arc length at each of its points (over less
    /// near its ends, so that it keeps them): a jog shorter than that is smoothed out.
    pub(super) fn averaged(&self, half: f64) -> Self {
        let length = self.length();
        // (Nine samples across the window: the points are a quarter edge apart or closer.)
        let points = self
            .arc
            .iter()
            .map(|&u| {
                let h = half.min(u).min(length - u).max(0.0);
                let mut sum = [0.0, 0.0];
                for k in 0..=8 {
                    let p = self.at(u - h + 2.0 * h * k as f64 / 8.0);
                    sum = [sum[0] + p[0], sum[1] + p[1]];
                }
                [sum[0] / 9.0, sum[1] / 9.0]
            })
            .collect();
        Self::new(points)
    }

    /// Largest turn per unit length over any stretch `window` long (1/m): the curvature a
    /// lip step of that length must follow, not a single kink's (a sample knocked aside
    /// by the hand's noise turns the path sharply over a short stretch only).
    pub(super) fn max_turn_rate(&self, window: f64) -> f64 {
        let n = self.points.len();
        let turns: Vec<f64> = (0..n)
            .map(|i| {
                if i == 0 || i + 1 == n {
                    return 0.0;
                }
                let (d0, d1) = (
                    sub2(self.points[i], self.points[i - 1]),
                    sub2(self.points[i + 1], self.points[i]),
                );
                cross2(d0, d1).atan2(d0[0] * d1[0] + d0[1] * d1[1]).abs()
            })
            .collect();
        let mut best: f64 = 0.0;
        let mut start = 0;
        let mut sum = 0.0;
        // Turns at the vertices within a window ending at vertex i.
        for i in 0..n {
            sum += turns[i];
            while self.arc[i] - self.arc[start] > window {
                sum -= turns[start];
                start += 1;
            }
            best = best.max(sum);
        }
        best / window.max(1e-300)
    }

    /// Unit tangent at u, smoothed over ±δ.
    pub(super) fn tangent(&self, u: f64, delta: f64) -> [f64; 2] {
        let a = self.at((u - delta).max(0.0));
        let b = self.at((u + delta).min(self.length()));
        let d = sub2(b, a);
        let n = d[0].hypot(d[1]);
        if n > 0.0 {
            [d[0] / n, d[1] / n]
        } else {
            [1.0, 0.0]
        }
    }
}

/// The path through its samples as a smooth curve, and the blade's track (tip − entry)
/// along it: quadratic Bézier pieces from the middle of one segment to the middle of the
/// next with the sample between as control point (a uniform quadratic B-spline, extended
/// by straight half segments to the first and last sample), four chords a piece. Sampled
/// every quarter edge, a curved stroke would otherwise turn by whole sample angles at the
/// samples, and the lips with it; a straight one stays as it is.
pub(super) fn smooth_path(points: &[[f64; 2]], tracks: &[Vec3]) -> (Vec<[f64; 2]>, Vec<Vec3>) {
    let n = points.len();
    if n < 3 {
        return (points.to_vec(), tracks.to_vec());
    }
    let mid = |i: usize| {
        (
            [
                0.5 * (points[i][0] + points[i + 1][0]),
                0.5 * (points[i][1] + points[i + 1][1]),
            ],
            (tracks[i] + tracks[i + 1]) * 0.5,
        )
    };
    let mut out_points = vec![points[0]];
    let mut out_tracks = vec![tracks[0]];
    for i in 1..n - 1 {
        let ((a, ta), (c, tc)) = (mid(i - 1), mid(i));
        let (b, tb) = (points[i], tracks[i]);
        for k in 0..4 {
            let t = k as f64 / 4.0;
            let (wa, wb, wc) = ((1.0 - t) * (1.0 - t), 2.0 * t * (1.0 - t), t * t);
            out_points.push([
                wa * a[0] + wb * b[0] + wc * c[0],
                wa * a[1] + wb * b[1] + wc * c[1],
            ]);
            out_tracks.push(ta * wa + tb * wb + tc * wc);
        }
    }
    let (last_mid, last_track) = mid(n - 2);
    out_points.push(last_mid);
    out_tracks.push(last_track);
    out_points.push(points[n - 1]);
    out_tracks.push(tracks[n - 1]);
    (out_points, out_tracks)
}
