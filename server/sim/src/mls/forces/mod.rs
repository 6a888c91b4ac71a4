//! Elastic forces as the exact negative gradient of the MLS energy, with hourglass
//! stabilisation (physics.md §1.7, §1.9), and the matrix-free tangent product.
//!
//! Per point i with `u_ij = p_j − p_i`:
//!
//! ```text
//! B_i  = Σ_j u_ij ⊗ (w_ij x_ij)          F_p = B_i A_i⁺    F = complete(F_p)
//! Fe_i = −V_i P(F)                       k_i = α E V_i / tr A_i
//! M_i  = Fe_i A_i⁺ + k_i F_p
//! g_ij = M_i (w_ij x_ij) − k_i w_ij u_ij ;   f_j += g_ij ,   f_i −= g_ij
//! ```
//!
//! `M_i (w x)` is `Fe_i d_ij` (the stress term) plus `k_i w F_p x` (from the hourglass residual
//! `e_ij = u_ij − F_p x_ij`, whose force is `−k_i w_ij e_ij` on j). Every pair term is
//! antisymmetric, so Σf = 0 and Σ p × f = 0 hold to rounding. No allocation.

mod eval_set;
mod lane_stvk;
mod pair_kernel;
pub(crate) mod stencil_kernel;

use crate::math::{Mat3, Vec3};
use wide::f64x4;

use crate::mls::material::{
    DET_RANGE, ElasticModel, ElasticParams, StressSample, stress, stress_differential,
};
use crate::mls::operator::stencil::LatticeStencil;
use crate::mls::operator::{LANES, MAX_RUN_ROW, MlsOperator, PointRank, complete};
use crate::mls::prestress::{self, Prestress, Sym};
use stencil_kernel::{Restriction, StencilFields, StencilInputs};

pub use eval_set::EvalSet;
pub(crate) use eval_set::StencilChunks;
use lane_stvk::point_stvk;
pub(crate) use lane_stvk::{lane_stress_scalar, lane_stvk};
use pair_kernel::{Points, Shared, Skip};

/// Figures from one force evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceStats {
    /// Strain energy Σ V_i ψ(F_i) (J).
    pub strain_energy: f64,
    /// Hourglass energy (J).
    pub hourglass_energy: f64,
    /// The surface layer's prestress energy Σ V S₀ : E (J, `mls::prestress`): negative
    /// where the layer has shortened.
    pub prestress_energy: f64,
    /// Smallest det F over points with stress.
    pub min_det_f: f64,
    /// Largest det F.
    pub max_det_f: f64,
    /// Points whose F was clamped (det F outside [0.2, 5]).
    pub clamped_points: u32,
    /// False if any F was not finite.
    pub finite: bool,
    /// The largest factor by which the material's stiffening raised a point's tangent (1:
    /// none; `StressSample::stiffening`).
    pub max_stiffening: f64,
}

impl ForceStats {
    /// Nothing evaluated yet.
    pub const EMPTY: Self = Self {
        strain_energy: 0.0,
        hourglass_energy: 0.0,
        prestress_energy: 0.0,
        min_det_f: f64::INFINITY,
        max_det_f: f64::NEG_INFINITY,
        clamped_points: 0,
        finite: true,
        max_stiffening: 1.0,
    };

    /// Adds one point's energies and stress checks. The hourglass energy is
    /// `½ k (Σ w |u|² − F_p : B)` for the least-squares F_p, clipped at 0 against rounding.
    pub(crate) fn add_point(&mut self, strain: f64, hourglass: f64, check: PointCheck) {
        self.strain_energy += strain;
        self.hourglass_energy += hourglass.max(0.0);
        self.min_det_f = self.min_det_f.min(check.det);
        self.max_det_f = self.max_det_f.max(check.det);
        self.clamped_points += u32::from(check.clamped);
        self.finite &= check.finite;
        self.max_stiffening = self.max_stiffening.max(check.stiffening);
    }

    /// The figures of two disjoint sets of points together (`self` first in the sums).
    pub fn merge(&self, other: &Self) -> Self {
        Self {
            strain_energy: self.strain_energy + other.strain_energy,
            hourglass_energy: self.hourglass_energy + other.hourglass_energy,
            prestress_energy: self.prestress_energy + other.prestress_energy,
            min_det_f: self.min_det_f.min(other.min_det_f),
            max_det_f: self.max_det_f.max(other.max_det_f),
            clamped_points: self.clamped_points + other.clamped_points,
            finite: self.finite && other.finite,
            max_stiffening: self.max_stiffening.max(other.max_stiffening),
        }
    }

