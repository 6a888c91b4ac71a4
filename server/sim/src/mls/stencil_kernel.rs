//! The force kernel's fixed-stencil path: the points of the uncut lattice (`stencil`)
//! evaluated four box sites at a time from fields laid out over the box.
//!
//! Per evaluated point i, in displacements `u = p − X` (so that the sums do not carry the
//! points' absolute positions):
//!
//! ```text
//! B_i  = Σ_o w x(o) ⊗ u[i+o] − u_i ⊗ Σ w x      H = B_i A⁻¹,  F = I + H
//! S_i  = Σ_o w(o) u[i+o]                          Z_i = Σ_o w(o) |u[i+o]|²
//! M'_i = (k_i B_i − V_i P(F)) A⁻¹                  (= M_i − k_i I of `forces`)
//! ```
//!
//! and the pair force `g_ij = M'_i w x_ij − k_i w_ij (u_j − u_i)` (the same as `forces`' once
//! `p_j − p_i = u_j − u_i + x_ij` is put in) lands on j, −Σ_j g_ij on i. The first pass
//! writes `M'`, `k u` and `k` into box fields; the second gathers at every site the pair
//! forces of the stencil points around it:
//!
//! ```text
//! f_j = −Σ_o M'[j+o] w x(o) + Σ_o w(o) (k u)[j+o] − u_j Σ_o w(o) k[j+o] − Σ_i g_ji
//! ```
//!
//! (w x is odd in o, w even). Every sum over o is a sum over the block's rows of the
//! differences or sums of x neighbours, weighted by three class coefficients; empty sites
//! and points the stencil does not evaluate hold zeros, so they add nothing.
//!
//! The hourglass energy ½ k (Σ_j w |u_j − u_i|² − H : B) takes Σ_j w |u_j − u_i|² as
//! `Z − 2 u_i·S + |u_i|² Σ w`: its rounding is relative to |u|², a cost of the last digits
//! of an energy that only the divergence guard reads.

use wide::f64x4;

use super::forces::{ForceStats, PointCheck, Threads, lane_stress_scalar, lane_stvk};
use super::material::ElasticParams;
use super::operator::LANES;
use super::stencil::{LatticeStencil, NONE, QuadTerms};
use crate::math::Vec3;

/// Box fields of one evaluation, allocated once (at the first evaluation).
#[derive(Debug, Clone, Default)]
pub(crate) struct StencilFields {
    /// Displacements.
    u: [Vec<f64>; 3],
    /// |u|².
    z: Vec<f64>,
    /// M', entry (r, c) at 3r + c.
    m: [Vec<f64>; 9],
    /// k u.
    ku: [Vec<f64>; 3],
    /// Hourglass stiffness k.
    k: Vec<f64>,
    /// The forces: the first pass writes each point's reaction −Σ_j g_ij, the second adds
    /// the pair forces it gathers.
    pub(crate) f: [Vec<f64>; 3],
    /// Plane sums along a span, five fields' worth for each half of the quads.
    sums: [[PlaneSums; 5]; 2],
}

impl StencilFields {
    /// Sizes the fields for `stencil` (allocates only when the box changes).
    pub(crate) fn fit(&mut self, stencil: &LatticeStencil) {
        let sites = stencil.sites();
        if self.z.len() == sites {
            return;
        }
        let all = self
            .u
            .iter_mut()
            .chain(std::iter::once(&mut self.z))
            .chain(self.m.iter_mut())
            .chain(self.ku.iter_mut())
            .chain(std::iter::once(&mut self.k))
            .chain(self.f.iter_mut());
        for field in all {
            field.clear();
            field.resize(sites, 0.0);
        }
        let row = stencil.strides().0;
        self.sums.iter_mut().flatten().for_each(|s| s.fit(row));
    }

    /// Writes the displacements of the lattice points at `p` into the box.
    pub(crate) fn scatter(&mut self, stencil: &LatticeStencil, p: &[Vec3]) {
        for ((&site, x), pi) in stencil.site_of().iter().zip(stencil.rest()).zip(p) {
            let site = site as usize;
            let u = pi - x;
            for c in 0..3 {
                self.u[c][site] = u[c];
            }
            self.z[site] = u.norm_squared();
        }
    }
}

/// The three class coefficients as vectors.
#[derive(Clone, Copy)]
struct Coefficients {
    /// w of a face, edge and corner neighbour.
    w: [f64x4; 3],
    /// s·w of the same.
    cw: [f64x4; 3],
}

