//! The MLS gradient operator, precomputed in rest space (physics.md §1.4, §3).
//!
//! For point i with neighbours j: `A_i = Σ_j w_ij x_ij x_ijᵀ`, `d_ij = A_i⁺ w_ij x_ij`, and
//! `F_i = Σ_j (p_j − p_i) d_ijᵀ = (Σ_j (p_j − p_i) ⊗ w_ij x_ij) A_i⁺` (A is symmetric). So a
//! pair needs only `w_ij x_ij` and `w_ij`; the per-point `A_i⁺` turns the accumulated outer
//! product into F. The same identity collapses the force scatter (see `forces`).
//!
//! Rank handling after cuts (§3): the eigenvalues of A_i decide the rank, with a direction
//! counted as unsampled below `σ_max / 10⁴`. Rank 3 uses A⁻¹. Rank 2 (a planar
//! neighbourhood, e.g. a one-layer sliver) uses the pseudo-inverse and records the range and
//! null directions so that F can be completed with the current normal. Rank ≤ 1, or fewer than
//! four neighbours, is an orphan: it carries no stress of its own and follows its neighbours
//! through their fits (they still see it) and their hourglass terms.
//!
//! Rows are stored with a fixed capacity per point, mirroring [`Neighbourhoods`], so a cut
//! recomputes only the points whose neighbourhood changed ([`MlsOperator::update_points`]).
//! The pair data is kept as structure-of-arrays with the capacity rounded up to a multiple
//! of [`LANES`]: the force kernel reads four pairs at a time. Padding slots name the point
//! itself and carry zero weights, so they add nothing wherever they are read.

pub mod stencil;

use crate::math::{Mat3, Vec3};
use crate::model::{Kernel, Neighbourhoods};
use stencil::LatticeStencil;

/// A direction is unsampled when its eigenvalue is below σ_max divided by this.
pub const MAX_CONDITION: f64 = 1e4;

/// Pairs processed together by the force kernel.
pub const LANES: usize = 4;

/// Longest row a stencil run may have (the kernel keeps a run's offsets on the stack).
pub const MAX_RUN_ROW: usize = 64;

/// Lattice coordinates of the points and the spacing: with them, rest offsets between lattice
/// points are computed exactly as `s·(Δi, Δj, Δk)`, so every interior point with a complete
/// stencil gets a bit-identical row (which the stencil kernel relies on).
#[derive(Debug, Clone, PartialEq)]
pub struct LatticeOffsets {
    /// Lattice coordinates (i, j, k) per point.
    pub coords: Vec<[u32; 3]>,
    /// Spacing s (m).
    pub spacing: f64,
}

/// Per-pair data: `w_ij x_ij` and `w_ij`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PairTerm {
    /// `w_ij (X_j − X_i)` (m).
    pub wx: Vec3,
    /// Kernel weight w_ij.
    pub w: f64,
}

/// How a point's neighbourhood samples space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PointRank {
    /// Full rank: F from A⁻¹.
    Full,
    /// Planar neighbourhood: F from the pseudo-inverse, completed along `null` (rest normal)
    /// with the current normal built from the images of `t1` and `t2`.
    Planar {
        /// In-plane principal direction.
        t1: Vec3,
        /// Second in-plane direction, with `t1 × t2 = null`.
        t2: Vec3,
        /// Unsampled (normal) direction.
        null: Vec3,
    },
    /// Rank ≤ 1 or fewer than 4 neighbours: no stress of its own.
    Orphan,
}

/// Per-point data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointTerm {
    /// A⁺ (inverse, or pseudo-inverse on the sampled directions).
    pub a_pinv: Mat3,
    /// tr(A) (m²), for the hourglass stiffness k_i = α E V_i / tr(A_i).
    pub trace_a: f64,
    /// Σ_j w_ij x_ij (m): with it, `F_i = (Σ_j p_j ⊗ w x − p_i ⊗ Σ w x) A⁺`.
    pub sum_wx: Vec3,
    /// Σ_j w_ij.
    pub sum_w: f64,
    /// σ_max / σ_min of A over its sampled directions.
    pub condition: f64,
    /// Rank classification.
    pub rank: PointRank,
}

impl Default for PointTerm {
    fn default() -> Self {
        Self {
            a_pinv: Mat3::zeros(),
            trace_a: 0.0,
            sum_wx: Vec3::zeros(),
            sum_w: 0.0,
            condition: 1.0,
            rank: PointRank::Orphan,
        }
    }
}