    /// Total elastic energy (J).
    pub fn energy(&self) -> f64 {
        self.unsigned_energy() + self.prestress_energy
    }

    /// The part of the elastic energy that is never negative: strain and hourglass (J).
    pub fn unsigned_energy(&self) -> f64 {
        self.strain_energy + self.hourglass_energy
    }
}

/// What one point's stress evaluation tells the statistics.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PointCheck {
    /// det F before any clamping.
    det: f64,
    /// The singular values were clamped.
    clamped: bool,
    /// det F and P are finite.
    finite: bool,
    /// The stiffening's factor on the tangent (1: none).
    stiffening: f64,
}

impl PointCheck {
    fn of(s: &StressSample) -> Self {
        Self {
            det: s.det,
            clamped: s.clamped,
            finite: s.det.is_finite() && s.p.iter().all(|x| x.is_finite()),
            stiffening: s.stiffening,
        }
    }

    /// StVK inside the ordinary det F range (so finite, not clamped), its tangent
    /// `stiffening` times the plain law's.
    pub(crate) fn plain(det: f64, stiffening: f64) -> Self {
        Self {
            det,
            clamped: false,
            finite: det.is_finite(),
            stiffening,
        }
    }
}

/// Hourglass stiffness k_i = α E V_i / tr(A_i) (N/m).
#[inline]
pub fn hourglass_stiffness(params: &ElasticParams, volume: f64, trace_a: f64) -> f64 {
    if trace_a > 0.0 {
        params.hourglass_alpha * params.effective_youngs_modulus() * volume / trace_a
    } else {
        0.0
    }
}

/// A force evaluation is split into this many parts, each summing into its own buffers,
/// merged in a fixed order. Fixed whatever the thread count, so one thread and two give the
/// same bits.
pub const PARTS: usize = 2;

/// One part's forces: the run kernel's (structure-of-arrays) and the point kernel's.
#[derive(Debug, Clone, Default)]
struct PartForces {
    soa: [Vec<f64>; 3],
    /// (x, y, z, 0) per point.
    lanes: Vec<f64x4>,
}

/// Positions in both kernels' layouts and each part's forces, allocated once.
#[derive(Debug, Clone, Default)]
pub struct ForceScratch {
    pos: [Vec<f64>; 3],
    /// Positions as (x, y, z, 0) vectors for the point kernel.
    pos4: Vec<f64x4>,
    parts: [PartForces; PARTS],
    /// Where the two parts run.
    threads: Threads,
    /// The box fields of the lattice stencil (`stencil_kernel`), sized at first use.
    stencil: StencilFields,
    /// Whole-body evaluations never take the lattice stencil (otherwise they do where the
    /// operator has one).
    pairs_only: bool,
    /// Beside the stencil, what is left to the pair kernels.
    pair_work: PairWork,
}

/// The points the pair kernels take beside the lattice stencil (those it does not
/// evaluate), and the points their rows reach (sorted): only those points' positions are
/// copied and force buffers read.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct PairLists {
    pub points: Vec<u32>,
    pub touched: Vec<u32>,
    flags: Vec<bool>,
}

impl PairLists {
    /// The lists for the `candidates` (in order) that the stencil does not evaluate,
    /// reusing the buffers (sized for every point at the first call, so later ones do not
    /// allocate).
    fn fill(
        &mut self,
        op: &MlsOperator,
        evaluated: &[bool],
        candidates: impl IntoIterator<Item = u32>,
    ) {
        let n = op.len();
        if self.flags.len() != n {
            self.flags = vec![false; n];
            self.points = Vec::with_capacity(n);
            self.touched = Vec::with_capacity(n);
        }
        for &i in &self.touched {
            self.flags[i as usize] = false;
        }
        self.points.clear();
        self.touched.clear();
        for i in candidates {
            if evaluated[i as usize] {
                continue;
            }
            self.points.push(i);
            for &j in std::iter::once(&i).chain(op.neighbours(i as usize)) {
                if !std::mem::replace(&mut self.flags[j as usize], true) {
                    self.touched.push(j);
                }
            }
        }
        self.touched.sort_unstable();
    }
}