/// Sums over the yz-plane around each site of a span of quads, from x − 1 of the first
/// quad to x + 4 of the last (index 0 is x − 1). With them every stencil sum is a few
/// terms in x: for a face, edge and corner neighbour the yz-offset has 0, 1 or 2 non-zero
/// components, so
///
/// ```text
/// Σ_o (w x)_x v = cw₁ δv + cw₂ δP + cw₃ δQ                 δa = a[x+1] − a[x−1]
/// Σ_o (w x)_y v = cw₁ E_y + cw₂ (F_y + σE_y) + cw₃ σF_y    σa = a[x+1] + a[x−1]
/// Σ_o w v       = w₁ (P + σv) + w₂ (Q + σP) + w₃ σQ
/// ```
///
/// with P the sum of the four edge-sharing neighbours in the plane, Q of the four corners,
/// E_y = v[y+1] − v[y−1] and F_y the same difference one row up and down in z (E_z, F_z
/// likewise). About a quarter of the arithmetic of summing the 26 sites directly.
#[derive(Debug, Clone, Default)]
struct PlaneSums {
    p: Vec<f64>,
    q: Vec<f64>,
    ey: Vec<f64>,
    fy: Vec<f64>,
    ez: Vec<f64>,
    fz: Vec<f64>,
}

/// Which plane sums a field needs.
#[derive(Clone, Copy)]
struct Needs {
    /// P and Q (for x derivatives and weighted sums).
    pq: bool,
    /// E_y and F_y.
    y: bool,
    /// E_z and F_z.
    z: bool,
}

/// Four-site chunks.
type Chunks<'a> = &'a [[f64; LANES]];

/// The first `n` chunks of four sites of `flat`.
#[inline(always)]
fn chunks(flat: &[f64], n: usize) -> Chunks<'_> {
    &flat[..LANES * n].as_chunks::<LANES>().0[..n]
}

/// The same, writable.
#[inline(always)]
fn chunks_mut(flat: &mut [f64], n: usize) -> &mut [[f64; LANES]] {
    &mut flat[..LANES * n].as_chunks_mut::<LANES>().0[..n]
}

impl PlaneSums {
    /// Room for a span as long as a box row of `sites`.
    fn fit(&mut self, sites: usize) {
        for v in [
            &mut self.p,
            &mut self.q,
            &mut self.ey,
            &mut self.fy,
            &mut self.ez,
            &mut self.fz,
        ] {
            v.clear();
            v.resize(sites + 2 * LANES, 0.0);
        }
    }

    /// The sums of `rows` (a field's nine rows along a span of `quads` quads), over
    /// `quads + 1` chunks from x − 1 of the first quad.
    #[inline(always)]
    fn fill(&mut self, rows: &SpanRows<'_>, quads: usize, needs: Needs) {
        let n = quads + 1;
        let r = &rows.rows;
        let (r00, r01, r02) = (chunks(r[0][0], n), chunks(r[0][1], n), chunks(r[0][2], n));
        let (r10, r12) = (chunks(r[1][0], n), chunks(r[1][2], n));
        let (r20, r21, r22) = (chunks(r[2][0], n), chunks(r[2][1], n), chunks(r[2][2], n));
        let v = f64x4::from;
        if needs.pq {
            let p = chunks_mut(&mut self.p, n);
            for i in 0..n {
                p[i] = ((v(r01[i]) + v(r21[i])) + (v(r10[i]) + v(r12[i]))).to_array();
            }
            let q = chunks_mut(&mut self.q, n);
            for i in 0..n {
                q[i] = ((v(r00[i]) + v(r20[i])) + (v(r02[i]) + v(r22[i]))).to_array();
            }
        }
        if needs.y {
            let e = chunks_mut(&mut self.ey, n);
            for i in 0..n {
                e[i] = (v(r21[i]) - v(r01[i])).to_array();
            }
            let f = chunks_mut(&mut self.fy, n);
            for i in 0..n {
                f[i] = ((v(r20[i]) - v(r00[i])) + (v(r22[i]) - v(r02[i]))).to_array();
            }
        }
        if needs.z {
            let e = chunks_mut(&mut self.ez, n);
            for i in 0..n {
                e[i] = (v(r12[i]) - v(r10[i])).to_array();
            }
            let f = chunks_mut(&mut self.fz, n);
            for i in 0..n {
                f[i] = ((v(r02[i]) - v(r00[i])) + (v(r22[i]) - v(r20[i]))).to_array();
            }
        }
    }
}

/// A buffer along a span (index 0 at x − 1 of the first quad) seen three times, one site
/// apart: quad q's lanes at x − 1, x and x + 1 are chunk q of each view.
#[derive(Clone, Copy)]
struct Shifted<'a> {
    minus: Chunks<'a>,
    centre: Chunks<'a>,
    plus: Chunks<'a>,
}