/// The precomputed operator: for each point, its neighbours, pair terms and point term.
#[derive(Debug, Clone, PartialEq)]
pub struct MlsOperator {
    /// Slots per point: the neighbour capacity rounded up to a multiple of [`LANES`].
    capacity: usize,
    counts: Vec<u32>,
    ids: Vec<u32>,
    /// `w_ij x_ij`, one array per component.
    wx: [Vec<f64>; 3],
    w: Vec<f64>,
    points: Vec<PointTerm>,
    lattice: Option<LatticeOffsets>,
    /// First points of runs: four consecutive full-rank points with bit-identical rows whose
    /// neighbours in every slot are consecutive too (the interior of the lattice). The force
    /// kernel treats a run as four SIMD lanes.
    runs: Vec<u32>,
    in_run: Vec<bool>,
    run_start: Vec<u32>,
    /// The uncut lattice's points as a box with a fixed stencil, for whole-body evaluations.
    stencil: Option<LatticeStencil>,
    /// Counts the updates of rows, so that what is derived from them can tell it is stale.
    topology_version: u64,
}

/// Counts of each rank class, for reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct RankCounts {
    /// Full-rank points.
    pub full: usize,
    /// Planar (rank-2) points.
    pub planar: usize,
    /// Orphans.
    pub orphan: usize,
}

impl MlsOperator {
    /// Precomputes the operator for every point. With `lattice`, offsets between lattice points
    /// are exact multiples of the spacing.
    pub fn build(
        rest: &[Vec3],
        neighbours: &Neighbourhoods,
        kernel: &Kernel,
        lattice: Option<LatticeOffsets>,
    ) -> Self {
        let capacity = neighbours.capacity().div_ceil(LANES).max(1) * LANES;
        let n = rest.len();
        let mut op = Self {
            capacity,
            counts: vec![0; n],
            ids: vec![0; n * capacity],
            wx: [
                vec![0.0; n * capacity],
                vec![0.0; n * capacity],
                vec![0.0; n * capacity],
            ],
            w: vec![0.0; n * capacity],
            points: vec![PointTerm::default(); n],
            lattice,
            runs: Vec::new(),
            in_run: vec![false; n],
            run_start: vec![0; n],
            stencil: None,
            topology_version: 0,
        };
        for i in 0..n {
            op.compute_point(i, rest, neighbours, kernel);
        }
        op.detect_runs();
        op.stencil = match &op.lattice {
            Some(l) => LatticeStencil::build(&op, rest, l, kernel),
            None => None,
        };
        op
    }

    /// Changes whenever rows are recomputed ([`MlsOperator::update_points`]).
    pub fn topology_version(&self) -> u64 {
        self.topology_version
    }

    /// The lattice stencil, when the operator has one (see `stencil`).
    pub fn stencil(&self) -> Option<&LatticeStencil> {
        self.stencil.as_ref()
    }

    /// Recomputes the rows of `points` after their neighbour lists changed (a cut). Call it
    /// for every point whose list changed, including those that lost a neighbour because the
    /// other end's list changed.
    pub fn update_points(
        &mut self,
        points: &[u32],
        rest: &[Vec3],
        neighbours: &Neighbourhoods,
        kernel: &Kernel,
    ) {
        self.topology_version += 1;
        for &i in points {
            self.compute_point(i as usize, rest, neighbours, kernel);
            // Its row is no longer the stencil's (or may not be): the pair kernels take it.
            if let Some(stencil) = &mut self.stencil {
                stencil.demote(i as usize);
            }
        }
        // Runs containing a changed point no longer share one row: their points go back to
        // the single-point kernel. Local work only (new runs are not formed after a cut).
        let mut dissolved = false;
        for &i in points {
            let i = i as usize;
            if self.in_run[i] {
                let start = self.run_start[i] as usize;
                self.in_run[start..start + LANES]
                    .iter_mut()
                    .for_each(|r| *r = false);
                dissolved = true;
            }
        }
        if dissolved {
            let in_run = &self.in_run;
            self.runs.retain(|&r| in_run[r as usize]);
        }
    }

    /// The first point of the run containing point i (meaningful when [`MlsOperator::in_run`]).
    #[inline]
    pub fn run_start(&self, i: usize) -> usize {
        self.run_start[i] as usize
    }

