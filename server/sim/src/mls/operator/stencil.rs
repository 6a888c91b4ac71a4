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
//! The box is cut into *chunks* of four consecutive sites in x, the kernel's SIMD lanes;
//! box rows are a whole number of chunks, so a site's y and z neighbours are in the chunks
//! a fixed number of chunks away. The kernel walks *spans*: runs of consecutive chunks
//! holding the points (a box row's, joined with the next row's across short gaps). A point
//! whose row stops being the stencil (a cut, a transparent pair, a virtual point joining
//! it) is *demoted*: its lane's terms become zero and the single-point kernel takes its
//! stress; its chunk still gathers the forces its stencil neighbours put on it.

use wide::f64x4;

use crate::math::Vec3;
use crate::mls::operator::{LANES, LatticeOffsets, MlsOperator, PointRank};
use crate::model::Kernel;

/// No point (an empty site), or no site (a point off the lattice).
pub(crate) const NONE: u32 = u32::MAX;

/// Spans of two box rows are joined when at most this many chunks lie between them (the
/// kernel's work on the gap is less than a span's set-up).
pub(crate) const JOIN_GAP_CHUNKS: usize = 3;

/// Per-lane terms of one chunk (lane = consecutive site in x).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct ChunkTerms {
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
    /// Every lane's A⁻¹ is diagonal and its Σ w x zero (to rounding: a point with its
    /// whole 26-point row, or no stress): the kernel then skips those terms.
    pub diagonal: bool,
}

impl ChunkTerms {
    /// Whether the lanes' off-diagonal A⁻¹ and Σ w x are rounding against the diagonal
    /// and s Σ w: a full row's A is (2w₁ + 8w₂ + 8w₃) s² I and its Σ w x zero exactly, and
    /// the operator's sums reach that to the last digits (1e-12 leaves a margin of 10⁴).
    fn is_diagonal(&self, spacing: f64) -> bool {
        const ROUNDING: f64 = 1e-12;
        (0..LANES).all(|lane| {
            let a = |r: usize, c: usize| self.a_inv[3 * r + c].to_array()[lane];
            let scale = (0..3).map(|d| a(d, d).abs()).fold(0.0, f64::max);
            let off = (0..3)
                .flat_map(|r| (0..3).filter(move |&c| c != r).map(move |c| (r, c)))
                .all(|(r, c)| a(r, c).abs() <= ROUNDING * scale);
            let sum_w = self.sum_w.to_array()[lane].abs();
            let centred = self
                .sum_wx
                .iter()
                .all(|v| v.to_array()[lane].abs() <= ROUNDING * spacing * sum_w);
            off && centred
        })
    }

    /// Whether any site of the chunk holds a point.
    pub(crate) fn has_points(&self) -> bool {
        self.point.iter().any(|&i| i != NONE)
    }
}

/// `v` with lane `lane` set to `x`.
fn with_lane(v: f64x4, lane: usize, x: f64) -> f64x4 {
    let mut a = v.to_array();
    a[lane] = x;
    f64x4::from(a)
}

/// A run of consecutive chunks the kernel walks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Span {
    /// First chunk (box index).
    pub chunk: u32,
    /// Chunks in the span.
    pub len: u32,
    /// Index of its first chunk's terms (the spans' terms are stored one after another).
    pub terms: u32,
}

/// The lattice's box, its spans and the per-lane terms of the points the stencil evaluates.
#[derive(Debug, Clone, PartialEq)]
pub struct LatticeStencil {
    /// Sites along the box's x, y, z (x fastest; x a multiple of four).
    dims: [usize; 3],
    /// The lattice axis of each box axis (the longest first).
    axes: [usize; 3],
    /// Per lattice point: its site.
    site_of: Vec<u32>,
    /// Per lattice point: its rest position (the kernel works on displacements).
    rest: Vec<Vec3>,
    spans: Vec<Span>,
    /// Terms of every chunk of every span, in span order.
    terms: Vec<ChunkTerms>,
    /// Per lattice point: index of its chunk's terms · LANES + lane.
    lane_of: Vec<u32>,
    /// Per box chunk: index of its terms, or [`NONE`] outside the spans.
    terms_of_chunk: Vec<u32>,
    /// Per point of the operator (virtual nodes included): stress evaluated by the stencil.
    evaluated: Vec<bool>,
    evaluated_count: usize,
    /// w of a face, edge and corner neighbour.
    weight: [f64; 3],
    /// s·w of a face, edge and corner neighbour: the non-zero components of `w x`.
    weighted_offset: [f64; 3],
}

/// The lattice laid out as a box of sites: its dimensions, axes and occupants.
struct BoxLayout {
    dims: [usize; 3],
    axes: [usize; 3],
    /// The point at each site, or [`NONE`].
    occupant: Vec<u32>,
    /// Per lattice point: its site.
    site_of: Vec<u32>,
}