impl<'a> Shifted<'a> {
    /// The views of `flat` for `quads` quads.
    #[inline(always)]
    fn of(flat: &'a [f64], quads: usize) -> Self {
        Self {
            minus: chunks(flat, quads),
            centre: chunks(&flat[1..], quads),
            plus: chunks(&flat[2..], quads),
        }
    }

    #[inline(always)]
    fn at(&self, q: usize) -> (f64x4, f64x4, f64x4) {
        (
            f64x4::from(self.minus[q]),
            f64x4::from(self.centre[q]),
            f64x4::from(self.plus[q]),
        )
    }
}

/// Σ_o (w x)_x(o) v[i+o] at quad q, from the field's row and its P and Q.
#[inline(always)]
fn grad_x(k: &Coefficients, v: &Shifted<'_>, p: &Shifted<'_>, qq: &Shifted<'_>, q: usize) -> f64x4 {
    let (v0, _, v2) = v.at(q);
    let (p0, _, p2) = p.at(q);
    let (q0, _, q2) = qq.at(q);
    k.cw[0].mul_add(v2 - v0, k.cw[1].mul_add(p2 - p0, k.cw[2] * (q2 - q0)))
}

/// Σ_o (w x)_y(o) v[i+o] (or z) at quad q, from E and F of the field.
#[inline(always)]
fn grad_yz(k: &Coefficients, e: &Shifted<'_>, f: &Shifted<'_>, q: usize) -> f64x4 {
    let (e0, e1, e2) = e.at(q);
    let (f0, f1, f2) = f.at(q);
    k.cw[0].mul_add(e1, k.cw[1].mul_add(f1 + (e0 + e2), k.cw[2] * (f0 + f2)))
}

/// Σ_o w(o) v[i+o] (the centre left out) at quad q, from the field's row and its P and Q.
#[inline(always)]
fn weighted_sum(
    k: &Coefficients,
    v: &Shifted<'_>,
    p: &Shifted<'_>,
    qq: &Shifted<'_>,
    q: usize,
) -> f64x4 {
    let (v0, _, v2) = v.at(q);
    let (p0, p1, p2) = p.at(q);
    let (q0, q1, q2) = qq.at(q);
    k.w[0].mul_add(
        p1 + (v0 + v2),
        k.w[1].mul_add(q1 + (p0 + p2), k.w[2] * (q0 + q2)),
    )
}

/// A field's views along a span for x derivatives and weighted sums: its own row, P, Q.
struct PqViews<'a> {
    v: Shifted<'a>,
    p: Shifted<'a>,
    q: Shifted<'a>,
}

impl<'a> PqViews<'a> {
    #[inline(always)]
    fn of(rows: &SpanRows<'a>, sums: &'a PlaneSums, quads: usize) -> Self {
        Self {
            v: Shifted::of(rows.rows[1][1], quads),
            p: Shifted::of(&sums.p, quads),
            q: Shifted::of(&sums.q, quads),
        }
    }

    #[inline(always)]
    fn grad_x(&self, k: &Coefficients, q: usize) -> f64x4 {
        grad_x(k, &self.v, &self.p, &self.q, q)
    }

    #[inline(always)]
    fn weighted_sum(&self, k: &Coefficients, q: usize) -> f64x4 {
        weighted_sum(k, &self.v, &self.p, &self.q, q)
    }
}

/// A field's views along a span for a y (or z) derivative: E and F.
struct EfViews<'a> {
    e: Shifted<'a>,
    f: Shifted<'a>,
}

impl<'a> EfViews<'a> {
    #[inline(always)]
    fn y(sums: &'a PlaneSums, quads: usize) -> Self {
        Self {
            e: Shifted::of(&sums.ey, quads),
            f: Shifted::of(&sums.fy, quads),
        }
    }

    #[inline(always)]
    fn z(sums: &'a PlaneSums, quads: usize) -> Self {
        Self {
            e: Shifted::of(&sums.ez, quads),
            f: Shifted::of(&sums.fz, quads),
        }
    }

    #[inline(always)]
    fn grad(&self, k: &Coefficients, q: usize) -> f64x4 {
        grad_yz(k, &self.e, &self.f, q)
    }
}

