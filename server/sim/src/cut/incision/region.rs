//! Region R, the skin re-triangulated around the path: where the incision is made (the mean
//! normal n̄ near the path and the plane frame), the region's first extent, and how it grows
//! and falls back between tries (the [`Policy`]).

use std::collections::{HashMap, HashSet};

use crate::geometry::TriMesh;
use crate::math::Vec3;

use super::LIP_ROOM;
use super::path::IncisionPath;
use super::plane::{Frame, dist_sq_segment_triangle_2d, sub2};
use super::types::{IncisionError, IncisionParams};
use crate::cut::cells::FaceKind;

/// Where the incision is made.
pub(super) struct Site {
    /// The area-weighted normal near the path.
    pub n_bar: Vec3,
    /// The mean edge of the skin near the path (m).
    pub edge: f64,
    /// The plane ⊥ n̄: origin at the path's start, e1 along its chord.
    pub frame: Frame,
    /// The region's first extent: skin under and around the opening, and its one-ring.
    pub in_region: Vec<bool>,
    /// The skin triangle on the other side of each directed edge.
    pub edge_owner: HashMap<(u32, u32), usize>,
}

impl Site {
    /// Whether triangle `t` faces n̄ within `acos(min_cos)`.
    pub fn facing_at(&self, mesh: &TriMesh, t: usize, min_cos: f64) -> bool {
        mesh.doubled_area_normal(t)
            .try_normalize(1e-300)
            .is_some_and(|n| n.dot(&self.n_bar) > min_cos)
    }

    /// Whether triangle `t` faces n̄ well (within 53°): the region grows onto such faces
    /// wherever it must.
    pub fn facing_well(&self, mesh: &TriMesh, t: usize) -> bool {
        self.facing_at(mesh, t, 0.6)
    }
}

/// The deepest a path is opened for its length: deeper, its walls' cells are slivers.
const MAX_DEPTH_PER_LENGTH: f64 = 16.0;

/// Chooses where to cut `path` on `mesh`, and the region's first extent.
pub(super) fn choose_site(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    path: &IncisionPath,
    params: &IncisionParams,
) -> Result<Site, IncisionError> {
    let (samples, global_edge) = (&path.samples, path.global_edge);
    // Skin triangles near the path, their mean normal and edge length.
    let centroid = |t: usize| {
        let [a, b, c] = mesh.corners(t);
        (a + b + c) / 3.0
    };
    // Far enough for the region to give the widest opening the path may have its room
    // (below: the lips stay within 0.45 of the way to the region's boundary); on a fine
    // mesh two and a half edges are not enough (the cerebroma's 2.1 mm edges held its
    // wounds to a 1.9 mm half-opening, where 0.3 × 9 mm deep wants 2.7).
    let widest = params.opening_for(path.length, path.depth_max);
    let reach = (2.5 * global_edge).max(widest / LIP_ROOM + 1.5 * global_edge);
    let candidates: Vec<usize> = (0..mesh.triangles.len())
        .filter(|&t| kinds[t] == FaceKind::Skin && path.near(&centroid(t), reach))
        .collect();
    let mut normal_sum = Vec3::zeros();
    let mut edge_sum = 0.0;
    let mut edge_count = 0;
    for &t in &candidates {
        if path.near(&centroid(t), global_edge) {
            normal_sum += mesh.doubled_area_normal(t);
            let [a, b, c] = mesh.corners(t);
            edge_sum += (b - a).norm() + (c - b).norm() + (a - c).norm();
            edge_count += 3;
        }
    }
    let n_bar = normal_sum
        .try_normalize(1e-300)
        .ok_or(IncisionError::NoRegion)?;
    let edge = if edge_count > 0 {
        edge_sum / edge_count as f64
    } else {
        global_edge
    };
    // A path much shorter than its depth waits until it is longer: its walls' columns, as
    // many as its lips' vertices, would stand a few hundredths of a millimetre apart beside
    // rows at least depth / 64 tall (a crack that had grown 0.12 mm under an 8.2 mm deep
    // blade drew 6.7° cells on the cerebroma).
    let shortest = (0.1 * edge).max(path.depth_max / MAX_DEPTH_PER_LENGTH);
    if path.length < shortest {
        return Err(IncisionError::TooShort {
            length_mm: path.length * 1e3,
            min_mm: shortest * 1e3,
        });
    }
    let a3 = samples[0].surface;
    let b3 = samples[samples.len() - 1].surface;
    let chord = b3 - a3;
    let e1 = (chord - n_bar * chord.dot(&n_bar))
        .try_normalize(1e-300)
        .unwrap_or_else(|| n_bar.cross(&Vec3::x()).normalize());
    let frame = Frame {
        origin: a3,
        e1,
        e2: n_bar.cross(&e1),
    };
    let mut site = Site {
        n_bar,
        edge,
        frame,
        in_region: Vec::new(),
        edge_owner: edge_owners(mesh, kinds),
    };
    site.in_region = first_extent(mesh, &site, path, params, &candidates)?;
    Ok(site)
}

