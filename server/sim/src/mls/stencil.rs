//! The uncut lattice as a dense box of sites, for the force kernel's fixed-stencil path.
//!
//! On the lattice with h = 2s, every full-rank point's row is, until a cut edits it, the
//! lattice points present among its 26 stencil neighbours, and a pair's `w x` and `w` depend
//! only on the offset's class: face, edge or corner. Laid out as a box of sites (x fastest)
//! with an empty layer around the body, a row's sums become sums over a 3×3×3 block of
//! sites with three shared coefficients: no per-pair data is read, a neighbour that is not
//! there is an empty site holding zero, and the boundary layer goes through the same code
//! as the interior. The evaluation itself is in `stencil_kernel`.
//!
//! Four consecutive sites of a box row form a *quad*, the kernel's SIMD lanes; the quads
//! cover every site holding a point. A point whose row stops being the stencil (a cut, a
//! transparent pair, a virtual point joining it) is *demoted*: its lane's terms become zero
//! and the single-point kernel takes its stress; the quad still gathers the forces its
//! stencil neighbours put on it.

use wide::f64x4;

use crate::math::Vec3;
use crate::mls::operator::{LANES, LatticeOffsets, MlsOperator, PointRank};
use crate::model::Kernel;

/// No point (an empty site), or no site (a point off the lattice).
pub(crate) const NONE: u32 = u32::MAX;

/// Per-lane terms of one quad (lane = consecutive site in x).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct QuadTerms {
    /// A⁻¹ of each lane, entry (r, c) at `3r + c`; zero for a lane the stencil does not
    /// evaluate.
    pub a_inv: [f64x4; 9],
    /// Σ_j w_ij x_ij (m).
    pub sum_wx: [f64x4; 3],
    /// Σ_j w_ij.
    pub sum_w: f64x4,
    /// 1 / tr A (m⁻²), for the hourglass stiffness; zero for a lane not evaluated.
    pub inv_trace_a: f64x4,
    /// The point at each site, or [`NONE`].
    pub point: [u32; LANES],
    /// Whether the stencil evaluates the lane's stress.
    pub evaluated: [bool; LANES],
}

/// `v` with lane `lane` set to `x`.
fn with_lane(v: f64x4, lane: usize, x: f64) -> f64x4 {
    let mut a = v.to_array();
    a[lane] = x;
    f64x4::from(a)
}

/// The lattice's sites, quads and the per-lane terms of the points the stencil evaluates.
#[derive(Debug, Clone, PartialEq)]
pub struct LatticeStencil {
    /// Sites along x, y, z (x fastest).
    dims: [usize; 3],
    /// Per lattice point: its site.
    site_of: Vec<u32>,
    /// Per lattice point: its rest position (the kernel works on displacements).
    rest: Vec<Vec3>,
    /// First site of each quad, ascending.
    quads: Vec<u32>,
    /// Runs of quads along one box row: (first quad, count).
    spans: Vec<(u32, u32)>,
    terms: Vec<QuadTerms>,
    /// Per lattice point: `quad · LANES + lane`.
    lane_of: Vec<u32>,
    /// Per point of the operator (virtual nodes included): stress evaluated by the stencil.
    evaluated: Vec<bool>,
    evaluated_count: usize,
    /// w of a face, edge and corner neighbour.
    weight: [f64; 3],
    /// s·w of a face, edge and corner neighbour: the non-zero components of `w x`.
    weighted_offset: [f64; 3],
}

