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

use crate::math::{Mat3, Vec3};
use wide::f64x4;

use crate::mls::material::{
    DET_RANGE, ElasticModel, ElasticParams, StressSample, stress, stress_differential,
};
use crate::mls::operator::{LANES, MAX_RUN_ROW, MlsOperator, PointRank, complete};
use crate::mls::stencil::LatticeStencil;
use crate::mls::stencil_kernel::{self, Restriction, StencilFields, StencilInputs};

/// Figures from one force evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceStats {
    /// Strain energy Σ V_i ψ(F_i) (J).
    pub strain_energy: f64,
    /// Hourglass energy (J).
    pub hourglass_energy: f64,
    /// Smallest det F over points with stress.
    pub min_det_f: f64,
    /// Largest det F.
    pub max_det_f: f64,
    /// Points whose F was clamped (det F outside [0.2, 5]).
    pub clamped_points: u32,
    /// False if any F was not finite.
    pub finite: bool,
}

impl ForceStats {
    /// Nothing evaluated yet.
    pub const EMPTY: Self = Self {
        strain_energy: 0.0,
        hourglass_energy: 0.0,
        min_det_f: f64::INFINITY,
        max_det_f: f64::NEG_INFINITY,
        clamped_points: 0,
        finite: true,
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
    }

    /// The figures of two disjoint sets of points together (`self` first in the sums).
    pub fn merge(&self, other: &Self) -> Self {
        Self {
            strain_energy: self.strain_energy + other.strain_energy,
            hourglass_energy: self.hourglass_energy + other.hourglass_energy,
            min_det_f: self.min_det_f.min(other.min_det_f),
            max_det_f: self.max_det_f.max(other.max_det_f),
            clamped_points: self.clamped_points + other.clamped_points,
            finite: self.finite && other.finite,
        }
    }

    /// Total elastic energy (J).
    pub fn energy(&self) -> f64 {
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
}

impl PointCheck {
    fn of(s: &StressSample) -> Self {
        Self {
            det: s.det,
            clamped: s.clamped,
            finite: s.det.is_finite() && s.p.iter().all(|x| x.is_finite()),
        }
    }

    /// Plain StVK inside the ordinary det F range (so finite, not clamped).
    pub(crate) fn plain(det: f64) -> Self {
        Self {
            det,
            clamped: false,
            finite: det.is_finite(),
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

/// Which points a force evaluation covers, so that its cost follows the active region and
/// not the body. Points outside `stress` carry no stress of their own (they are frozen
/// neighbours); forces land on `touched` = stress ∪ their neighbours, and are whole on the
/// `active` points the set was made for (the ones that are integrated). The lattice
/// stencil gathers only there: the other touched points get just what the pair kernels
/// scatter onto them, which nothing reads (a frozen point does not move).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EvalSet {
    /// The points the set was made for, sorted: their forces are whole.
    pub active: Vec<u32>,
    /// Points whose stress is evaluated, sorted.
    pub stress: Vec<u32>,
    /// Points that can receive force, sorted.
    pub touched: Vec<u32>,
    /// Runs of the operator whose four lanes are all in `stress`.
    pub runs: Vec<u32>,
    /// Per point: handled by one of `runs`.
    in_runs: Vec<bool>,
    in_stress: Vec<bool>,
    in_touched: Vec<bool>,
    /// Where the operator has a lattice stencil (and the set may use it): the box chunks
    /// holding a point of `stress` (the stencil's first pass) and of `active` (its second),
    /// sorted.
    stencil_chunks: Option<StencilChunks>,
}

/// The box chunks an evaluation set's stencil passes cover, and what it leaves to the pair
/// kernels.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct StencilChunks {
    /// Chunks holding a point of `stress`.
    pub stress: Vec<u32>,
    /// Chunks holding an active point (where the second pass gathers forces).
    pub active: Vec<u32>,
    /// Per box chunk: 1 when listed in `stress`, 2 in `active` (bits).
    flags: Vec<u8>,
    /// The points of `stress` the stencil does not evaluate, for the pair kernels.
    pub pairs: PairLists,
}

impl StencilChunks {
    /// The lists for `set` on `stencil`, reusing the buffers.
    fn rebuild(
        &mut self,
        op: &MlsOperator,
        stencil: &LatticeStencil,
        stress: &[u32],
        active: &[u32],
    ) {
        let chunks = stencil.chunks();
        if self.flags.len() != chunks {
            self.flags = vec![0; chunks];
            // Room for every chunk up front (no growth on the real-time path).
            self.stress = Vec::with_capacity(chunks);
            self.active = Vec::with_capacity(chunks);
        }
        self.pairs
            .fill(op, stencil.evaluated(), stress.iter().copied());
        for &c in self.stress.iter().chain(&self.active) {
            self.flags[c as usize] = 0;
        }
        self.stress.clear();
        self.active.clear();
        let sites = stencil.site_of();
        for (points, bit, list) in [
            (stress, 1u8, &mut self.stress),
            (active, 2, &mut self.active),
        ] {
            for &i in points {
                let Some(&site) = sites.get(i as usize) else {
                    continue;
                };
                let c = site as usize / LANES;
                if self.flags[c] & bit == 0 {
                    self.flags[c] |= bit;
                    list.push(c as u32);
                }
            }
            list.sort_unstable();
        }
    }
}

impl EvalSet {
    /// The set for integrating `active` points: their stress and that of their neighbours
    /// (which pushes on them) is evaluated.
    pub fn for_active(op: &MlsOperator, active: &[u32]) -> Self {
        let mut set = Self::default();
        set.rebuild(op, active, true);
        set
    }

