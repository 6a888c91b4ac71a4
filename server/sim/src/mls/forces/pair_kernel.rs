//! The pair kernel: forces of the points the stencil does not take (points a cut changed,
//! virtual points, planar and orphan points), one point or a run of four at a time.

use super::*;

/// The single points of one part: a range of indices, or a slice of the evaluation set.
pub(crate) enum Points<'a> {
    Range(std::ops::Range<usize>),
    Listed(&'a [u32]),
}

/// What both parts read.
pub(crate) struct Shared<'a> {
    pub(crate) op: &'a MlsOperator,
    pub(crate) params: &'a ElasticParams,
    pub(crate) volumes: &'a [f64],
    pub(crate) prestress: Option<&'a [Sym]>,
    pub(crate) pos: [&'a [f64]; 3],
    pub(crate) pos4: &'a [f64x4],
    /// The points the single-point kernel leaves to another.
    pub(crate) skip: Skip<'a>,
}

/// Which points the single-point kernel leaves out.
#[derive(Clone, Copy)]
pub(crate) enum Skip<'a> {
    /// Those the operator's runs cover.
    OperatorRuns,
    /// Those an evaluation set's runs cover.
    InRuns(&'a [bool]),
    /// Those the lattice stencil evaluates.
    Stencil(&'a [bool]),
}

impl Shared<'_> {
    /// Evaluates `runs` and the single points of `points` that no run covers into `out`.
    // Inlined into the caller's module, as when the kernels shared one file: without it
    // the evaluation measured 3 % slower (docs/ARCHITECTURE.md, "Decisions").
    #[inline]
    pub(crate) fn part(
        &self,
        runs: &[u32],
        points: Points<'_>,
        out: &mut PartForces,
    ) -> ForceStats {
        let mut stats = ForceStats::EMPTY;
        let mut lanes = RunBuffers::default();
        for &i in runs {
            run_kernel(
                self.op,
                self.params,
                self.volumes,
                self.prestress,
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
                    self.prestress,
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
pub(crate) fn point_kernel(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    prestress: Option<&[Sym]>,
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
    // P, and F's columns as the stress saw it (completed where the rank asks for it).
    let (mut pc, fcols) = match fast {
        Some((pc, psi, check)) => {
            stats.add_point(v * psi, hourglass, check);
            (pc, fpc)
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
            let column = |m: &Mat3, c: usize| f64x4::from([m[(0, c)], m[(1, c)], m[(2, c)], 0.0]);
            (
                std::array::from_fn(|c| column(&st.p, c)),
                std::array::from_fn(|c| column(&full, c)),
            )
        }
    };
    if let Some(field) = prestress {
        stats.prestress_energy += v * prestress::add_to_columns(field, i, &fcols, &mut pc);
    }
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
pub(crate) const BUFFERED: usize = 64;

/// Offsets of a run, one vector of four lanes per component and slot.
pub(crate) struct RunBuffers {
    pub(crate) u: [[f64x4; 3]; MAX_RUN_ROW],
}

impl Default for RunBuffers {
    fn default() -> Self {
        Self {
            u: [[f64x4::ZERO; 3]; MAX_RUN_ROW],
        }
    }
}

#[inline]
pub(crate) fn load4(values: &[f64], at: usize) -> f64x4 {
    let chunk: [f64; 4] = values[at..at + 4].try_into().expect("a run has four lanes");
    f64x4::from(chunk)
}

#[inline]
pub(crate) fn add4(values: &mut [f64], at: usize, v: f64x4) {
    let sum = load4(values, at) + v;
    values[at..at + 4].copy_from_slice(&sum.to_array());
}

/// The four points `i..i+4` of a run as SIMD lanes: they share one row (same `w x`, `w`, A⁺,
/// tr A) and their neighbours in each slot are consecutive, so every load and store of
/// positions and forces is a contiguous vector.
#[allow(clippy::too_many_arguments)]
#[inline]
pub(crate) fn run_kernel(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    prestress: Option<&[Sym]>,
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
    let (mut p_stress, psi, checks) = match lane_stvk(params, &fp) {
        Some(stressed) => stressed,
        None => lane_stress_scalar(params, &fp),
    };
    if let Some(s0) =
        prestress.and_then(|f| prestress::gather(f, std::array::from_fn(|l| Some(i + l))))
    {
        let e = (prestress::add_to_lanes(&fp, &s0, &mut p_stress) * volume).to_array();
        stats.prestress_energy += e.iter().sum::<f64>();
    }
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