impl LatticeStencil {
    /// The stencil of `op`'s lattice points, or `None` when the support does not give the
    /// 26-point stencil (h/s outside (√3, 2]) or no point qualifies.
    pub(crate) fn build(
        op: &MlsOperator,
        rest: &[Vec3],
        lattice: &LatticeOffsets,
        kernel: &Kernel,
    ) -> Option<Self> {
        let s = lattice.spacing;
        let coords = &lattice.coords;
        let ratio = kernel.support_m / s;
        if coords.is_empty() || !(ratio > 3f64.sqrt() && ratio <= 2.0) {
            return None;
        }
        // The class values exactly as the operator computes them for a lattice offset.
        let class = |n: usize| {
            let x = Vec3::new(
                s,
                if n >= 2 { s } else { 0.0 },
                if n >= 3 { s } else { 0.0 },
            );
            let w = kernel.weight_sq(x.norm_squared());
            (w, s * w)
        };
        let (w1, cw1) = class(1);
        let (w2, cw2) = class(2);
        let (w3, cw3) = class(3);
        let lo = [0, 1, 2].map(|a| coords.iter().map(|c| c[a]).min().unwrap_or(0));
        let hi = [0, 1, 2].map(|a| coords.iter().map(|c| c[a]).max().unwrap_or(0));
        let extent = [0, 1, 2].map(|a| (hi[a] - lo[a]) as usize + 1);
        // An empty layer on every side, and in x room for the last quad of a row to run
        // over (3 sites) and for the kernel, which reads a span's rows in chunks of four
        // from x − 1 to two chunks past the last quad (7 more).
        let dims = [extent[0] + 2 + LANES + 6, extent[1] + 2, extent[2] + 2];
        let sites = dims[0].checked_mul(dims[1])?.checked_mul(dims[2])?;
        if sites >= NONE as usize {
            return None;
        }
        let site_at = |c: [u32; 3]| {
            (c[0] - lo[0] + 1) as usize
                + dims[0] * ((c[1] - lo[1] + 1) as usize + dims[1] * (c[2] - lo[2] + 1) as usize)
        };
        let mut occupant = vec![NONE; sites];
        let mut site_of = Vec::with_capacity(coords.len());
        for (i, &c) in coords.iter().enumerate() {
            let site = site_at(c);
            if occupant[site] != NONE {
                // Two points on one site: not a lattice this layout can hold.
                return None;
            }
            occupant[site] = i as u32;
            site_of.push(site as u32);
        }
        let (sy, sz) = (dims[0] as isize, (dims[0] * dims[1]) as isize);
        let stencil_sites = |site: usize| {
            (-1isize..=1).flat_map(move |dz| {
                (-1isize..=1).flat_map(move |dy| {
                    (-1isize..=1).map(move |dx| (site as isize + dx + dy * sy + dz * sz) as usize)
                })
            })
        };
        // A point qualifies when its row is exactly the points present in its stencil, with
        // the class values bit for bit.
        let qualifies = |i: usize| {
            if !matches!(op.point(i).rank, PointRank::Full) {
                return false;
            }
            let present = stencil_sites(site_of[i] as usize)
                .filter(|&t| occupant[t] != NONE && t != site_of[i] as usize)
                .count();
            let ids = op.neighbours(i);
            if ids.len() != present {
                return false;
            }
            ids.iter().zip(op.pair_terms(i)).all(|(&j, pair)| {
                let Some(cj) = coords.get(j as usize) else {
                    return false;
                };
                let o = [0, 1, 2].map(|a| cj[a] as i64 - coords[i][a] as i64);
                let n = o.iter().map(|d| d.unsigned_abs() as usize).sum::<usize>();
                if o.iter().any(|d| d.abs() > 1) || n == 0 {
                    return false;
                }
                let (w, _) = [class(1), class(2), class(3)][n - 1];
                pair.w.to_bits() == w.to_bits()
                    && (0..3).all(|a| {
                        let x = o[a] as f64 * s;
                        pair.wx[a].to_bits() == (x * w).to_bits()
                    })
            })
        };
        let mut evaluated = vec![false; op.len()];
        let mut evaluated_count = 0;
        for i in 0..coords.len() {
            if qualifies(i) {
                evaluated[i] = true;
                evaluated_count += 1;
            }
        }
        if evaluated_count == 0 {
            return None;
        }
        // Quads over each box row's span of points, in site order.
        let mut quads = Vec::new();
        let mut spans = Vec::new();
        let mut terms = Vec::new();
        let mut lane_of = vec![NONE; coords.len()];
        for z in 1..dims[2] - 1 {
            for y in 1..dims[1] - 1 {
                let row = dims[0] * (y + dims[1] * z);
                let occupied = |x: usize| occupant[row + x] != NONE;
                let Some(first) = (0..dims[0]).find(|&x| occupied(x)) else {
                    continue;
                };
                let last = (0..dims[0]).rev().find(|&x| occupied(x)).unwrap_or(first);
                spans.push((
                    quads.len() as u32,
                    (last - first + LANES) as u32 / LANES as u32,
                ));
                let mut x = first;
                while x <= last {
                    let mut quad = QuadTerms::default();
                    for lane in 0..LANES {
                        let i = occupant[row + x + lane];
                        quad.point[lane] = i;
                        if i == NONE {
                            continue;
                        }
                        lane_of[i as usize] = (quads.len() * LANES + lane) as u32;
                        if evaluated[i as usize] {
                            let t = op.point(i as usize);
                            let q = &mut quad;
                            for r in 0..3 {
                                for c in 0..3 {
                                    q.a_inv[3 * r + c] =
                                        with_lane(q.a_inv[3 * r + c], lane, t.a_pinv[(r, c)]);
                                }
                                q.sum_wx[r] = with_lane(q.sum_wx[r], lane, t.sum_wx[r]);
                            }
                            q.sum_w = with_lane(q.sum_w, lane, t.sum_w);
                            q.inv_trace_a = with_lane(q.inv_trace_a, lane, 1.0 / t.trace_a);
                            q.evaluated[lane] = true;
                        }
                    }
                    quads.push((row + x) as u32);
                    terms.push(quad);
                    x += LANES;
                }
            }
        }
        Some(Self {
            dims,
            site_of,
            rest: rest[..coords.len()].to_vec(),
            quads,
            spans,
            terms,
            lane_of,
            evaluated,
            evaluated_count,
            weight: [w1, w2, w3],
            weighted_offset: [cw1, cw2, cw3],
        })
    }