/// What a whole-body evaluation leaves to the pair kernels, for one topology of the
/// operator.
#[derive(Debug, Clone, Default)]
struct PairWork {
    /// The operator's [`MlsOperator::topology_version`] the lists are for.
    version: Option<u64>,
    lists: PairLists,
}

impl PairWork {
    /// Brings the lists up to date with `op` (a pass over the points after a cut).
    fn refresh(&mut self, op: &MlsOperator, evaluated: &[bool]) {
        if self.version == Some(op.topology_version()) {
            return;
        }
        self.lists.fill(op, evaluated, 0..op.len() as u32);
        self.version = Some(op.topology_version());
    }
}

impl ForceScratch {
    /// Buffers for `n` points.
    pub fn new(n: usize) -> Self {
        let mut s = Self::default();
        s.resize(n);
        s
    }

    /// Sizes every buffer an evaluation with `op` needs (the lattice stencil's fields and
    /// lists included), so that the first evaluation does not allocate: for callers that
    /// count allocations from their first tick.
    pub fn fit_to(&mut self, op: &MlsOperator) {
        self.resize(op.len());
        if let Some(stencil) = op.stencil() {
            self.stencil.fit(stencil);
            self.pair_work.refresh(op, stencil.evaluated());
        }
    }

    /// The same buffers, never taking the lattice stencil: every point through the pair
    /// kernels (to compare the two paths).
    pub fn without_stencil(mut self) -> Self {
        self.pairs_only = true;
        self
    }

    /// The same buffers, evaluated with `threads`.
    pub fn with_threads(mut self, threads: Threads) -> Self {
        self.threads = threads;
        self
    }

    /// Where the evaluations run their parts.
    pub fn threads(&self) -> Threads {
        self.threads
    }

    /// Where the evaluation's parts run from now on.
    pub fn set_threads(&mut self, threads: Threads) {
        self.threads = threads;
    }

    fn resize(&mut self, n: usize) {
        if self.pos4.len() == n {
            return;
        }
        // Only when the point count changes, never in a steady loop.
        for c in 0..3 {
            self.pos[c].resize(n, 0.0);
        }
        self.pos4.resize(n, f64x4::ZERO);
        for part in &mut self.parts {
            for c in 0..3 {
                part.soa[c].resize(n, 0.0);
            }
            part.lanes.resize(n, f64x4::ZERO);
        }
    }

    /// Copies the positions of `points` (all when `None`) into both layouts. The force
    /// buffers are zero between evaluations: the merge that reads an entry clears it, and
    /// the kernels write only to the points the merge reads (a separate clearing pass cost
    /// as much as the merge).
    fn prepare(&mut self, p: &[Vec3], points: Option<&[u32]>) {
        self.resize(p.len());
        let mut one = |i: usize| {
            for c in 0..3 {
                self.pos[c][i] = p[i][c];
            }
            self.pos4[i] = f64x4::from([p[i].x, p[i].y, p[i].z, 0.0]);
        };
        match points {
            Some(list) => list.iter().for_each(|&i| one(i as usize)),
            None => (0..p.len()).for_each(one),
        }
    }
}