/// One field's nine box rows along a span of quads, from x − 1 of the first quad, cut once
/// per span so that the quads' reads need no bounds checks of their own.
struct SpanRows<'a> {
    /// Indexed [y][z] with 0, 1, 2 for −1, 0, +1; `4 (quads + 2)` sites each.
    rows: [[&'a [f64]; 3]; 3],
}

impl<'a> SpanRows<'a> {
    /// The rows of `field` for `quads` quads whose block of rows starts at `starts`.
    #[inline(always)]
    fn of(field: &'a [f64], starts: &[[usize; 3]; 3], quads: usize) -> Self {
        let len = LANES * (quads + 2);
        let row = |y: usize, z: usize| -> &'a [f64] {
            let s = starts[y][z];
            &field[s..s + len]
        };
        Self {
            rows: [
                [row(0, 0), row(0, 1), row(0, 2)],
                [row(1, 0), row(1, 1), row(1, 2)],
                [row(2, 0), row(2, 1), row(2, 2)],
            ],
        }
    }
}

#[inline(always)]
fn store(field: &mut [f64], site: usize, v: f64x4) {
    field[site..site + LANES].copy_from_slice(&v.to_array());
}

/// Where a quad's block of rows starts in each field: `site − 1 + dy·sy + dz·sz`.
#[inline(always)]
fn block_starts(site: usize, sy: usize, sz: usize) -> [[usize; 3]; 3] {
    let o = site - 1 - sy - sz;
    [
        [o, o + sz, o + 2 * sz],
        [o + sy, o + sy + sz, o + sy + 2 * sz],
        [o + 2 * sy, o + 2 * sy + sz, o + 2 * sy + 2 * sz],
    ]
}

/// Runs `a` and `b`, one after the other or as a `rayon::join`.
fn both<A: Send, B: Send>(
    threads: Threads,
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    match threads {
        Threads::One => (a(), b()),
        Threads::Rayon => rayon::join(a, b),
    }
}

/// Each field cut at site `at`: the first parts, then the second.
fn split_each<const N: usize>(
    fields: &mut [Vec<f64>; N],
    at: usize,
) -> ([&mut [f64]; N], [&mut [f64]; N]) {
    let mut parts = fields.each_mut().map(|f| {
        let (a, b) = f.split_at_mut(at);
        (Some(a), Some(b))
    });
    let first = std::array::from_fn(|i| parts[i].0.take().expect("taken once"));
    let second = std::array::from_fn(|i| parts[i].1.take().expect("taken once"));
    (first, second)
}

/// Evaluates the stencil's points at positions `p`: their statistics (the first half of
/// the quads, then the second), and in `fields.f` the pair forces of their rows gathered at
/// every site. The halves run on one thread or two with the same bits.
pub(crate) fn evaluate(
    inputs: StencilInputs<'_>,
    p: &[Vec3],
    fields: &mut StencilFields,
    threads: Threads,
) -> (ForceStats, ForceStats) {
    let stencil = inputs.stencil;
    fields.fit(stencil);
    fields.scatter(stencil, p);
    let (quads, _) = stencil.quads();
    let half = quads.len() / 2;
    let split = quads.get(half).map_or(stencil.sites(), |&s| s as usize);
    let StencilFields {
        u,
        z,
        m,
        ku,
        k,
        f,
        sums,
    } = fields;
    let [sums_a, sums_b] = sums;
    let (mut f_a, mut f_b) = split_each(f, split);
    let stats = {
        let (m_a, m_b) = split_each(m, split);
        let (ku_a, ku_b) = split_each(ku, split);
        let (k_a, k_b) = k.split_at_mut(split);
        let read = PassOneIn { u, z };
        let mut a = PassOneOut {
            offset: 0,
            m: m_a,
            ku: ku_a,
            k: k_a,
            own: &mut f_a,
        };
        let mut b = PassOneOut {
            offset: split,
            m: m_b,
            ku: ku_b,
            k: k_b,
            own: &mut f_b,
        };
        both(
            threads,
            || pass_one(&inputs, 0..half, &read, sums_a, &mut a),
            || pass_one(&inputs, half..quads.len(), &read, sums_b, &mut b),
        )
    };
    let read = PassTwoIn { m, ku, k, u };
    let mut a = PassTwoOut {
        offset: 0,
        f: &mut f_a,
    };
    let mut b = PassTwoOut {
        offset: split,
        f: &mut f_b,
    };
    both(
        threads,
        || pass_two(&inputs, 0..half, &read, sums_a, &mut a),
        || pass_two(&inputs, half..quads.len(), &read, sums_b, &mut b),
    );
    stats
}

/// What the first pass reads.
struct PassOneIn<'a> {
    u: &'a [Vec<f64>; 3],
    z: &'a [f64],
}