/// Region R's first extent: skin facing n̄ within reach of the opening, plus its one-ring.
/// Triangles under the opening may be steep; the ring around them must face n̄ well, or
/// their angles would change a lot between the projection (where R is chosen, and
/// triangulated if it has no chart) and the surface.
fn first_extent(
    mesh: &TriMesh,
    site: &Site,
    path: &IncisionPath,
    params: &IncisionParams,
    candidates: &[usize],
) -> Result<Vec<bool>, IncisionError> {
    let (frame, edge) = (&site.frame, site.edge);
    // The path projected onto n̄'s plane, to choose R by (R is laid flat in a chart of its
    // own below, where the path is placed again).
    let path_projected: Vec<[f64; 2]> = path
        .samples
        .iter()
        .map(|s| frame.project(&s.surface))
        .collect();
    let projected_length: f64 = path_projected
        .windows(2)
        .map(|w| {
            let d = sub2(w[1], w[0]);
            d[0].hypot(d[1])
        })
        .sum();
    let w_wanted = params.opening_for(projected_length, path.depth_max);
    let facing = |t: usize| site.facing_at(mesh, t, 0.2);
    let facing_well = |t: usize| site.facing_well(mesh, t);
    let tri2 = |t: usize| mesh.triangles[t].map(|v| frame.project(&mesh.positions[v as usize]));
    // The core: the triangles under the opening (steep ones too), and those within the
    // room the lips need (0.45 of the way to the region's boundary, below) that face n̄
    // well — a steep face there (the end of the cerebroma, 72° to n̄) would only be
    // distorted by the projection (16.5° skin triangles when it was let in).
    let under = w_wanted + 0.1 * edge;
    let room_for_lips = w_wanted / LIP_ROOM - 0.5 * edge;
    let mut in_region = vec![false; mesh.triangles.len()];
    let mut core_vertices = HashSet::new();
    for &t in candidates {
        let reach = match (facing_well(t), facing(t)) {
            (true, _) => under.max(room_for_lips),
            (false, true) => under,
            (false, false) => continue,
        };
        let tri = tri2(t);
        let touches = path_projected
            .windows(2)
            .any(|w| dist_sq_segment_triangle_2d(&tri, w[0], w[1]) < reach * reach);
        if touches {
            in_region[t] = true;
            core_vertices.extend(mesh.triangles[t]);
        }
    }
    if core_vertices.is_empty() {
        return Err(IncisionError::NoRegion);
    }
    for &t in candidates {
        if !in_region[t]
            && facing_well(t)
            && mesh.triangles[t].iter().any(|v| core_vertices.contains(v))
        {
            in_region[t] = true;
        }
    }
    Ok(in_region)
}

/// The skin triangle on the other side of each directed edge.
fn edge_owners(mesh: &TriMesh, kinds: &[FaceKind]) -> HashMap<(u32, u32), usize> {
    let mut edge_owner: HashMap<(u32, u32), usize> = HashMap::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if kinds[t] == FaceKind::Skin {
            for k in 0..3 {
                edge_owner.insert((tri[k], tri[(k + 1) % 3]), t);
            }
        }
    }
    edge_owner
}