/// Adds the elastic forces at positions `p` to `f` (N): of every point, or, with `set`, of
/// the points in `set.stress` (forces then land only on `set.touched`, and are whole on
/// `set.active`). With `prestress`, its layer's `F S₀` is added to their stress.
///
/// Runs of four interior points with identical stencils go through a 4-lane SIMD kernel
/// (contiguous loads, shared rows); every other point through the single-point kernel.
/// The work is split in two fixed parts ([`PARTS`]), on one thread or two ([`Threads`]),
/// with the same bits either way.
#[allow(clippy::too_many_arguments)]
pub fn add_elastic_forces(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    prestress: Option<&Prestress>,
    p: &[Vec3],
    set: Option<&EvalSet>,
    f: &mut [Vec3],
    scratch: &mut ForceScratch,
) -> ForceStats {
    // The merge reads (and clears) `f.len()` entries and the kernels write up to
    // `op.len()`: a shorter `f` would leave forces in the scratch for the next call.
    assert!(
        f.len() == p.len() && p.len() == op.len(),
        "forces {}, positions {} and operator {} must cover the same points",
        f.len(),
        p.len(),
        op.len()
    );
    // A whole-body evaluation takes the uncut lattice's points through the fixed stencil
    // (`stencil_kernel`); the pair kernels then take only the points it does not evaluate.
    // A set that holds every point is the whole body.
    let set = set.filter(|s| s.stress.len() < op.len());
    // A restricted evaluation takes the stencil over the chunks of its points.
    let stencil = match set {
        _ if scratch.pairs_only => None,
        None => op.stencil(),
        Some(s) => s.stencil_chunks().and(op.stencil()),
    };
    let runs: &[u32] = match (set, stencil) {
        (_, Some(_)) => &[],
        (Some(s), None) => &s.runs,
        (None, None) => op.runs(),
    };
    let mut work = std::mem::take(&mut scratch.pair_work);
    if let (None, Some(stencil)) = (set, stencil) {
        work.refresh(op, stencil.evaluated());
    }
    // Both kernels read positions and write forces in their own layout: runs as
    // structure-of-arrays (contiguous lanes), single points as (x, y, z, 0) vectors (one
    // neighbour is one aligned load). The forces are summed into `f` at the end.
    let touched: Option<&[u32]> = match (set, stencil) {
        (Some(s), Some(_)) => s.stencil_chunks().map(|c| &c.pairs.touched[..]),
        (Some(s), None) => Some(&s.touched),
        (None, Some(_)) => Some(&work.lists.touched),
        (None, None) => None,
    };
    scratch.prepare(p, touched);
    let ForceScratch {
        pos,
        pos4,
        parts,
        threads,
        stencil: fields,
        ..
    } = scratch;
    let prestress = prestress.and_then(Prestress::field);
    let stencil_stats = stencil.map(|stencil| {
        let inputs = StencilInputs {
            stencil,
            params,
            volumes,
            prestress,
        };
        let restriction = set.map(|s| Restriction {
            chunks: s.stencil_chunks().expect("a set with stencil chunks"),
            stress: &s.in_stress,
            touched: &s.touched,
        });
        let (a, b) = stencil_kernel::evaluate(inputs, p, restriction, fields, *threads);
        a.merge(&b)
    });
    let shared = Shared {
        op,
        params,
        volumes,
        prestress,
        pos: [&pos[0][..], &pos[1][..], &pos[2][..]],
        pos4,
        skip: match (set, stencil) {
            (_, Some(st)) => Skip::Stencil(st.evaluated()),
            (Some(s), None) => Skip::InRuns(&s.in_runs),
            (None, None) => Skip::OperatorRuns,
        },
    };
    // Half of the runs and half of the single points each: the two kernels' costs per point
    // differ, so both are split.
    let (runs_a, runs_b) = runs.split_at(runs.len() / 2);
    let listed = match (set, stencil) {
        (Some(s), Some(_)) => s.stencil_chunks().map(|c| &c.pairs.points[..]),
        (Some(s), None) => Some(&s.stress[..]),
        (None, Some(_)) => Some(&work.lists.points[..]),
        (None, None) => None,
    };
    let (points_a, points_b) = match listed {
        Some(list) => {
            let (a, b) = list.split_at(list.len() / 2);
            (Points::Listed(a), Points::Listed(b))
        }
        None => {
            let half = op.len() / 2;
            (Points::Range(0..half), Points::Range(half..op.len()))
        }
    };
    let [part_a, part_b] = parts;
    let (stats_a, stats_b) = match *threads {
        Threads::One => (
            shared.part(runs_a, points_a, part_a),
            shared.part(runs_b, points_b, part_b),
        ),
        #[cfg(feature = "parallel")]
        Threads::Rayon => rayon::join(
            || shared.part(runs_a, points_a, part_a),
            || shared.part(runs_b, points_b, part_b),
        ),
    };
    merge_parts(f, part_a, part_b, touched);
    scratch.pair_work = work;
    let pair_stats = stats_a.merge(&stats_b);
    match (stencil, stencil_stats) {
        (Some(stencil), Some(stats)) => {
            add_gathered(f, stencil, fields, set);
            stats.merge(&pair_stats)
        }
        _ => pair_stats,
    }
}