    /// Like [`EvalSet::for_active`] but never using the SIMD runs or the lattice stencil
    /// (the single-point kernel only).
    pub fn scalar_only(op: &MlsOperator, active: &[u32]) -> Self {
        let mut set = Self::default();
        set.rebuild(op, active, false);
        set
    }

    /// Recomputes the set in place (reusing its buffers); the work is proportional to the
    /// set, not to the body.
    pub fn rebuild(&mut self, op: &MlsOperator, active: &[u32], use_runs: bool) {
        let n = op.len();
        if self.in_stress.len() != n {
            self.in_stress = vec![false; n];
            self.in_runs = vec![false; n];
            self.in_touched = vec![false; n];
            self.active.clear();
            self.stress.clear();
            self.touched.clear();
            self.runs.clear();
            // Room for the whole body up front: an active region that grows while cutting
            // must not grow these on the real-time path.
            self.active.reserve(n);
            self.stress.reserve(n);
            self.touched.reserve(n);
            self.runs.reserve(n / LANES + 1);
        }
        // Clear only what the previous set marked.
        for &i in &self.stress {
            self.in_stress[i as usize] = false;
            self.in_runs[i as usize] = false;
        }
        for &i in &self.touched {
            self.in_touched[i as usize] = false;
        }
        self.stress.clear();
        self.touched.clear();
        self.runs.clear();
        self.active.clear();
        self.active.extend_from_slice(active);
        self.active.sort_unstable();
        self.active.dedup();
        let mark = |i: u32, list: &mut Vec<u32>, flags: &mut Vec<bool>| {
            if !std::mem::replace(&mut flags[i as usize], true) {
                list.push(i);
            }
        };
        for &i in active {
            mark(i, &mut self.stress, &mut self.in_stress);
            for &j in op.neighbours(i as usize) {
                mark(j, &mut self.stress, &mut self.in_stress);
            }
        }
        self.stress.sort_unstable();
        for &i in &self.stress {
            mark(i, &mut self.touched, &mut self.in_touched);
            for &j in op.neighbours(i as usize) {
                mark(j, &mut self.touched, &mut self.in_touched);
            }
        }
        self.touched.sort_unstable();
        match op.stencil() {
            Some(stencil) if use_runs => self
                .stencil_chunks
                .get_or_insert_with(StencilChunks::default)
                .rebuild(op, stencil, &self.stress, &self.active),
            _ => self.stencil_chunks = None,
        }
        if use_runs {
            for &i in &self.stress {
                let i = i as usize;
                if !op.in_run(i) || op.run_start(i) != i {
                    continue;
                }
                if (i..i + LANES).all(|q| self.in_stress[q]) {
                    self.runs.push(i as u32);
                    self.in_runs[i..i + LANES]
                        .iter_mut()
                        .for_each(|x| *x = true);
                }
            }
        }
    }

    /// Whether point i's stress is evaluated.
    pub fn has_stress(&self, i: usize) -> bool {
        self.in_stress[i]
    }