    /// Finds the runs of four points the stencil kernel can process together.
    fn detect_runs(&mut self) {
        self.runs.clear();
        self.in_run.iter_mut().for_each(|r| *r = false);
        let n = self.len();
        let mut i = 0;
        while i + LANES <= n {
            if self.is_run(i) {
                self.runs.push(i as u32);
                self.in_run[i..i + LANES].iter_mut().for_each(|r| *r = true);
                self.run_start[i..i + LANES]
                    .iter_mut()
                    .for_each(|r| *r = i as u32);
                i += LANES;
            } else {
                i += 1;
            }
        }
    }

    fn is_run(&self, i: usize) -> bool {
        let first = &self.points[i];
        let count = self.counts[i] as usize;
        if !matches!(first.rank, PointRank::Full) || count == 0 || count > MAX_RUN_ROW {
            return false;
        }
        let row = |k: usize| (k * self.capacity)..(k * self.capacity + count);
        let same_bits =
            |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        (1..LANES).all(|lane| {
            let q = i + lane;
            let other = &self.points[q];
            self.counts[q] as usize == count
                && matches!(other.rank, PointRank::Full)
                && same_bits(first.a_pinv.as_slice(), other.a_pinv.as_slice())
                && first.trace_a.to_bits() == other.trace_a.to_bits()
                && same_bits(&self.w[row(i)], &self.w[row(q)])
                && (0..3).all(|c| same_bits(&self.wx[c][row(i)], &self.wx[c][row(q)]))
                && self.ids[row(i)]
                    .iter()
                    .zip(&self.ids[row(q)])
                    .all(|(a, b)| *b as usize == *a as usize + lane)
        })
    }

    /// Runs of four points for the stencil kernel (their first indices).
    pub fn runs(&self) -> &[u32] {
        &self.runs
    }

    /// Whether point i belongs to a run.
    #[inline]
    pub fn in_run(&self, i: usize) -> bool {
        self.in_run[i]
    }

    fn compute_point(
        &mut self,
        i: usize,
        rest: &[Vec3],
        neighbours: &Neighbourhoods,
        kernel: &Kernel,
    ) {
        let list = neighbours.of(i);
        let extra = neighbours.extra_of(i);
        let base = i * self.capacity;
        let mut a = Mat3::zeros();
        let mut sum_wx = Vec3::zeros();
        let mut sum_w = 0.0;
        let mut count = 0;
        for (&j, &e) in list.iter().zip(extra) {
            // Exact lattice offsets between lattice points; nodes added after the lattice
            // (virtual points) use their rest positions.
            let x = match &self.lattice {
                Some(l) if i < l.coords.len() && (j as usize) < l.coords.len() => {
                    let (a, b) = (l.coords[i], l.coords[j as usize]);
                    Vec3::new(
                        (b[0] as f64 - a[0] as f64) * l.spacing,
                        (b[1] as f64 - a[1] as f64) * l.spacing,
                        (b[2] as f64 - a[2] as f64) * l.spacing,
                    )
                }
                _ => rest[j as usize] - rest[i],
            };
            // A transparent pair (near the crack front) weighs as if it were `e` farther.
            let w = if e > 0.0 {
                let r = x.norm() + e;
                kernel.weight_sq(r * r)
            } else {
                kernel.weight_sq(x.norm_squared())
            };
            if w <= 0.0 {
                continue;
            }
            a += x * x.transpose() * w;
            sum_wx += x * w;
            sum_w += w;
            self.ids[base + count] = j;
            for c in 0..3 {
                self.wx[c][base + count] = x[c] * w;
            }
            self.w[base + count] = w;
            count += 1;
        }
        self.order_row(base, count);
        for k in count..self.capacity {
            self.ids[base + k] = i as u32;
            for c in 0..3 {
                self.wx[c][base + k] = 0.0;
            }
            self.w[base + k] = 0.0;
        }
        self.counts[i] = count as u32;
        self.points[i] = classify(a, sum_wx, sum_w, count);
    }