/// Sums both parts' forces on `touched` (all points when `None`) into `f`, clearing them
/// for the next evaluation.
fn merge_parts(
    f: &mut [Vec3],
    part_a: &mut PartForces,
    part_b: &mut PartForces,
    touched: Option<&[u32]>,
) {
    let n = f.len();
    let mut add = |i: usize| {
        let (ga, gb) = (part_a.lanes[i].to_array(), part_b.lanes[i].to_array());
        for c in 0..3 {
            f[i][c] += part_a.soa[c][i] + ga[c] + (part_b.soa[c][i] + gb[c]);
            part_a.soa[c][i] = 0.0;
            part_b.soa[c][i] = 0.0;
        }
        part_a.lanes[i] = f64x4::ZERO;
        part_b.lanes[i] = f64x4::ZERO;
    };
    match touched {
        Some(list) => list.iter().for_each(|&i| add(i as usize)),
        None => (0..n).for_each(add),
    }
}

/// Adds the stencil's gathered forces to `f`: the sites of the points whose forces are
/// whole (all, or the set's active points) are written by each evaluation, so nothing
/// needs clearing.
fn add_gathered(
    f: &mut [Vec3],
    stencil: &LatticeStencil,
    fields: &StencilFields,
    set: Option<&EvalSet>,
) {
    let sites = stencil.site_of();
    let [fx, fy, fz] = fields.forces();
    let at = |site: u32| {
        let s = site as usize;
        Vec3::new(fx[s], fy[s], fz[s])
    };
    match set {
        None => {
            for (f, &site) in f.iter_mut().zip(sites) {
                *f += at(site);
            }
        }
        Some(s) => {
            for &i in &s.active {
                if let Some(&site) = sites.get(i as usize) {
                    f[i as usize] += at(site);
                }
            }
        }
    }
}

/// Where a force evaluation runs its parts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Threads {
    /// One after the other on the calling thread (the real-time default: no waiting).
    #[default]
    One,
    /// As a `rayon::join`: in parallel when called inside a rayon pool with a free thread.
    /// The caller waits on rayon's latch, so this is for machines with a core to spare.
    #[cfg(feature = "parallel")]
    Rayon,
}

impl Threads {
    /// Runs `a` and `b`, one after the other or as a `rayon::join` (`b` then on another
    /// thread of the caller's pool if one is free).
    pub(crate) fn both<A: Send, B: Send>(
        self,
        a: impl FnOnce() -> A + Send,
        b: impl FnOnce() -> B + Send,
    ) -> (A, B) {
        match self {
            Threads::One => (a(), b()),
            #[cfg(feature = "parallel")]
            Threads::Rayon => rayon::join(a, b),
        }
    }
}

/// `out = K v`, where K = −∂f/∂p is the tangent stiffness of the elastic forces at `p`
/// (the rank-2 completion's dependence on p is left out, as in the force), `prestress`'s
/// constant `dF S₀` included.
#[allow(clippy::too_many_arguments)]
pub fn stiffness_product(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    prestress: Option<&Prestress>,
    p: &[Vec3],
    v: &[Vec3],
    out: &mut [Vec3],
) {
    for o in out.iter_mut() {
        *o = Vec3::zeros();
    }
    for i in 0..op.len() {
        let term = op.point(i);
        if let PointRank::Orphan = term.rank {
            continue;
        }
        let ids = op.neighbours(i);
        let (pi, vi) = (p[i], v[i]);
        let mut b = Mat3::zeros();
        let mut db = Mat3::zeros();
        for (j, pair) in ids.iter().zip(op.pair_terms(i)) {
            let j = *j as usize;
            b += (p[j] - pi) * pair.wx.transpose();
            db += (v[j] - vi) * pair.wx.transpose();
        }
        let fp = b * term.a_pinv;
        let dfp = db * term.a_pinv;
        let full = complete(fp, &term.rank);
        let vol = volumes[i];
        let k = hourglass_stiffness(params, vol, term.trace_a);
        let mut dp = stress_differential(params, &full, &dfp);
        if let Some(s0) = prestress.and_then(|pre| pre.stress_of(i)) {
            dp += dfp * s0;
        }
        let dm = dp * (-vol) * term.a_pinv + dfp * k;
        let mut acc = Vec3::zeros();
        for (j, pair) in ids.iter().zip(op.pair_terms(i)) {
            let j = *j as usize;
            let dg = dm * pair.wx - (v[j] - vi) * (k * pair.w);
            // K v = −δf.
            out[j] -= dg;
            acc += dg;
        }
        out[i] += acc;
    }
}

#[cfg(test)]
pub(crate) mod tests;