    /// The stencil's chunks for this set, when it may use the stencil.
    pub(crate) fn stencil_chunks(&self) -> Option<&StencilChunks> {
        self.stencil_chunks.as_ref()
    }
}

/// Adds the elastic forces at positions `p` to `f` (N): of every point, or, with `set`, of
/// the points in `set.stress` (forces then land only on `set.touched`, and are whole on
/// `set.active`).
///
/// Runs of four interior points with identical stencils go through a 4-lane SIMD kernel
/// (contiguous loads, shared rows); every other point through the single-point kernel.
/// The work is split in two fixed parts ([`PARTS`]), on one thread or two ([`Threads`]),
/// with the same bits either way.
pub fn add_elastic_forces(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
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
    let stencil_stats = stencil.map(|stencil| {
        let inputs = StencilInputs {
            stencil,
            params,
            volumes,
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
    scratch.pair_work = work;
    let pair_stats = stats_a.merge(&stats_b);
    match (stencil, stencil_stats) {
        (Some(stencil), Some(stats)) => {
            // The stencil's gathered forces: the sites of the points whose forces are whole
            // (all, or the set's active points) are written by each evaluation, so nothing
            // needs clearing.
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
            stats.merge(&pair_stats)
        }
        _ => pair_stats,
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

/// The single points of one part: a range of indices, or a slice of the evaluation set.
enum Points<'a> {
    Range(std::ops::Range<usize>),
    Listed(&'a [u32]),
}

/// What both parts read.
struct Shared<'a> {
    op: &'a MlsOperator,
    params: &'a ElasticParams,
    volumes: &'a [f64],
    pos: [&'a [f64]; 3],
    pos4: &'a [f64x4],
    /// The points the single-point kernel leaves to another.
    skip: Skip<'a>,
}

/// Which points the single-point kernel leaves out.
#[derive(Clone, Copy)]
enum Skip<'a> {
    /// Those the operator's runs cover.
    OperatorRuns,
    /// Those an evaluation set's runs cover.
    InRuns(&'a [bool]),
    /// Those the lattice stencil evaluates.
    Stencil(&'a [bool]),
}

impl Shared<'_> {
    /// Evaluates `runs` and the single points of `points` that no run covers into `out`.
    fn part(&self, runs: &[u32], points: Points<'_>, out: &mut PartForces) -> ForceStats {
        let mut stats = ForceStats::EMPTY;
        let mut lanes = RunBuffers::default();
        for &i in runs {
            run_kernel(
                self.op,
                self.params,
                self.volumes,
                self.pos,
                i as usize,
                &mut out.soa,
                &mut lanes,
                &mut stats,
            );
        }
        let mut offsets = [f64x4::ZERO; BUFFERED];
        let mut one = |i: usize| {
            let elsewhere = match self.skip {
                Skip::OperatorRuns => self.op.in_run(i),
                Skip::InRuns(flags) | Skip::Stencil(flags) => flags[i],
            };
            if !elsewhere {
                point_kernel(
                    self.op,
                    self.params,
                    self.volumes,
                    self.pos4,
                    i,
                    &mut out.lanes,
                    &mut offsets,
                    &mut stats,
                );
            }
        };
        match points {
            Points::Range(r) => r.for_each(&mut one),
            Points::Listed(list) => list.iter().for_each(|&i| one(i as usize)),
        }
        stats
    }
}

/// One point through the general kernel: its own row, any rank, any stress model. The three
/// components of a position, offset or force are the lanes of one vector (the fourth is 0).
#[allow(clippy::too_many_arguments)]
#[inline]
fn point_kernel(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    pos4: &[f64x4],
    i: usize,
    force4: &mut [f64x4],
    offsets: &mut [f64x4; BUFFERED],
    stats: &mut ForceStats,
) {
    let term = op.point(i);
    // Orphans have no stress of their own; nor do virtual points (no volume), whose
    // one-sided fits must not feed the statistics (det F, clamping) either.
    if matches!(term.rank, PointRank::Orphan) || volumes[i] == 0.0 {
        return;
    }
    let (ids, wx, w) = op.padded_row(i);
    let used = op.neighbours(i).len();
    let pi = pos4[i];
    // Pass 1: the columns of B = Σ u ⊗ (w x) and Σ w |u|² (lane-wise, summed after). Even
    // and odd slots accumulate separately: one chain of dependent FMAs over the row would
    // bound the loop by FMA latency, not throughput. Rows are padded to a multiple of four
    // with zero-weight slots naming i itself, so reading a pair of slots past `used` is safe.
    let pairs = used.div_ceil(2);
    let slot_terms = |k: usize| {
        (
            f64x4::splat(wx[0][k]),
            f64x4::splat(wx[1][k]),
            f64x4::splat(wx[2][k]),
            f64x4::splat(w[k]),
        )
    };
    let (mut b0, mut b1, mut b2, mut q) = (f64x4::ZERO, f64x4::ZERO, f64x4::ZERO, f64x4::ZERO);
    let (mut c0, mut c1, mut c2, mut r) = (f64x4::ZERO, f64x4::ZERO, f64x4::ZERO, f64x4::ZERO);
    for pair in 0..pairs {
        let (ka, kb) = (2 * pair, 2 * pair + 1);
        let ua = pos4[ids[ka] as usize] - pi;
        let ub = pos4[ids[kb] as usize] - pi;
        if kb < BUFFERED {
            offsets[ka] = ua;
            offsets[kb] = ub;
        }
        let (x, y, z, wa) = slot_terms(ka);
        b0 = ua.mul_add(x, b0);
        b1 = ua.mul_add(y, b1);
        b2 = ua.mul_add(z, b2);
        q = (ua * ua).mul_add(wa, q);
        let (x, y, z, wb) = slot_terms(kb);
        c0 = ub.mul_add(x, c0);
        c1 = ub.mul_add(y, c1);
        c2 = ub.mul_add(z, c2);
        r = (ub * ub).mul_add(wb, r);
    }
    let bcol = [b0 + c0, b1 + c1, b2 + c2];
    let sum_wuu = {
        let l = (q + r).to_array();
        l[0] + l[1] + l[2]
    };
    // The 3×3 algebra stays in column vectors: rebuilding matrices from scalar stores and
    // reading them back as vectors stalls on store forwarding (43 % of this kernel, perf).
    let a = &term.a_pinv;
    let times_a = |cols: &[f64x4; 3], c: usize| {
        cols[0].mul_add(
            f64x4::splat(a[(0, c)]),
            cols[1].mul_add(f64x4::splat(a[(1, c)]), cols[2] * f64x4::splat(a[(2, c)])),
        )
    };
    let fpc: [f64x4; 3] = std::array::from_fn(|c| times_a(&bcol, c));
    let v = volumes[i];
    let k = hourglass_stiffness(params, v, term.trace_a);
    let fpb = {
        let l = fpc[0]
            .mul_add(bcol[0], fpc[1].mul_add(bcol[1], fpc[2] * bcol[2]))
            .to_array();
        l[0] + l[1] + l[2]
    };
    let hourglass = 0.5 * k * (sum_wuu - fpb);
    let fast = match term.rank {
        PointRank::Full => point_stvk(params, &fpc),
        _ => None,
    };
    let pc = match fast {
        Some((pc, psi, det)) => {
            stats.add_point(v * psi, hourglass, PointCheck::plain(det));
            pc
        }
        None => {
            // Planar completion, other models, the clamp fallback: the general code.
            let cols = fpc.map(|c| c.to_array());
            let fp = Mat3::from_fn(|row, c| cols[c][row]);
            let full = match term.rank {
                PointRank::Full => fp,
                _ => complete(fp, &term.rank),
            };
            let st = stress(params, &full);
            stats.add_point(v * st.psi, hourglass, PointCheck::of(&st));
            std::array::from_fn(|c| f64x4::from([st.p[(0, c)], st.p[(1, c)], st.p[(2, c)], 0.0]))
        }
    };
    // Pass 2: M = −V P A⁺ + k F_p; g_ij = M (w x) − k w u onto the neighbours, −Σ g onto i.
    let neg_v = f64x4::splat(-v);
    let kk = f64x4::splat(k);
    let mc: [f64x4; 3] = std::array::from_fn(|c| neg_v.mul_add(times_a(&pc, c), kk * fpc[c]));
    let kw = |slot: usize| f64x4::splat(-k * w[slot]);
    let pair_force = |slot: usize, u: f64x4| {
        let t = mc[2] * f64x4::splat(wx[2][slot]);
        let t = mc[1].mul_add(f64x4::splat(wx[1][slot]), t);
        let t = mc[0].mul_add(f64x4::splat(wx[0][slot]), t);
        kw(slot).mul_add(u, t)
    };
    let offset = |slot: usize| {
        if slot < BUFFERED {
            offsets[slot]
        } else {
            pos4[ids[slot] as usize] - pi
        }
    };
    let (mut acc_a, mut acc_b) = (f64x4::ZERO, f64x4::ZERO);
    for pair in 0..pairs {
        let (ka, kb) = (2 * pair, 2 * pair + 1);
        let ga = pair_force(ka, offset(ka));
        let gb = pair_force(kb, offset(kb));
        force4[ids[ka] as usize] += ga;
        force4[ids[kb] as usize] += gb;
        acc_a += ga;
        acc_b += gb;
    }
    force4[i] -= acc_a + acc_b;
}

/// Offsets `u_ij = p_j − p_i` kept between the two passes over a row; rows longer than
/// this (support ratios above ~3) are recomputed in the second pass instead.
const BUFFERED: usize = 64;

/// Offsets of a run, one vector of four lanes per component and slot.
struct RunBuffers {
    u: [[f64x4; 3]; MAX_RUN_ROW],
}

impl Default for RunBuffers {
    fn default() -> Self {
        Self {
            u: [[f64x4::ZERO; 3]; MAX_RUN_ROW],
        }
    }
}

#[inline]
fn load4(values: &[f64], at: usize) -> f64x4 {
    let chunk: [f64; 4] = values[at..at + 4].try_into().expect("a run has four lanes");
    f64x4::from(chunk)
}

#[inline]
fn add4(values: &mut [f64], at: usize, v: f64x4) {
    let sum = load4(values, at) + v;
    values[at..at + 4].copy_from_slice(&sum.to_array());
}

/// The four points `i..i+4` of a run as SIMD lanes: they share one row (same `w x`, `w`, A⁺,
/// tr A) and their neighbours in each slot are consecutive, so every load and store of
/// positions and forces is a contiguous vector.
#[allow(clippy::too_many_arguments)]
fn run_kernel(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    pos: [&[f64]; 3],
    i: usize,
    force: &mut [Vec<f64>; 3],
    lanes: &mut RunBuffers,
    stats: &mut ForceStats,
) {
    let term = op.point(i);
    let (ids, wx, w) = op.padded_row(i);
    let used = op.neighbours(i).len();
    let pi = [load4(pos[0], i), load4(pos[1], i), load4(pos[2], i)];
    // Pass 1a: the offsets u = p_j − p_i of the row, and Σ w |u|².
    let (wx, w) = (&wx.map(|c| &c[..used]), &w[..used]);
    let mut wuu = f64x4::ZERO;
    for (slot, &j) in ids[..used].iter().enumerate() {
        let j = j as usize;
        let u = [
            load4(pos[0], j) - pi[0],
            load4(pos[1], j) - pi[1],
            load4(pos[2], j) - pi[2],
        ];
        lanes.u[slot] = u;
        wuu = f64x4::splat(w[slot]).mul_add(u[0] * u[0] + u[1] * u[1] + u[2] * u[2], wuu);
    }
    // Pass 1b: B = Σ u ⊗ (w x) from the stored offsets. A separate loop: nine accumulators,
    // three offsets and a broadcast fill the sixteen vector registers, and with the run's
    // position as well an accumulator spilled and its FMA chain went through memory (up to
    // a quarter of the kernel, perf).
    let mut b = [[f64x4::ZERO; 3]; 3];
    for (slot, u) in lanes.u[..used].iter().enumerate() {
        for c in 0..3 {
            let x = f64x4::splat(wx[c][slot]);
            for r in 0..3 {
                b[r][c] = u[r].mul_add(x, b[r][c]);
            }
        }
    }
    // F_p = B A⁺ per lane.
    let a = &term.a_pinv;
    let mut fp = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            fp[r][c] = b[r][0].mul_add(
                f64x4::splat(a[(0, c)]),
                b[r][1].mul_add(f64x4::splat(a[(1, c)]), b[r][2] * f64x4::splat(a[(2, c)])),
            );
        }
    }
    let volume = load4(volumes, i);
    let k = f64x4::splat(params.hourglass_alpha * params.effective_youngs_modulus() / term.trace_a)
        * volume;
    // Stress: vectorised StVK when every lane is in the ordinary range, else per lane.
    let (p_stress, psi, checks) = match lane_stvk(params, &fp) {
        Some((p, psi, det)) => (p, psi, det.to_array().map(PointCheck::plain)),
        None => lane_stress_scalar(params, &fp),
    };
    let strain = (psi * volume).to_array();
    // Hourglass energy ½ k (Σ w|u|² − F_p : B).
    let mut fpb = f64x4::ZERO;
    for r in 0..3 {
        for c in 0..3 {
            fpb = fp[r][c].mul_add(b[r][c], fpb);
        }
    }
    let hourglass = (f64x4::splat(0.5) * k * (wuu - fpb)).to_array();
    for lane in 0..LANES {
        stats.add_point(strain[lane], hourglass[lane], checks[lane]);
    }
    // M = −V P A⁺ + k F_p.
    let neg_v = -volume;
    let mut m = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            let pa = p_stress[r][0].mul_add(
                f64x4::splat(a[(0, c)]),
                p_stress[r][1].mul_add(
                    f64x4::splat(a[(1, c)]),
                    p_stress[r][2] * f64x4::splat(a[(2, c)]),
                ),
            );
            m[r][c] = neg_v.mul_add(pa, k * fp[r][c]);
        }
    }
    // Pass 2: g = M (w x) − k w u onto the neighbours, −Σ g onto the run.
    let neg_k = -k;
    let mut acc = [f64x4::ZERO; 3];
    for (slot, &j) in ids[..used].iter().enumerate() {
        let j = j as usize;
        let u = lanes.u[slot];
        let x = [
            f64x4::splat(wx[0][slot]),
            f64x4::splat(wx[1][slot]),
            f64x4::splat(wx[2][slot]),
        ];
        let kw = neg_k * f64x4::splat(w[slot]);
        for r in 0..3 {
            let g = kw.mul_add(
                u[r],
                m[r][0].mul_add(x[0], m[r][1].mul_add(x[1], m[r][2] * x[2])),
            );
            acc[r] -= g;
            add4(&mut force[r], j, g);
        }
    }
    for r in 0..3 {
        add4(&mut force[r], i, acc[r]);
    }
}

/// StVK for one point whose F is given as column vectors (x, y, z, 0): P as column
/// vectors, ψ and det F; `None` when the model is not plain StVK or det F needs the clamp.
#[inline]
fn point_stvk(params: &ElasticParams, fc: &[f64x4; 3]) -> Option<([f64x4; 3], f64, f64)> {
    if params.model != ElasticModel::StVK || params.volume_k != 0.0 {
        return None;
    }
    // f[c][r] = F[r][c].
    let f = fc.map(|c| c.to_array());
    let det = f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1])
        - f[1][0] * (f[0][1] * f[2][2] - f[0][2] * f[2][1])
        + f[2][0] * (f[0][1] * f[1][2] - f[0][2] * f[1][1]);
    let (lo, hi) = DET_RANGE;
    if !(det >= lo && det <= hi) {
        return None;
    }
    // E = ½ (FᵀF − I): entries are dot products of columns.
    let dot = |a: usize, b: usize| f[a][0] * f[b][0] + f[a][1] * f[b][1] + f[a][2] * f[b][2];
    let mut e = [[0.0f64; 3]; 3];
    for r in 0..3 {
        for c in r..3 {
            let v = 0.5 * (dot(r, c) - if r == c { 1.0 } else { 0.0 });
            e[r][c] = v;
            e[c][r] = v;
        }
    }
    let tr = e[0][0] + e[1][1] + e[2][2];
    let (lambda, mu) = (params.lame.lambda, params.lame.mu);
    let ee: f64 = e.iter().flatten().map(|x| x * x).sum();
    let psi = mu * ee + 0.5 * lambda * tr * tr;
    let sm = |r: usize, c: usize| 2.0 * mu * e[r][c] + if r == c { lambda * tr } else { 0.0 };
    // P = F S, column by column: P[:, c] = Σ_k F[:, k] S[k][c].
    let pc = std::array::from_fn(|c| {
        fc[0].mul_add(
            f64x4::splat(sm(0, c)),
            fc[1].mul_add(f64x4::splat(sm(1, c)), fc[2] * f64x4::splat(sm(2, c))),
        )
    });
    Some((pc, psi, det))
}

/// StVK stress and energy density for four lanes, or `None` when the model is not plain
/// StVK or some lane needs the clamp fallback.
#[inline]
pub(crate) fn lane_stvk(
    params: &ElasticParams,
    f: &[[f64x4; 3]; 3],
) -> Option<([[f64x4; 3]; 3], f64x4, f64x4)> {
    if params.model != ElasticModel::StVK || params.volume_k != 0.0 {
        return None;
    }
    let det = f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1])
        - f[0][1] * (f[1][0] * f[2][2] - f[1][2] * f[2][0])
        + f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0]);
    let (lo, hi) = DET_RANGE;
    if det.to_array().iter().any(|d| !(*d >= lo && *d <= hi)) {
        return None;
    }
    // E = ½ (FᵀF − I), symmetric.
    let half = f64x4::splat(0.5);
    let mut e = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in r..3 {
            let cc = f[0][r].mul_add(f[0][c], f[1][r].mul_add(f[1][c], f[2][r] * f[2][c]));
            let v = if r == c {
                (cc - f64x4::ONE) * half
            } else {
                cc * half
            };
            e[r][c] = v;
            e[c][r] = v;
        }
    }
    let tr = e[0][0] + e[1][1] + e[2][2];
    let lambda = f64x4::splat(params.lame.lambda);
    let two_mu = f64x4::splat(2.0 * params.lame.mu);
    let mut sm = [[f64x4::ZERO; 3]; 3];
    let mut ee = f64x4::ZERO;
    for r in 0..3 {
        for c in 0..3 {
            sm[r][c] = two_mu * e[r][c] + if r == c { lambda * tr } else { f64x4::ZERO };
            ee = e[r][c].mul_add(e[r][c], ee);
        }
    }
    let psi = f64x4::splat(params.lame.mu) * ee + half * lambda * tr * tr;
    let mut p = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            p[r][c] = f[r][0].mul_add(sm[0][c], f[r][1].mul_add(sm[1][c], f[r][2] * sm[2][c]));
        }
    }
    Some((p, psi, det))
}