    /// Point i's stress is no longer the stencil's (its row changed): its lane's terms
    /// become zero, so the stencil neither evaluates it nor pushes with it.
    pub(crate) fn demote(&mut self, i: usize) {
        if !self.evaluated.get(i).copied().unwrap_or(false) {
            return;
        }
        self.evaluated[i] = false;
        self.evaluated_count -= 1;
        let at = self.lane_of[i] as usize;
        let (quad, lane) = (at / LANES, at % LANES);
        let t = &mut self.terms[quad];
        t.a_inv
            .iter_mut()
            .for_each(|v| *v = with_lane(*v, lane, 0.0));
        t.sum_wx
            .iter_mut()
            .for_each(|v| *v = with_lane(*v, lane, 0.0));
        t.sum_w = with_lane(t.sum_w, lane, 0.0);
        t.inv_trace_a = with_lane(t.inv_trace_a, lane, 0.0);
        t.evaluated[lane] = false;
    }

    /// Per point: evaluated by the stencil.
    pub(crate) fn evaluated(&self) -> &[bool] {
        &self.evaluated
    }

    /// How many points the stencil evaluates.
    pub fn evaluated_count(&self) -> usize {
        self.evaluated_count
    }

    /// Sites in the box.
    pub(crate) fn sites(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Site steps in y and z.
    pub(crate) fn strides(&self) -> (usize, usize) {
        (self.dims[0], self.dims[0] * self.dims[1])
    }

    /// Sites of the lattice points.
    pub(crate) fn site_of(&self) -> &[u32] {
        &self.site_of
    }

    /// Rest positions of the lattice points.
    pub(crate) fn rest(&self) -> &[Vec3] {
        &self.rest
    }

    /// First sites of the quads and their terms.
    pub(crate) fn quads(&self) -> (&[u32], &[QuadTerms]) {
        (&self.quads, &self.terms)
    }

    /// The quads as runs along box rows: (first quad, count), in quad order.
    pub(crate) fn spans(&self) -> &[(u32, u32)] {
        &self.spans
    }

    /// w and s·w of a face, edge and corner neighbour.
    pub(crate) fn coefficients(&self) -> ([f64; 3], [f64; 3]) {
        (self.weight, self.weighted_offset)
    }
}

#[cfg(test)]
mod tests {
    use crate::progress::Silent;
    use crate::scene::{Material, build_scene, builtin};
    use crate::solver::{Solver, SolverConfig};

    /// On the built organs every full-rank point is the stencil's, and the quads add few
    /// empty lanes.
    #[test]
    fn the_stencil_takes_every_full_rank_point_of_the_built_organs() {
        for name in ["liver", "cerebroma", "block"] {
            let model = build_scene(&builtin(name).expect("built-in"), None, &mut Silent)
                .expect("builds")
                .model;
            let solver = Solver::for_model(&model, &Material::LIVER, SolverConfig::default());
            let op = solver.operator();
            let stencil = op.stencil().expect("a lattice with h = 2s has a stencil");
            assert_eq!(stencil.evaluated_count(), op.rank_counts().full, "{name}");
            let (quads, _) = stencil.quads();
            let lanes = quads.len() * super::LANES;
            assert!(
                lanes as f64 <= 1.15 * op.len() as f64,
                "{name}: {lanes} lanes for {} points",
                op.len()
            );
        }
    }
}