/// The fields the first pass writes, for the sites from `offset` on.
struct PassOneOut<'a, 'b, 'f> {
    offset: usize,
    m: [&'a mut [f64]; 9],
    ku: [&'a mut [f64]; 3],
    k: &'a mut [f64],
    /// The forces, where each point's reaction goes.
    own: &'b mut [&'f mut [f64]; 3],
}

/// What the second pass reads.
struct PassTwoIn<'a> {
    m: &'a [Vec<f64>; 9],
    ku: &'a [Vec<f64>; 3],
    k: &'a [f64],
    u: &'a [Vec<f64>; 3],
}

/// The forces the second pass adds to, for the sites from `offset` on.
struct PassTwoOut<'a, 'b> {
    offset: usize,
    f: &'b mut [&'a mut [f64]; 3],
}

fn coefficients(stencil: &LatticeStencil) -> Coefficients {
    let (w, cw) = stencil.coefficients();
    Coefficients {
        w: w.map(f64x4::splat),
        cw: cw.map(f64x4::splat),
    }
}

/// The spans of quads within `range`, each as (first quad, count, site of the first).
fn spans_within(
    stencil: &LatticeStencil,
    range: std::ops::Range<usize>,
) -> impl Iterator<Item = (usize, usize, usize)> + '_ {
    let (quads, _) = stencil.quads();
    stencil.spans().iter().filter_map(move |&(first, count)| {
        let lo = (first as usize).max(range.start);
        let hi = (first as usize + count as usize).min(range.end);
        (lo < hi).then(|| (lo, hi - lo, quads[lo] as usize))
    })
}

/// Stress of the points of quads `range`: M', k u, k and the reaction −Σ g into the fields.
fn pass_one(
    inputs: &StencilInputs<'_>,
    range: std::ops::Range<usize>,
    read: &PassOneIn<'_>,
    sums: &mut [PlaneSums; 5],
    out: &mut PassOneOut<'_, '_, '_>,
) -> ForceStats {
    let stencil = inputs.stencil;
    let (sy, sz) = stencil.strides();
    let (_, terms) = stencil.quads();
    let coef = coefficients(stencil);
    let params = inputs.params;
    let alpha_e = f64x4::splat(params.hourglass_alpha * params.effective_youngs_modulus());
    let half = f64x4::splat(0.5);
    let mut stats = ForceStats::EMPTY;
    let all = Needs {
        pq: true,
        y: true,
        z: true,
    };
    let weighted = Needs {
        pq: true,
        y: false,
        z: false,
    };
    let [s0, s1, s2, s3, _] = sums;
    for (first, count, site0) in spans_within(stencil, range) {
        let starts = block_starts(site0, sy, sz);
        let u_rows = [
            SpanRows::of(&read.u[0], &starts, count),
            SpanRows::of(&read.u[1], &starts, count),
            SpanRows::of(&read.u[2], &starts, count),
        ];
        let z_rows = SpanRows::of(read.z, &starts, count);
        s0.fill(&u_rows[0], count, all);
        s1.fill(&u_rows[1], count, all);
        s2.fill(&u_rows[2], count, all);
        s3.fill(&z_rows, count, weighted);
        let views = [
            (
                PqViews::of(&u_rows[0], s0, count),
                EfViews::y(s0, count),
                EfViews::z(s0, count),
            ),
            (
                PqViews::of(&u_rows[1], s1, count),
                EfViews::y(s1, count),
                EfViews::z(s1, count),
            ),
            (
                PqViews::of(&u_rows[2], s2, count),
                EfViews::y(s2, count),
                EfViews::z(s2, count),
            ),
        ];
        let z_views = PqViews::of(&z_rows, s3, count);
        for q in 0..count {
            let t = &terms[first + q];
            let sum_wx = t.sum_wx;
            let mut b = [[f64x4::ZERO; 3]; 3];
            let mut sw = [f64x4::ZERO; 3];
            let mut uc = [f64x4::ZERO; 3];
            for r in 0..3 {
                let (pq, y, z) = &views[r];
                uc[r] = pq.v.at(q).1;
                let neg = -uc[r];
                b[r][0] = neg.mul_add(sum_wx[0], pq.grad_x(&coef, q));
                b[r][1] = neg.mul_add(sum_wx[1], y.grad(&coef, q));
                b[r][2] = neg.mul_add(sum_wx[2], z.grad(&coef, q));
                sw[r] = pq.weighted_sum(&coef, q);
            }
            let zs = z_views.weighted_sum(&coef, q);
            let point = QuadPoint {
                site: site0 + LANES * q - out.offset,
                b,
                sw,
                uc,
                zs,
            };
            point_stress(inputs, t, alpha_e, half, point, out, &mut stats);
        }
    }
    stats
}