/// Per-lane stress through the general (scalar) constitutive code.
pub(crate) fn lane_stress_scalar(
    params: &ElasticParams,
    f: &[[f64x4; 3]; 3],
) -> ([[f64x4; 3]; 3], f64x4, [PointCheck; LANES]) {
    let fa: [[[f64; 4]; 3]; 3] =
        std::array::from_fn(|r| std::array::from_fn(|c| f[r][c].to_array()));
    let samples: [_; LANES] =
        std::array::from_fn(|lane| stress(params, &Mat3::from_fn(|r, c| fa[r][c][lane])));
    (
        std::array::from_fn(|r| std::array::from_fn(|c| f64x4::from(samples.map(|s| s.p[(r, c)])))),
        f64x4::from(samples.map(|s| s.psi)),
        samples.map(|s| PointCheck::of(&s)),
    )
}

/// `out = K v`, where K = −∂f/∂p is the tangent stiffness of the elastic forces at `p`
/// (the rank-2 completion's dependence on p is left out, as in the force).
pub fn stiffness_product(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
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
        let dp = stress_differential(params, &full, &dfp);
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
mod tests {
    use super::*;
    use crate::mls::material::ElasticModel;
    use crate::model::{Kernel, Neighbourhoods, RestGrid};

    /// A jittered 4³ lattice with unit-ish volumes.
    fn cloud() -> (Vec<Vec3>, MlsOperator, Vec<f64>) {
        let s = 0.002;
        let mut rest = Vec::new();
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 33) as f64 / (1u64 << 31) as f64) - 0.5
        };
        for k in 0..4 {
            for j in 0..4 {
                for i in 0..4 {
                    rest.push(
                        Vec3::new(
                            i as f64 + 0.2 * rnd(),
                            j as f64 + 0.2 * rnd(),
                            k as f64 + 0.2 * rnd(),
                        ) * s,
                    );
                }
            }
        }
        let kernel = Kernel { support_m: 2.0 * s };
        let grid = RestGrid::build(&rest, kernel.support_m);
        let nb = Neighbourhoods::build(&rest, &grid, kernel.support_m, 0);
        let op = MlsOperator::build(&rest, &nb, &kernel, None);
        let volumes = vec![s * s * s; rest.len()];
        (rest, op, volumes)
    }

    fn deformed(rest: &[Vec3]) -> Vec<Vec3> {
        rest.iter()
            .enumerate()
            .map(|(i, x)| {
                let t = i as f64;
                x + Vec3::new((t * 0.7).sin(), (t * 1.3).cos(), (t * 0.37).sin()) * 2e-4
            })
            .collect()
    }

    fn energy(op: &MlsOperator, params: &ElasticParams, vol: &[f64], p: &[Vec3]) -> f64 {
        let mut f = vec![Vec3::zeros(); p.len()];
        add_elastic_forces(
            op,
            params,
            vol,
            p,
            None,
            &mut f,
            &mut ForceScratch::new(p.len()),
        )
        .energy()
    }

    /// f = −∂U/∂p to finite-difference accuracy, for each model, with hourglass and volume term.
    #[test]
    fn forces_are_the_negative_energy_gradient() {
        let (rest, op, vol) = cloud();
        let p = deformed(&rest);
        for model in [
            ElasticModel::StVK,
            ElasticModel::MuellerCompat,
            ElasticModel::Corotated,
        ] {
            let mut params = ElasticParams::stvk(5000.0, 0.45);
            params.model = model;
            params.volume_k = 3000.0;
            let mut f = vec![Vec3::zeros(); p.len()];
            add_elastic_forces(
                &op,
                &params,
                &vol,
                &p,
                None,
                &mut f,
                &mut ForceScratch::new(p.len()),
            );
            let scale = f.iter().map(|x| x.norm()).fold(0.0, f64::max);
            let h = 1e-8;
            for i in [0usize, 5, 21, 42, 63] {
                for a in 0..3 {
                    let mut pp = p.clone();
                    let mut pm = p.clone();
                    pp[i][a] += h;
                    pm[i][a] -= h;
                    let fd = -(energy(&op, &params, &vol, &pp) - energy(&op, &params, &vol, &pm))
                        / (2.0 * h);
                    assert!(
                        (fd - f[i][a]).abs() < 1e-6 * scale,
                        "{model:?} point {i} axis {a}: {fd} vs {}",
                        f[i][a]
                    );
                }
            }
        }
    }

    /// K v matches the finite-difference change of the forces (StVK, exact tangent).
    #[test]
    fn stiffness_product_matches_finite_differences() {
        let (rest, op, vol) = cloud();
        let p = deformed(&rest);
        let mut params = ElasticParams::stvk(5000.0, 0.45);
        params.volume_k = 1000.0;
        let dir: Vec<Vec3> = (0..p.len())
            .map(|i| Vec3::new((i as f64).cos(), (i as f64 * 2.1).sin(), 0.3))
            .collect();
        let mut kv = vec![Vec3::zeros(); p.len()];
        stiffness_product(&op, &params, &vol, &p, &dir, &mut kv);
        let h = 1e-7;
        let force_at = |s: f64| {
            let q: Vec<Vec3> = p.iter().zip(&dir).map(|(x, d)| x + d * s).collect();
            let mut f = vec![Vec3::zeros(); p.len()];
            add_elastic_forces(
                &op,
                &params,
                &vol,
                &q,
                None,
                &mut f,
                &mut ForceScratch::new(q.len()),
            );
            f
        };
        let (fp, fm) = (force_at(h), force_at(-h));
        let scale = kv.iter().map(|x| x.norm()).fold(0.0, f64::max);
        for i in 0..p.len() {
            let fd = -(fp[i] - fm[i]) / (2.0 * h);
            assert!((fd - kv[i]).norm() < 1e-5 * scale, "point {i}");
        }
    }

    #[test]
    fn momentum_is_conserved_exactly() {
        let (rest, op, vol) = cloud();
        let p = deformed(&rest);
        let params = ElasticParams::stvk(5000.0, 0.45);
        let mut f = vec![Vec3::zeros(); p.len()];
        add_elastic_forces(
            &op,
            &params,
            &vol,
            &p,
            None,
            &mut f,
            &mut ForceScratch::new(p.len()),
        );
        let scale: f64 = f.iter().map(|x| x.norm()).sum();
        let total: Vec3 = f.iter().sum();
        let torque: Vec3 = p.iter().zip(&f).map(|(x, g)| x.cross(g)).sum();
        let arm = p.iter().map(|x| x.norm()).fold(0.0, f64::max);
        assert!(total.norm() < 1e-13 * scale, "{total}");
        assert!(torque.norm() < 1e-13 * scale * arm, "{torque}");
    }

    /// The scratch's force buffers are clear after every evaluation (the merge clears what it
    /// reads): a full evaluation after one over an evaluation set gives the bits of a full
    /// evaluation with fresh buffers.
    #[test]
    fn scratch_buffers_are_clear_between_evaluations() {
        let (rest, op, vol) = cloud();
        let p = deformed(&rest);
        let params = ElasticParams::stvk(5000.0, 0.45);
        let evaluate = |set: Option<&EvalSet>, scratch: &mut ForceScratch| {
            let mut f = vec![Vec3::zeros(); p.len()];
            add_elastic_forces(&op, &params, &vol, &p, set, &mut f, scratch);
            f
        };
        let fresh = evaluate(None, &mut ForceScratch::new(p.len()));
        let some: Vec<u32> = (0..p.len() as u32).step_by(4).collect();
        let set = EvalSet::for_active(&op, &some);
        let mut scratch = ForceScratch::new(p.len());
        let partial = evaluate(Some(&set), &mut scratch);
        assert!(partial.iter().any(|f| f.norm() > 0.0));
        assert_eq!(evaluate(None, &mut scratch), fresh);
        assert_eq!(evaluate(None, &mut scratch), fresh);
    }

    /// The 4-lane run kernel agrees with the single-point kernel on a lattice body with many runs,
    /// for StVK and for a clamped state.
    #[test]
    fn run_kernel_matches_scalar_kernel() {
        use crate::mls::operator::LatticeOffsets;
        let n = 9;
        let s = 0.002;
        let mut rest = Vec::new();
        let mut coords = Vec::new();
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    rest.push(Vec3::new(i as f64, j as f64, k as f64) * s);
                    coords.push([i as u32, j as u32, k as u32]);
                }
            }
        }
        let kernel = Kernel { support_m: 2.0 * s };
        let grid = RestGrid::build(&rest, kernel.support_m);
        let nb = Neighbourhoods::build(&rest, &grid, kernel.support_m, 0);
        let lattice = LatticeOffsets { coords, spacing: s };
        let op = MlsOperator::build(&rest, &nb, &kernel, Some(lattice));
        assert!(op.runs().len() >= 40, "{} runs", op.runs().len());
        let volumes: Vec<f64> = (0..rest.len())
            .map(|i| s * s * s * (1.0 + 0.01 * (i % 7) as f64))
            .collect();
        let params = ElasticParams::stvk(5000.0, 0.45);
        let everyone: Vec<u32> = (0..rest.len() as u32).collect();
        let scalar = EvalSet::scalar_only(&op, &everyone);
        for amplitude in [1e-4, 2e-3] {
            // The larger displacement pushes some det F below 0.2 (clamp fallback lanes).
            let p: Vec<Vec3> = rest
                .iter()
                .enumerate()
                .map(|(i, x)| {
                    x + Vec3::new(
                        (i as f64).sin(),
                        (1.7 * i as f64).cos(),
                        (0.3 * i as f64).sin(),
                    ) * amplitude
                })
                .collect();
            let mut scratch = ForceScratch::new(p.len());
            let mut fast = vec![Vec3::zeros(); p.len()];
            let mut slow = vec![Vec3::zeros(); p.len()];
            let a = add_elastic_forces(&op, &params, &volumes, &p, None, &mut fast, &mut scratch);
            let b = add_elastic_forces(
                &op,
                &params,
                &volumes,
                &p,
                Some(&scalar),
                &mut slow,
                &mut scratch,
            );
            let scale = slow.iter().map(|x| x.norm()).fold(0.0, f64::max);
            for i in 0..p.len() {
                assert!(
                    (fast[i] - slow[i]).norm() < 1e-12 * scale,
                    "amplitude {amplitude}, point {i}"
                );
            }
            assert!((a.energy() - b.energy()).abs() < 1e-12 * b.energy());
            assert_eq!(a.clamped_points, b.clamped_points);
            assert!((a.min_det_f - b.min_det_f).abs() < 1e-12);
        }
    }
}