impl BoxLayout {
    /// The box of `coords`, or `None` when it is too big to index or two points share a
    /// site.
    fn of(coords: &[[u32; 3]]) -> Option<Self> {
        let low = [0, 1, 2].map(|a| coords.iter().map(|c| c[a]).min().unwrap_or(0));
        let high = [0, 1, 2].map(|a| coords.iter().map(|c| c[a]).max().unwrap_or(0));
        // The box's rows run along the body's longest axis: long rows make long spans (a
        // bent shoulder's rows across its width held two chunks for every three points).
        let mut axes = [0, 1, 2];
        axes.sort_by_key(|&a| std::cmp::Reverse(high[a] - low[a]));
        let lo = axes.map(|a| low[a]);
        let extent = axes.map(|a| (high[a] - low[a]) as usize + 1);
        // An empty site on every side (in x, the row's first and last), rows a whole
        // number of chunks, and an empty layer of two rows below and above in y and z so
        // that the kernel's reads one chunk before and after a span stay in the box.
        let dims = [
            (extent[0] + 2).div_ceil(LANES) * LANES,
            extent[1] + 4,
            extent[2] + 4,
        ];
        let sites = dims[0].checked_mul(dims[1])?.checked_mul(dims[2])?;
        if sites >= NONE as usize {
            return None;
        }
        let site_at = |c: [u32; 3]| {
            let c = axes.map(|a| c[a]);
            (c[0] - lo[0] + 1) as usize
                + dims[0] * ((c[1] - lo[1] + 2) as usize + dims[1] * (c[2] - lo[2] + 2) as usize)
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
        Some(BoxLayout {
            dims,
            axes,
            occupant,
            site_of,
        })
    }

    /// The 27 sites of `site`'s stencil, itself included.
    fn stencil_sites(&self, site: usize) -> impl Iterator<Item = usize> {
        let (sy, sz) = (
            self.dims[0] as isize,
            (self.dims[0] * self.dims[1]) as isize,
        );
        (-1isize..=1).flat_map(move |dz| {
            (-1isize..=1).flat_map(move |dy| {
                (-1isize..=1).map(move |dx| (site as isize + dx + dy * sy + dz * sz) as usize)
            })
        })
    }

    /// Whether point `i`'s row is exactly the points present in its stencil, with the
    /// class values (w, s·w of a face, edge and corner neighbour) bit for bit.
    fn qualifies(
        &self,
        op: &MlsOperator,
        coords: &[[u32; 3]],
        i: usize,
        s: f64,
        classes: &[(f64, f64); 3],
    ) -> bool {
        if !matches!(op.point(i).rank, PointRank::Full) {
            return false;
        }
        let own = self.site_of[i] as usize;
        let present = self
            .stencil_sites(own)
            .filter(|&t| self.occupant[t] != NONE && t != own)
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
            let (w, _) = classes[n - 1];
            pair.w.to_bits() == w.to_bits()
                && (0..3).all(|a| {
                    let x = o[a] as f64 * s;
                    pair.wx[a].to_bits() == (x * w).to_bits()
                })
        })
    }

    /// The chunks holding points, in box order, as spans joined across short gaps (their
    /// `terms` not yet set).
    fn spans(&self) -> Vec<Span> {
        let occupied = |chunk: usize| {
            self.occupant[LANES * chunk..LANES * (chunk + 1)]
                .iter()
                .any(|&i| i != NONE)
        };
        let mut spans: Vec<Span> = Vec::new();
        for chunk in 0..self.occupant.len() / LANES {
            if !occupied(chunk) {
                continue;
            }
            match spans.last_mut() {
                Some(last) if chunk - (last.chunk + last.len) as usize <= JOIN_GAP_CHUNKS => {
                    last.len = (chunk + 1) as u32 - last.chunk;
                }
                _ => spans.push(Span {
                    chunk: chunk as u32,
                    len: 1,
                    terms: 0,
                }),
            }
        }
        spans
    }
}