/// The region as it was before its first growth onto a face not facing n̄ well.
#[derive(Debug, Clone)]
pub(super) struct Saved {
    grown: Vec<bool>,
    attempt: usize,
    mended: usize,
}

/// How the region may grow, and where a failed try sends it back to.
///
/// R grows where the refinement had to split its boundary (the triangles beyond would be
/// split into slivers), and where it is not a disk (mended), and is triangulated again.
/// It may grow into triangles that do not face n̄ well (the rim of a thin part, 80–130° from
/// n̄ on the deltoid sheet): laid flat in its conformal chart they keep their angles. Where a
/// region grown so cannot be triangulated (no disk, no chart, the path outside it, ...), R
/// goes back to where it was before its first such growth and grows only into triangles
/// facing n̄ well from there. Where it still fails, R is made from the start as before
/// charts — grown only onto faces facing n̄ well, triangulated in the projection — so a
/// region that could be opened then still can (a spike 6 mm tall on a 2 mm mesh beside the
/// cut gave its partly grown region no chart, and its region facing n̄ well a hole in the
/// chart). Falling back to the last R that could be triangulated instead drew more wounds
/// on the deltoid scan, and more cells under 15° on every scan.
#[derive(Debug, Clone)]
pub(super) enum Policy {
    /// Onto any face, in a conformal chart; `saved` once it grew onto a steep one.
    Steep { saved: Option<Saved> },
    /// Onto faces facing n̄ well only, in a conformal chart (back from a steep growth).
    FacingWell,
    /// From the start again, onto faces facing n̄ well, projected onto n̄'s plane.
    Projected,
}

/// The region between tries.
pub(super) struct Region {
    /// The triangles in R.
    pub grown: Vec<bool>,
    /// Tries that triangulated R (its boundary split growths, at most eight).
    pub attempt: usize,
    /// Mends of R where it was not a disk (at most three).
    pub mended: usize,
    at_start: Vec<bool>,
    pub policy: Policy,
}

impl Region {
    /// The region as the site chose it.
    pub fn new(site: &Site) -> Self {
        Self {
            grown: site.in_region.clone(),
            attempt: 0,
            mended: 0,
            at_start: site.in_region.clone(),
            policy: Policy::Steep { saved: None },
        }
    }

    /// Whether R may grow onto faces that do not face n̄ well.
    pub fn steep_growth(&self) -> bool {
        matches!(self.policy, Policy::Steep { .. })
    }

    /// Whether R is laid flat in a conformal chart (or projected).
    pub fn charted(&self) -> bool {
        !matches!(self.policy, Policy::Projected)
    }

    /// Whether R has grown onto a steep face (a failure then goes back to before it).
    pub fn grew_steep(&self) -> bool {
        matches!(self.policy, Policy::Steep { saved: Some(_) })
    }

    /// R grows onto `joining`; the first growth onto a face not facing n̄ well saves R as it
    /// was.
    pub fn grow(&mut self, joining: &[usize], facing_well: impl Fn(usize) -> bool) {
        if let Policy::Steep {
            saved: saved @ None,
        } = &mut self.policy
            && joining.iter().any(|&t| !facing_well(t))
        {
            *saved = Some(Saved {
                grown: self.grown.clone(),
                attempt: self.attempt,
                mended: self.mended,
            });
        }
        for &t in joining {
            self.grown[t] = true;
        }
    }

    /// A try failed with `error`: R goes back by the policy, or the incision fails.
    pub fn fall_back(&mut self, error: IncisionError) -> Result<(), IncisionError> {
        match std::mem::replace(&mut self.policy, Policy::FacingWell) {
            Policy::Steep { saved: Some(s) } => {
                (self.grown, self.attempt, self.mended) = (s.grown, s.attempt, s.mended);
            }
            Policy::Steep { saved: None } | Policy::FacingWell => {
                (self.grown, self.attempt, self.mended) = (self.at_start.clone(), 0, 0);
                self.policy = Policy::Projected;
            }
            Policy::Projected => {
                self.policy = Policy::Projected;
                return Err(error);
            }
        }
        Ok(())
    }
}
