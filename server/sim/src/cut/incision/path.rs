//! The blade's path as an incision reads it: the samples without repeats, its length, and
//! the cut below each sample.

use crate::geometry::TriMesh;
use crate::math::Vec3;

use super::types::IncisionError;
use crate::cut::blade::PathSample;

/// The path of one incision.
pub(super) struct IncisionPath {
    /// The samples without repeats.
    pub samples: Vec<PathSample>,
    /// The cut below each sample, square to the path ([`tracks_across`]).
    pub across: Vec<Vec3>,
    /// The deepest of them (m).
    pub depth_max: f64,
    /// The path's length on the surface (m).
    pub length: f64,
    /// The mesh's mean edge (m).
    pub global_edge: f64,
}

impl IncisionPath {
    /// `path` on `mesh`; too short when it has fewer than two distinct samples.
    pub fn new(mesh: &TriMesh, path: &[PathSample]) -> Result<Self, IncisionError> {
        let mut samples: Vec<PathSample> = Vec::with_capacity(path.len());
        for s in path {
            if samples
                .last()
                .is_none_or(|l: &PathSample| (l.surface - s.surface).norm() > 1e-9)
            {
                samples.push(*s);
            }
        }
        let global_edge = mesh.mean_edge_length();
        let length: f64 = samples
            .windows(2)
            .map(|w| (w[1].surface - w[0].surface).norm())
            .sum();
        if samples.len() < 2 {
            return Err(IncisionError::TooShort {
                length_mm: length * 1e3,
                min_mm: 0.5 * global_edge * 1e3,
            });
        }
        let across = tracks_across(&samples);
        let depth_max = across.iter().map(|t| t.norm()).fold(0.0, f64::max);
        Ok(Self {
            samples,
            across,
            depth_max,
            length,
            global_edge,
        })
    }

    /// Whether `x` is within `r` of the path.
    pub fn near(&self, x: &Vec3, r: f64) -> bool {
        self.samples.windows(2).any(|w| {
            crate::geometry::predicates::distance_sq_to_segment(x, &w[0].surface, &w[1].surface)
                < r * r
        })
    }
}

/// The blade's cut below each sample, square to the path: a vector from the surface point
/// down to the floor of the cut, in the cut surface. The cut surface Σ is ruled by the
/// blade's edge (entry → tip) at each sample, and its floor is the polyline through the
/// samples' `bottom`s (the tip's track; a stab's taper). The vector goes from the surface
/// point along the edge's part square to the path, to where it meets that floor (a part of
/// the floor running within 30° of the column never counts as met: a plunge); where it
/// meets none (beyond the floor's ends), it is the edge's part square to the path. A raked
/// blade's tip runs ahead of its entry point, so its edge in the tissue is longer than the
/// cut below the entry (√2× at 45°) and leans along the path; a blade tilted sideways cuts
/// a leaning wall, and the vector leans with it. (Where a raked blade went in, the cut
/// ramps down along its edge; the columns there, beyond the floor's start, are drawn as
/// deep as the edge's part square to the path. Taking the ramp as floor drew walls from
/// nothing to full depth over a few millimetres where an upright blade went into a
/// sloping top — the same ramp — and their cells were slivers, 11.7° in the randomized
/// stroke test.)
pub(crate) fn tracks_across(samples: &[PathSample]) -> Vec<Vec3> {
    let n = samples.len();
    (0..n)
        .map(|i| {
            let s = &samples[i];
            let track = s.bottom - s.surface;
            // The path's direction here: the central difference, or, where the path folds
            // back on itself (a sawing stroke's turn: the difference is short against the
            // steps), the step ahead (behind at the end).
            let (behind, ahead) = (
                s.surface - samples[i.saturating_sub(1)].surface,
                samples[(i + 1).min(n - 1)].surface - s.surface,
            );
            let central = behind + ahead;
            let chord = if central.norm() >= 0.5 * behind.norm().max(ahead.norm()) {
                central
            } else if i + 1 < n {
                ahead
            } else {
                behind
            };
            let square = match chord.try_normalize(1e-12) {
                Some(t) => track - t * track.dot(&t),
                None => track,
            };
            let Some(dir) = square.try_normalize(1e-12) else {
                return square;
            };
            // The floor segment the column passes closest to, if it passes within a fifth
            // of the edge's length in the tissue.
            let meets = samples
                .windows(2)
                .filter_map(|w| line_meets_segment(&s.surface, &dir, &w[0].bottom, &w[1].bottom))
                .filter(|&(depth, _)| depth > 0.0)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .filter(|&(_, gap)| gap <= 0.2 * track.norm());
            match meets {
                Some((depth, _)) => dir * depth.min(track.norm()),
                None => square,
            }
        })
        .collect()
}

/// Where the line `origin + s dir` (`dir` a unit vector) passes closest to the segment
/// a–b: s, and the distance between them there; `None` for a segment within 30° of the
/// line (or of no length), which it does not cross so much as run along.
fn line_meets_segment(origin: &Vec3, dir: &Vec3, a: &Vec3, b: &Vec3) -> Option<(f64, f64)> {
    let (e, w) = (b - a, origin - a);
    let (along, e_sq) = (dir.dot(&e), e.norm_squared());
    let denom = e_sq - along * along;
    // sin² of the angle between them, at least sin² 30°.
    if e_sq == 0.0 || denom < 0.25 * e_sq {
        return None;
    }
    let (d, f) = (dir.dot(&w), e.dot(&w));
    let r = ((f - d * along) / denom).clamp(0.0, 1.0);
    let s = r * along - d;
    Some((s, (w + dir * s - e * r).norm()))
}