impl ChunkTerms {
    /// The terms of the chunk whose lanes hold `points` ([`NONE`] for an empty site): the
    /// operator's sums for the lanes the stencil evaluates, zero for the others.
    fn of(op: &MlsOperator, points: &[u32], evaluated: &[bool], spacing: f64) -> Self {
        let mut t = ChunkTerms::default();
        for (lane, &i) in points.iter().enumerate() {
            t.point[lane] = i;
            if i == NONE || !evaluated[i as usize] {
                continue;
            }
            let p = op.point(i as usize);
            for r in 0..3 {
                for c in 0..3 {
                    t.a_inv[3 * r + c] = with_lane(t.a_inv[3 * r + c], lane, p.a_pinv[(r, c)]);
                }
                t.sum_wx[r] = with_lane(t.sum_wx[r], lane, p.sum_wx[r]);
            }
            t.sum_w = with_lane(t.sum_w, lane, p.sum_w);
            t.inv_trace_a = with_lane(t.inv_trace_a, lane, 1.0 / p.trace_a);
            t.evaluated[lane] = true;
        }
        t.diagonal = t.is_diagonal(spacing);
        t
    }
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
        let classes = [class(1), class(2), class(3)];
        let layout = BoxLayout::of(coords)?;
        let mut evaluated = vec![false; op.len()];
        let mut evaluated_count = 0;
        for i in 0..coords.len() {
            if layout.qualifies(op, coords, i, s, &classes) {
                evaluated[i] = true;
                evaluated_count += 1;
            }
        }
        if evaluated_count == 0 {
            return None;
        }
        let mut spans = layout.spans();
        let sites = layout.occupant.len();
        let mut terms = Vec::new();
        let mut lane_of = vec![NONE; coords.len()];
        let mut terms_of_chunk = vec![NONE; sites / LANES];
        for span in &mut spans {
            span.terms = terms.len() as u32;
            for chunk in span.chunk as usize..(span.chunk + span.len) as usize {
                terms_of_chunk[chunk] = terms.len() as u32;
                let points = &layout.occupant[LANES * chunk..LANES * (chunk + 1)];
                for (lane, &i) in points.iter().enumerate() {
                    if i != NONE {
                        lane_of[i as usize] = (terms.len() * LANES + lane) as u32;
                    }
                }
                terms.push(ChunkTerms::of(op, points, &evaluated, s));
            }
        }
        let [(w1, cw1), (w2, cw2), (w3, cw3)] = classes;
        Some(Self {
            dims: layout.dims,
            axes: layout.axes,
            site_of: layout.site_of,
            rest: rest[..coords.len()].to_vec(),
            spans,
            terms,
            lane_of,
            terms_of_chunk,
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
        let (chunk, lane) = (at / LANES, at % LANES);
        let t = &mut self.terms[chunk];
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

    /// Chunks in the box.
    pub(crate) fn chunks(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2] / LANES
    }

    /// Chunk steps in y and z.
    pub(crate) fn chunk_strides(&self) -> (usize, usize) {
        (self.dims[0] / LANES, self.dims[0] * self.dims[1] / LANES)
    }

    /// Sites of the lattice points.
    pub(crate) fn site_of(&self) -> &[u32] {
        &self.site_of
    }

    /// Rest positions of the lattice points.
    pub(crate) fn rest(&self) -> &[Vec3] {
        &self.rest
    }

    /// The spans, in box order.
    pub(crate) fn spans(&self) -> &[Span] {
        &self.spans
    }

    /// Index of the terms of a chunk holding points.
    pub(crate) fn terms_of_chunk(&self, chunk: usize) -> u32 {
        self.terms_of_chunk[chunk]
    }

    /// The chunks' terms, span after span.
    pub(crate) fn terms(&self) -> &[ChunkTerms] {
        &self.terms
    }

    /// The longest span (chunks).
    pub(crate) fn longest_span(&self) -> usize {
        self.spans.iter().map(|s| s.len as usize).max().unwrap_or(0)
    }

    /// The lattice axis of each box axis.
    pub(crate) fn axes(&self) -> [usize; 3] {
        self.axes
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

    /// On the built organs every full-rank point is the stencil's, and the spans' chunks
    /// add few empty lanes.
    #[test]
    fn the_stencil_takes_every_full_rank_point_of_the_built_organs() {
        for name in ["liver", "shoulder", "cerebroma", "block"] {
            let model = build_scene(&builtin(name).expect("built-in"), None, &mut Silent)
                .expect("builds")
                .model;
            let solver = Solver::for_model(&model, &Material::LIVER, SolverConfig::default());
            let op = solver.operator();
            let stencil = op.stencil().expect("a lattice with h = 2s has a stencil");
            assert_eq!(stencil.evaluated_count(), op.rank_counts().full, "{name}");
            let lanes = stencil.terms().len() * super::LANES;
            assert!(
                lanes as f64 <= 2.0 * op.len() as f64,
                "{name}: {lanes} lanes for {} points",
                op.len()
            );
            // The interior takes the diagonal path: every chunk whose lanes all hold points
            // with a whole row (seen: liver 122 of 450 chunks with points, shoulder 273 of
            // 1624, cerebroma 975 of 2036, block 81 of 363).
            let whole_row = |i: u32| i != super::NONE && op.neighbours(i as usize).len() == 26;
            let terms = stencil.terms();
            for t in terms {
                if t.point.iter().all(|&i| whole_row(i)) {
                    assert!(t.diagonal, "{name}: {t:?}");
                }
            }
            let with_points = terms.iter().filter(|t| t.has_points()).count();
            let diagonal = terms
                .iter()
                .filter(|t| t.has_points() && t.diagonal)
                .count();
            assert!(diagonal > 0, "{name}: no diagonal chunk of {with_points}");
        }
    }
}