    /// Orders a row's slots by their x offset (behind, ahead, level), and within each of
    /// those by the signs of their y and z offsets, the same way in each. On the lattice,
    /// neighbours whose offsets differ only in x have overlapping index ranges in a run's
    /// 4-lane force writes; in this order they sit a third of the row apart, so one write
    /// has left the store buffer before the next overlapping read (adjacent, they stall on
    /// store forwarding: up to half of the run kernel's time, perf). The order is a pure
    /// function of the row's values, so identical rows stay identical. In place, without
    /// allocation (cuts call this on the simulation thread).
    fn order_row(&mut self, base: usize, count: usize) {
        let sign = |v: f64| {
            if v < 0.0 {
                0u8
            } else if v > 0.0 {
                2
            } else {
                1
            }
        };
        let key = |op: &Self, k: usize| {
            let (x, y, z) = (op.wx[0][base + k], op.wx[1][base + k], op.wx[2][base + k]);
            // Behind (0), ahead (1), level (2) in x.
            let group = [0u8, 2, 1][sign(x) as usize];
            (group, sign(y), sign(z), x, y, z)
        };
        // Insertion sort: rows are short (~26) and this runs at build time and on cuts.
        for k in 1..count {
            let mut m = k;
            while m > 0
                && key(self, m - 1).partial_cmp(&key(self, m)) == Some(std::cmp::Ordering::Greater)
            {
                let (a, b) = (base + m - 1, base + m);
                self.ids.swap(a, b);
                self.w.swap(a, b);
                for c in 0..3 {
                    self.wx[c].swap(a, b);
                }
                m -= 1;
            }
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Neighbour ids of point i.
    #[inline]
    pub fn neighbours(&self, i: usize) -> &[u32] {
        let base = i * self.capacity;
        &self.ids[base..base + self.counts[i] as usize]
    }

    /// Pair terms of point i, in the order of [`MlsOperator::neighbours`].
    #[inline]
    pub fn pair_terms(&self, i: usize) -> impl Iterator<Item = PairTerm> + '_ {
        let base = i * self.capacity;
        (base..base + self.counts[i] as usize).map(|k| self.pair_at(k))
    }

    /// The k-th pair term of point i.
    #[inline]
    pub fn pair(&self, i: usize, k: usize) -> PairTerm {
        debug_assert!(k < self.counts[i] as usize);
        self.pair_at(i * self.capacity + k)
    }

    #[inline]
    fn pair_at(&self, slot: usize) -> PairTerm {
        PairTerm {
            wx: Vec3::new(self.wx[0][slot], self.wx[1][slot], self.wx[2][slot]),
            w: self.w[slot],
        }
    }

    /// The whole padded row of point i, for the force kernel: ids (padding = i), the three
    /// `w x` components and w, each `capacity` long.
    #[inline]
    pub(crate) fn padded_row(&self, i: usize) -> (&[u32], [&[f64]; 3], &[f64]) {
        let r = i * self.capacity..(i + 1) * self.capacity;
        (
            &self.ids[r.clone()],
            [
                &self.wx[0][r.clone()],
                &self.wx[1][r.clone()],
                &self.wx[2][r.clone()],
            ],
            &self.w[r],
        )
    }

    /// Point term of point i.
    #[inline]
    pub fn point(&self, i: usize) -> &PointTerm {
        &self.points[i]
    }

    /// Slots per point (the neighbour capacity rounded up to a multiple of [`LANES`]).
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The MLS gradient weight vector `d_ij = A_i⁺ w_ij x_ij` for the k-th neighbour of i.
    pub fn d(&self, i: usize, k: usize) -> Vec3 {
        self.points[i].a_pinv * self.pair(i, k).wx
    }

    /// How many points are in each rank class.
    pub fn rank_counts(&self) -> RankCounts {
        self.rank_counts_of(0..self.points.len())
    }

    /// Counts of each rank class over the points in `range`.
    pub fn rank_counts_of(&self, range: std::ops::Range<usize>) -> RankCounts {
        let mut c = RankCounts::default();
        for p in &self.points[range] {
            match p.rank {
                PointRank::Full => c.full += 1,
                PointRank::Planar { .. } => c.planar += 1,
                PointRank::Orphan => c.orphan += 1,
            }
        }
        c
    }

    /// Deformation gradient of point i at positions `p` (completed for planar points,
    /// identity for orphans, which have none of their own).
    pub fn deformation_gradient(&self, i: usize, p: &[Vec3]) -> Mat3 {
        let term = &self.points[i];
        if let PointRank::Orphan = term.rank {
            return Mat3::identity();
        }
        let fp = self.fitted_gradient(i, p);
        complete(fp, &term.rank)
    }

    /// The least-squares fit `F_p = Σ_j (p_j − p_i) ⊗ w x · A⁺` without completion.
    #[inline]
    pub fn fitted_gradient(&self, i: usize, p: &[Vec3]) -> Mat3 {
        let pi = p[i];
        let mut b = Mat3::zeros();
        for (j, pair) in self.neighbours(i).iter().zip(self.pair_terms(i)) {
            b += (p[*j as usize] - pi) * pair.wx.transpose();
        }
        b * self.points[i].a_pinv
    }

    /// The surface's map `x = Σ_k w_k (p_k + F_k (X − X_k))` (physics.md §5.3) at rest
    /// point `x` as one row over the points, linear in them: F_k's fitted part is
    /// `Σ_j (p_j − p_k) (w x_kj · A_k⁺ (X − X_k))`. A planar point's completion and an
    /// orphan's identity are left out (their rest value goes to the sample's offset).
    /// `zero` is the kernel row (k, w_k); `out` gets the row sorted by point, merged.
    pub fn linear_row(
        &self,
        zero: &[(u32, f64)],
        x: &Vec3,
        rest: &[Vec3],
        out: &mut Vec<(u32, f64)>,
    ) {
        out.clear();
        for &(k, w) in zero {
            out.push((k, w));
            let term = &self.points[k as usize];
            if let PointRank::Orphan = term.rank {
                continue;
            }
            let r = term.a_pinv * (x - rest[k as usize]);
            let mut own = 0.0;
            for (j, pair) in self
                .neighbours(k as usize)
                .iter()
                .zip(self.pair_terms(k as usize))
            {
                let s = w * pair.wx.dot(&r);
                out.push((*j, s));
                own -= s;
            }
            out.push((k, own));
        }
        out.sort_unstable_by_key(|e| e.0);
        out.dedup_by(|later, kept| {
            let same = later.0 == kept.0;
            if same {
                kept.1 += later.1;
            }
            same
        });
    }
}

/// Completes a planar point's fitted gradient with the current normal (physics.md §3):
/// `F = F_p + n_c n_rᵀ`, `n_c = normalize((F_p t1) × (F_p t2))`. Other ranks pass through.
#[inline]
pub fn complete(fp: Mat3, rank: &PointRank) -> Mat3 {
    match rank {
        PointRank::Planar { t1, t2, null } => {
            let nc = (fp * t1).cross(&(fp * t2));
            let len = nc.norm();
            if len > 0.0 {
                fp + (nc / len) * null.transpose()
            } else {
                // The sliver collapsed to a line; keep the rest normal rather than a zero column.
                fp + null * null.transpose()
            }
        }
        _ => fp,
    }
}

/// Rank test and (pseudo-)inverse of a moment matrix.
fn classify(a: Mat3, sum_wx: Vec3, sum_w: f64, count: usize) -> PointTerm {
    let trace_a = a.trace();
    let mut term = PointTerm {
        trace_a,
        sum_wx,
        sum_w,
        ..PointTerm::default()
    };
    if count < 4 || trace_a <= 0.0 {
        return term;
    }
    let eig = nalgebra::SymmetricEigen::new(a);
    let sigma_max = eig.eigenvalues.max();
    let threshold = sigma_max / MAX_CONDITION;
    // The directions the neighbourhood samples, in ascending order (no allocation: rows
    // are refitted on the simulation thread when a cut changes them).
    let mut kept = [0usize; 3];
    let mut n_kept = 0;
    for k in 0..3 {
        if eig.eigenvalues[k] > threshold {
            kept[n_kept] = k;
            n_kept += 1;
        }
    }
    let sampled = &kept[..n_kept];
    let mut pinv = Mat3::zeros();
    for &k in sampled {
        let v = eig.eigenvectors.column(k);
        pinv += v * v.transpose() / eig.eigenvalues[k];
    }
    let sigma_min = sampled
        .iter()
        .map(|&k| eig.eigenvalues[k])
        .fold(f64::INFINITY, f64::min);
    term.a_pinv = pinv;
    term.condition = sigma_max / sigma_min;
    term.rank = match sampled.len() {
        3 => PointRank::Full,
        2 => {
            let null_k = (0..3).find(|k| !sampled.contains(k)).unwrap_or(0);
            let t1: Vec3 = eig.eigenvectors.column(sampled[0]).into();
            let t2: Vec3 = eig.eigenvectors.column(sampled[1]).into();
            // Orient the null direction so that (t1, t2, null) is right-handed; completion
            // then keeps det F > 0 under any rotation.
            let mut null: Vec3 = eig.eigenvectors.column(null_k).into();
            if t1.cross(&t2).dot(&null) < 0.0 {
                null = -null;
            }
            PointRank::Planar { t1, t2, null }
        }
        _ => {
            term.a_pinv = Mat3::zeros();
            PointRank::Orphan
        }
    };
    term
}