/// One quad's sums from the first pass.
struct QuadPoint {
    /// Where the quad's lanes are in the output fields.
    site: usize,
    /// B = Σ w x ⊗ u − u_i ⊗ Σ w x.
    b: [[f64x4; 3]; 3],
    /// S = Σ w u_j.
    sw: [f64x4; 3],
    /// u_i.
    uc: [f64x4; 3],
    /// Z = Σ w |u_j|².
    zs: f64x4,
}

/// The stress of a quad's points from their sums, into the output fields and `stats`.
#[inline(always)]
fn point_stress(
    inputs: &StencilInputs<'_>,
    t: &QuadTerms,
    alpha_e: f64x4,
    half: f64x4,
    point: QuadPoint,
    out: &mut PassOneOut<'_, '_, '_>,
    stats: &mut ForceStats,
) {
    let QuadPoint {
        site,
        b,
        sw,
        uc,
        zs,
    } = point;
    let params = inputs.params;
    let a = &t.a_inv;
    let sum_wx = t.sum_wx;
    let times_a = |m: &[[f64x4; 3]; 3], r: usize, c: usize| {
        m[r][0].mul_add(a[c], m[r][1].mul_add(a[3 + c], m[r][2] * a[6 + c]))
    };
    let mut h = [[f64x4::ZERO; 3]; 3];
    let mut f = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            h[r][c] = times_a(&b, r, c);
            f[r][c] = if r == c {
                h[r][c] + f64x4::ONE
            } else {
                h[r][c]
            };
        }
    }
    let (p_stress, psi, checks) = match lane_stvk(params, &f) {
        Some((p, psi, det)) => (p, psi, det.to_array().map(PointCheck::plain)),
        None => lane_stress_scalar(params, &f),
    };
    let volume_of = |lane: usize| match t.point[lane] {
        NONE => 0.0,
        i => inputs.volumes[i as usize],
    };
    let volume = f64x4::from([volume_of(0), volume_of(1), volume_of(2), volume_of(3)]);
    let k = alpha_e * volume * t.inv_trace_a;
    // M' = (k B − V P) A⁻¹.
    let neg_v = -volume;
    let mut kb = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            kb[r][c] = neg_v.mul_add(p_stress[r][c], k * b[r][c]);
        }
    }
    let sum_w = t.sum_w;
    let mut hb = f64x4::ZERO;
    let mut us = f64x4::ZERO;
    for r in 0..3 {
        let mr = [times_a(&kb, r, 0), times_a(&kb, r, 1), times_a(&kb, r, 2)];
        for c in 0..3 {
            store(out.m[3 * r + c], site, mr[c]);
            hb = h[r][c].mul_add(b[r][c], hb);
        }
        // −Σ_j g_ij = −M' Σ w x + k (S − u_i Σ w).
        let reaction = mr[0].mul_add(sum_wx[0], mr[1].mul_add(sum_wx[1], mr[2] * sum_wx[2]));
        let own = k * (-uc[r]).mul_add(sum_w, sw[r]) - reaction;
        store(out.own[r], site, own);
        store(out.ku[r], site, k * uc[r]);
        us = uc[r].mul_add(uc[r].mul_add(sum_w, f64x4::splat(-2.0) * sw[r]), us);
    }
    store(out.k, site, k);
    let hourglass = (half * k * (zs + us - hb)).to_array();
    let strain = (psi * volume).to_array();
    for lane in 0..LANES {
        if t.evaluated[lane] {
            stats.add_point(strain[lane], hourglass[lane], checks[lane]);
        }
    }
}

/// Gathers at each site of quads `range` the pair forces of the stencil points around it.
fn pass_two(
    inputs: &StencilInputs<'_>,
    range: std::ops::Range<usize>,
    read: &PassTwoIn<'_>,
    sums: &mut [PlaneSums; 5],
    out: &mut PassTwoOut<'_, '_>,
) {
    let stencil = inputs.stencil;
    let (sy, sz) = stencil.strides();
    let coef = coefficients(stencil);
    let only = |pq: bool, y: bool, z: bool| Needs { pq, y, z };
    let [s0, s1, s2, s3, s4] = sums;
    for (_, count, site0) in spans_within(stencil, range) {
        let starts = block_starts(site0, sy, sz);
        let k_rows = SpanRows::of(read.k, &starts, count);
        s4.fill(&k_rows, count, only(true, false, false));
        let k = PqViews::of(&k_rows, s4, count);
        for r in 0..3 {
            let mx = SpanRows::of(&read.m[3 * r], &starts, count);
            let my = SpanRows::of(&read.m[3 * r + 1], &starts, count);
            let mz = SpanRows::of(&read.m[3 * r + 2], &starts, count);
            let ku = SpanRows::of(&read.ku[r], &starts, count);
            s0.fill(&mx, count, only(true, false, false));
            s1.fill(&my, count, only(false, true, false));
            s2.fill(&mz, count, only(false, false, true));
            s3.fill(&ku, count, only(true, false, false));
            let u = chunks(&read.u[r][site0..], count);
            let at = site0 - out.offset;
            let f = chunks_mut(&mut out.f[r][at..], count);
            let (x, y, z) = (
                PqViews::of(&mx, s0, count),
                EfViews::y(s1, count),
                EfViews::z(s2, count),
            );
            let h = PqViews::of(&ku, s3, count);
            for q in 0..count {
                let kw = k.weighted_sum(&coef, q);
                let stress = x.grad_x(&coef, q) + y.grad(&coef, q) + z.grad(&coef, q);
                let hourglass = h.weighted_sum(&coef, q);
                let uc = f64x4::from(u[q]);
                let sum = (-uc).mul_add(kw, hourglass) - stress + f64x4::from(f[q]);
                f[q] = sum.to_array();
            }
        }
    }
}

/// What the evaluation reads besides the fields.
#[derive(Clone, Copy)]
pub(crate) struct StencilInputs<'a> {
    /// The box and its terms.
    pub stencil: &'a LatticeStencil,
    /// Material.
    pub params: &'a ElasticParams,
    /// Rest volumes of the operator's points (m³).
    pub volumes: &'a [f64],
}

#[cfg(test)]
mod tests {
    use crate::math::Vec3;
    use crate::mls::forces::{ForceScratch, ForceStats, add_elastic_forces};
    use crate::mls::material::{ElasticModel, ElasticParams};
    use crate::mls::operator::{LatticeOffsets, MlsOperator};
    use crate::model::{Kernel, Neighbourhoods, RestGrid};

    const S: f64 = 0.002;

    /// A ball of lattice points, off the origin (every kind of missing neighbour on its
    /// rough boundary), and volumes that differ from point to point.
    fn ball() -> (Vec<Vec3>, Neighbourhoods, Kernel, LatticeOffsets, Vec<f64>) {
        let (mut rest, mut coords, mut volumes) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..11u32 {
            for j in 0..11u32 {
                for i in 0..11u32 {
                    let d = Vec3::new(i as f64 - 5.0, j as f64 - 4.6, k as f64 - 5.3);
                    if d.norm() <= 4.8 {
                        rest.push(
                            Vec3::new(0.031, -0.017, 0.052)
                                + Vec3::new(i as f64, j as f64, k as f64) * S,
                        );
                        coords.push([i, j, k]);
                        volumes
                            .push(S * S * S * (0.3 + 0.7 * ((i * 7 + j * 3 + k) % 5) as f64 / 4.0));
                    }
                }
            }
        }
        let kernel = Kernel { support_m: 2.0 * S };
        let grid = RestGrid::build(&rest, kernel.support_m);
        let nb = Neighbourhoods::build(&rest, &grid, kernel.support_m, 4);
        let lattice = LatticeOffsets { coords, spacing: S };
        (rest, nb, kernel, lattice, volumes)
    }

    /// A rigid turn and shift of the rest shape, with a deformation of `amplitude` (m) on top.
    fn deformed(rest: &[Vec3], amplitude: f64) -> Vec<Vec3> {
        let turn = *nalgebra::Rotation3::new(Vec3::new(0.3, -0.4, 0.5)).matrix();
        rest.iter()
            .enumerate()
            .map(|(i, x)| {
                let t = i as f64;
                turn * x
                    + Vec3::new(0.004, -0.002, 0.001)
                    + Vec3::new((t * 0.7).sin(), (t * 1.3).cos(), (t * 0.37).sin()) * amplitude
            })
            .collect()
    }

    /// Forces and statistics of one evaluation, with the stencil or without.
    fn evaluate(
        op: &MlsOperator,
        params: &ElasticParams,
        volumes: &[f64],
        p: &[Vec3],
        stencil: bool,
    ) -> (Vec<Vec3>, ForceStats) {
        let mut scratch = ForceScratch::new(p.len());
        if !stencil {
            scratch = scratch.without_stencil();
        }
        let mut f = vec![Vec3::zeros(); p.len()];
        let stats = add_elastic_forces(op, params, volumes, p, None, &mut f, &mut scratch);
        (f, stats)
    }

    fn assert_same(
        op: &MlsOperator,
        params: &ElasticParams,
        volumes: &[f64],
        p: &[Vec3],
        what: &str,
    ) {
        let (fs, a) = evaluate(op, params, volumes, p, true);
        let (fp, b) = evaluate(op, params, volumes, p, false);
        let scale = fp.iter().map(|x| x.norm()).fold(0.0, f64::max);
        assert!(scale > 0.0, "{what}: no force");
        for i in 0..p.len() {
            assert!(
                (fs[i] - fp[i]).norm() <= 1e-10 * scale,
                "{what}, point {i}: {} against {}",
                fs[i],
                fp[i]
            );
        }
        assert!(
            (a.strain_energy - b.strain_energy).abs() <= 1e-10 * b.strain_energy,
            "{what}: strain energy {} against {}",
            a.strain_energy,
            b.strain_energy
        );
        assert!(
            (a.hourglass_energy - b.hourglass_energy).abs() <= 1e-6 * b.energy(),
            "{what}: hourglass energy {} against {}",
            a.hourglass_energy,
            b.hourglass_energy
        );
        assert!((a.min_det_f - b.min_det_f).abs() <= 1e-12, "{what}");
        assert!((a.max_det_f - b.max_det_f).abs() <= 1e-12, "{what}");
        assert_eq!(a.clamped_points, b.clamped_points, "{what}");
        assert!(a.finite && b.finite, "{what}");
    }

    /// Every constitutive model, with and without the volume term, near rest and far enough
    /// out that some points take the inversion clamp: the stencil gives the pair kernels'
    /// forces to rounding, on a body turned and shifted away from its rest place.
    #[test]
    fn the_stencil_gives_the_forces_of_the_pair_kernels() {
        let (rest, nb, kernel, lattice, volumes) = ball();
        let op = MlsOperator::build(&rest, &nb, &kernel, Some(lattice));
        let stencil = op.stencil().expect("a lattice with h = 2s");
        assert_eq!(stencil.evaluated_count(), op.rank_counts().full);
        for model in [
            ElasticModel::StVK,
            ElasticModel::MuellerCompat,
            ElasticModel::Corotated,
        ] {
            for volume_k in [0.0, 3000.0] {
                for amplitude in [1e-5, 2e-4, 1.5e-3] {
                    let mut params = ElasticParams::stvk(5000.0, 0.45);
                    params.model = model;
                    params.volume_k = volume_k;
                    let p = deformed(&rest, amplitude);
                    let what = format!("{model:?}, k_v {volume_k}, amplitude {amplitude}");
                    assert_same(&op, &params, &volumes, &p, &what);
                }
            }
        }
        let clamped = evaluate(
            &op,
            &ElasticParams::stvk(5000.0, 0.45),
            &volumes,
            &deformed(&rest, 1.5e-3),
            true,
        )
        .1;
        assert!(
            clamped.clamped_points > 0,
            "the largest deformation should reach the clamp"
        );
    }

    /// A cut through the ball: the points whose rows it changes leave the stencil for the pair
    /// kernels, and the forces are still those of the pair kernels alone.
    #[test]
    fn points_a_cut_changes_go_to_the_pair_kernels() {
        let (rest, mut nb, kernel, lattice, volumes) = ball();
        let coords = lattice.coords.clone();
        let mut op = MlsOperator::build(&rest, &nb, &kernel, Some(lattice));
        let before = op.stencil().expect("a stencil").evaluated_count();
        // Cut every pair across the plane x = 5.5 s in the upper half.
        let mut changed = Vec::new();
        for i in 0..rest.len() {
            for &j in op.neighbours(i).to_vec().iter() {
                let (a, b) = (coords[i], coords[j as usize]);
                if a[0] <= 5 && b[0] >= 6 && a[2] >= 5 && b[2] >= 5 {
                    nb.remove(i, j);
                    nb.remove(j as usize, i as u32);
                    changed.extend([i as u32, j]);
                }
            }
        }
        changed.sort_unstable();
        changed.dedup();
        assert!(changed.len() > 20, "{} points cut", changed.len());
        op.update_points(&changed, &rest, &nb, &kernel);
        let after = op.stencil().expect("a stencil").evaluated_count();
        assert_eq!(before - after, changed.len());
        let params = ElasticParams::stvk(5000.0, 0.45);
        for amplitude in [1e-5, 2e-4] {
            assert_same(
                &op,
                &params,
                &volumes,
                &deformed(&rest, amplitude),
                "after the cut",
            );
        }
    }
}
