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

use super::forces::StencilChunks;
use super::forces::{ForceStats, PointCheck, Threads, lane_stress_scalar, lane_stvk};
use super::material::ElasticParams;
use super::operator::LANES;
use super::stencil::{ChunkTerms, JOIN_GAP_CHUNKS, LatticeStencil, NONE, Span};
use crate::math::Vec3;

/// Four sites in x: one SIMD vector's worth of a field.
type Chunk = [f64; LANES];

/// A run of chunks.
type Chunks<'a> = &'a [Chunk];

/// What the second pass reads of one force component r at a chunk, side by side (one row
/// pointer reaches all four): the columns of M' for the box's x, y and z axes, and k u_r.
type Stress = [Chunk; 4];

/// Box fields of one evaluation, chunk by chunk, allocated once (at the first evaluation).
#[derive(Debug, Clone, Default)]
pub(crate) struct StencilFields {
    /// Displacements.
    u: [Vec<Chunk>; 3],
    /// |u|².
    z: Vec<Chunk>,
    /// Per force component: M' by box axis and k u.
    stress: [Vec<Stress>; 3],
    /// Hourglass stiffness k.
    k: Vec<Chunk>,
    /// The forces: the first pass writes each point's reaction −Σ_j g_ij, the second adds
    /// the pair forces it gathers.
    f: [Vec<Chunk>; 3],
    /// Scratch along a span, for each half of the spans.
    spans: [SpanScratch; 2],
    /// Which chunks of M', k u and k the last evaluation left non-zero.
    written: Written,
    /// The chunks of the last restricted evaluation's first pass.
    written_chunks: Vec<u32>,
    /// A restricted evaluation's runs of chunks for the first and the second pass.
    runs: [Vec<Span>; 2],
}

/// What the previous evaluation left in M', k u and k, which the second pass reads around
/// every site it gathers at: they must be zero wherever this evaluation does not write.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
enum Written {
    /// Nothing yet.
    #[default]
    Nothing,
    /// Every chunk holding a point (a whole-body evaluation).
    Everything,
    /// The chunks in `written_chunks` (a restricted evaluation).
    Chunks,
}

/// A restricted evaluation (an evaluation set): the stencil's points in `stress` have
/// stress, their displacements and those of the points around them (`touched`) are read,
/// and the forces are gathered at the chunks of the set's active points.
#[derive(Clone, Copy)]
pub(crate) struct Restriction<'a> {
    /// The chunks of the set's points.
    pub chunks: &'a StencilChunks,
    /// Per point: its stress is evaluated.
    pub stress: &'a [bool],
    /// The points whose displacements the passes read: the stress points and their
    /// neighbours.
    pub touched: &'a [u32],
}

impl StencilFields {
    /// Sizes the fields for `stencil` (allocates only when the box changes).
    pub(crate) fn fit(&mut self, stencil: &LatticeStencil) {
        let chunks = stencil.chunks();
        if self.z.len() == chunks {
            return;
        }
        let all = self
            .u
            .iter_mut()
            .chain(std::iter::once(&mut self.z))
            .chain(std::iter::once(&mut self.k))
            .chain(self.f.iter_mut());
        for field in all {
            field.clear();
            field.resize(chunks, [0.0; LANES]);
        }
        for field in &mut self.stress {
            field.clear();
            field.resize(chunks, [[0.0; LANES]; 4]);
        }
        let longest = stencil.longest_span();
        self.spans.iter_mut().for_each(|s| s.fit(longest));
        // Room for as many runs and chunks as the box has (no growth later).
        self.written = Written::Nothing;
        self.written_chunks = Vec::with_capacity(chunks);
        self.runs = [Vec::with_capacity(chunks), Vec::with_capacity(chunks)];
    }

    /// Sets M', k u and k to zero where the last evaluation wrote them, but for the chunks
    /// a whole-body evaluation is about to write anyway.
    fn clear_written(&mut self, whole: bool) {
        let clear = |fields: &mut Self, c: usize| {
            for stress in &mut fields.stress {
                stress[c] = [[0.0; LANES]; 4];
            }
            fields.k[c] = [0.0; LANES];
        };
        match (self.written, whole) {
            (Written::Nothing, _) | (Written::Everything, true) => {}
            (Written::Everything, false) => {
                for c in 0..self.k.len() {
                    clear(self, c);
                }
            }
            (Written::Chunks, _) => {
                for i in 0..self.written_chunks.len() {
                    let c = self.written_chunks[i] as usize;
                    clear(self, c);
                }
            }
        }
    }

    /// Writes the displacements of the lattice points at `p` into the box (of those in
    /// `points` only, when given).
    fn scatter(&mut self, stencil: &LatticeStencil, p: &[Vec3], points: Option<&[u32]>) {
        let (sites, rest) = (stencil.site_of(), stencil.rest());
        let [ux, uy, uz] = self.u.each_mut().map(|f| f.as_flattened_mut());
        let z = self.z.as_flattened_mut();
        let mut one = |site: u32, p: Vec3, rest: Vec3| {
            let site = site as usize;
            let u = p - rest;
            ux[site] = u.x;
            uy[site] = u.y;
            uz[site] = u.z;
            z[site] = u.norm_squared();
        };
        match points {
            None => {
                for ((&site, &p), &rest) in sites.iter().zip(p).zip(rest) {
                    one(site, p, rest);
                }
            }
            Some(list) => {
                for &i in list {
                    let i = i as usize;
                    if let (Some(&site), Some(&rest)) = (sites.get(i), rest.get(i)) {
                        one(site, p[i], rest);
                    }
                }
            }
        }
    }

    /// The gathered forces, one array per component indexed by site
    /// ([`LatticeStencil::site_of`]).
    #[inline]
    pub(crate) fn forces(&self) -> [&[f64]; 3] {
        self.f.each_ref().map(|f| f.as_flattened())
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

fn coefficients(stencil: &LatticeStencil) -> Coefficients {
    let (w, cw) = stencil.coefficients();
    Coefficients {
        w: w.map(f64x4::splat),
        cw: cw.map(f64x4::splat),
    }
}

/// Sums over the yz-plane around each site of a span, from the chunk before the span to
/// the chunk after it (local chunk 0 is the one before). With them every stencil sum is a
/// few terms in x: for a face, edge and corner neighbour the yz-offset has 0, 1 or 2
/// non-zero components, so
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
    p: Vec<Chunk>,
    q: Vec<Chunk>,
    ey: Vec<Chunk>,
    fy: Vec<Chunk>,
    ez: Vec<Chunk>,
    fz: Vec<Chunk>,
}

/// Which plane sums a field needs.
#[derive(Clone, Copy)]
enum Needs {
    /// All six (a displacement component: every stencil sum of it).
    All,
    /// P and Q (weighted sums).
    PQ,
}

/// Where a span is in the box: its first chunk, its length, and the chunk steps in y, z.
#[derive(Clone, Copy)]
struct Place {
    chunk: usize,
    len: usize,
    cy: usize,
    cz: usize,
}

impl Place {
    /// A field's chunks from the one before the span to the one after it, moved by
    /// (dy, dz) rows.
    #[inline(always)]
    fn around<'a>(&self, field: &'a [Chunk], dy: usize, dz: usize) -> Chunks<'a> {
        // dy, dz are 0, 1, 2 for −1, 0, +1.
        let start = self.chunk - 1 - self.cy - self.cz + dy * self.cy + dz * self.cz;
        &field[start..start + self.len + 2]
    }
}

impl PlaneSums {
    /// Room for spans of up to `chunks` chunks.
    fn fit(&mut self, chunks: usize) {
        for v in [
            &mut self.p,
            &mut self.q,
            &mut self.ey,
            &mut self.fy,
            &mut self.ez,
            &mut self.fz,
        ] {
            v.clear();
            v.resize(chunks + 2, [0.0; LANES]);
        }
    }

    /// The sums of `field` that `needs` names, around the span at `at`.
    fn fill(&mut self, field: &[Chunk], at: Place, needs: Needs) {
        let n = at.len + 2;
        let r = |y: usize, z: usize| at.around(field, y, z);
        let v = f64x4::from;
        match needs {
            Needs::All => {
                let (r01, r21, r10, r12) = (r(0, 1), r(2, 1), r(1, 0), r(1, 2));
                let (r00, r20, r02, r22) = (r(0, 0), r(2, 0), r(0, 2), r(2, 2));
                let (p, q) = (&mut self.p[..n], &mut self.q[..n]);
                let (ey, fy) = (&mut self.ey[..n], &mut self.fy[..n]);
                let (ez, fz) = (&mut self.ez[..n], &mut self.fz[..n]);
                for i in 0..n {
                    let (a01, a21, a10, a12) = (v(r01[i]), v(r21[i]), v(r10[i]), v(r12[i]));
                    let (a00, a20, a02, a22) = (v(r00[i]), v(r20[i]), v(r02[i]), v(r22[i]));
                    p[i] = ((a01 + a21) + (a10 + a12)).to_array();
                    q[i] = ((a00 + a20) + (a02 + a22)).to_array();
                    ey[i] = (a21 - a01).to_array();
                    fy[i] = ((a20 - a00) + (a22 - a02)).to_array();
                    ez[i] = (a12 - a10).to_array();
                    fz[i] = ((a02 - a00) + (a22 - a20)).to_array();
                }
            }
            Needs::PQ => {
                let (r01, r21, r10, r12) = (r(0, 1), r(2, 1), r(1, 0), r(1, 2));
                let (r00, r20, r02, r22) = (r(0, 0), r(2, 0), r(0, 2), r(2, 2));
                let (p, q) = (&mut self.p[..n], &mut self.q[..n]);
                for i in 0..n {
                    p[i] = ((v(r01[i]) + v(r21[i])) + (v(r10[i]) + v(r12[i]))).to_array();
                    q[i] = ((v(r00[i]) + v(r20[i])) + (v(r02[i]) + v(r22[i]))).to_array();
                }
            }
        }
    }
}

/// `n` chunks of four sites of `flat` from site `start`.
#[inline(always)]
fn chunks_at(flat: &[f64], start: usize, n: usize) -> Chunks<'_> {
    &flat[start..start + LANES * n].as_chunks::<LANES>().0[..n]
}

/// A buffer's lanes at x − 1, x and x + 1 of each chunk of a span: three views of it one
/// site apart (an unaligned vector load each).
#[derive(Clone, Copy)]
struct Shifted<'a> {
    minus: Chunks<'a>,
    centre: Chunks<'a>,
    plus: Chunks<'a>,
}

impl<'a> Shifted<'a> {
    /// The views of `n` chunks of `buffer` from chunk `first`.
    #[inline(always)]
    fn of(buffer: &'a [Chunk], first: usize, n: usize) -> Self {
        let flat = buffer.as_flattened();
        let start = LANES * first;
        Self {
            minus: chunks_at(flat, start - 1, n),
            centre: chunks_at(flat, start, n),
            plus: chunks_at(flat, start + 1, n),
        }
    }

    #[inline(always)]
    fn at(&self, i: usize) -> (f64x4, f64x4, f64x4) {
        (
            f64x4::from(self.minus[i]),
            f64x4::from(self.centre[i]),
            f64x4::from(self.plus[i]),
        )
    }
}

/// Per chunk of a span: Σ_o (w x)(o) v[i+o] (x, y, z), Σ_o w(o) v[i+o] and v itself, of one
/// field.
#[derive(Debug, Clone, Copy, Default)]
struct FieldSums {
    grad: [f64x4; 3],
    weighted: f64x4,
    centre: f64x4,
}

/// `out[i]` for the chunks of a span: the stencil sums of a field (`v` its own chunks, `s`
/// its plane sums).
fn field_sums(k: &Coefficients, v: Shifted<'_>, s: &PlaneSums, out: &mut [FieldSums]) {
    let n = out.len();
    let (p, q) = (Shifted::of(&s.p, 1, n), Shifted::of(&s.q, 1, n));
    let (ey, fy) = (Shifted::of(&s.ey, 1, n), Shifted::of(&s.fy, 1, n));
    let (ez, fz) = (Shifted::of(&s.ez, 1, n), Shifted::of(&s.fz, 1, n));
    for i in 0..n {
        let (v0, v1, v2) = v.at(i);
        let (p0, p1, p2) = p.at(i);
        let (q0, q1, q2) = q.at(i);
        let gx = k.cw[0].mul_add(v2 - v0, k.cw[1].mul_add(p2 - p0, k.cw[2] * (q2 - q0)));
        let weighted = k.w[0].mul_add(
            p1 + (v0 + v2),
            k.w[1].mul_add(q1 + (p0 + p2), k.w[2] * (q0 + q2)),
        );
        let (e0, e1, e2) = ey.at(i);
        let (f0, f1, f2) = fy.at(i);
        let gy = k.cw[0].mul_add(e1, k.cw[1].mul_add(f1 + (e0 + e2), k.cw[2] * (f0 + f2)));
        let (e0, e1, e2) = ez.at(i);
        let (f0, f1, f2) = fz.at(i);
        let gz = k.cw[0].mul_add(e1, k.cw[1].mul_add(f1 + (e0 + e2), k.cw[2] * (f0 + f2)));
        out[i] = FieldSums {
            grad: [gx, gy, gz],
            weighted,
            centre: v1,
        };
    }
}

/// `out[i] = Σ_o w(o) v[i+o]` for the chunks of a span.
fn weighted_sums(k: &Coefficients, v: Shifted<'_>, s: &PlaneSums, out: &mut [f64x4]) {
    let n = out.len();
    let (p, q) = (Shifted::of(&s.p, 1, n), Shifted::of(&s.q, 1, n));
    for i in 0..n {
        let (v0, _, v2) = v.at(i);
        let (p0, p1, p2) = p.at(i);
        let (q0, q1, q2) = q.at(i);
        out[i] = k.w[0].mul_add(
            p1 + (v0 + v2),
            k.w[1].mul_add(q1 + (p0 + p2), k.w[2] * (q0 + q2)),
        );
    }
}

/// The second pass's stencil sums of one force component, regrouped by the x offset they
/// are read at. With m_x, m_y, m_z the columns of M' for the box's x, y and z axes and
/// (plane sums as in [`PlaneSums`], per site)
///
/// ```text
/// G  = cw₁ m_x + cw₂ P(m_x) + cw₃ Q(m_x)
/// Yc = cw₁ E_y(m_y) + cw₂ F_y(m_y)      Ys = cw₂ E_y(m_y) + cw₃ F_y(m_y)   (Zc, Zs of m_z)
/// Wc = w₁ P(ku) + w₂ Q(ku)              Ws = w₁ ku + w₂ P(ku) + w₃ Q(ku)
/// ```
///
/// the gathered force −Σ (w x)·M' + Σ w (k u) is
///
/// ```text
/// (Wc − Yc − Zc)[x] + (Ws − Ys − Zs + G)[x−1] + (Ws − Ys − Zs − G)[x+1]
/// ```
///
/// so one loop over the span's planes reads each of the four fields' rows once and
/// writes three sums, and one loop in x adds them (instead of a plane-sum pass and a
/// stencil-sum pass per field).
#[derive(Debug, Clone, Default)]
struct GatherPlanes {
    /// Read at x.
    centre: Vec<Chunk>,
    /// Read at x − 1.
    minus: Vec<Chunk>,
    /// Read at x + 1.
    plus: Vec<Chunk>,
}

impl GatherPlanes {
    fn fit(&mut self, chunks: usize) {
        for v in [&mut self.centre, &mut self.minus, &mut self.plus] {
            v.clear();
            v.resize(chunks + 2, [0.0; LANES]);
        }
    }

    /// The three sums of one component's `stress` around the span at `at`.
    fn fill(&mut self, k: &Coefficients, stress: &[Stress], at: Place) {
        let n = at.len + 2;
        let start = at.chunk - 1;
        let (cy, cz) = (at.cy, at.cz);
        // Row (dy, dz) at 3 (dz + 1) + dy + 1, each from the chunk before the span.
        let row = |dy: isize, dz: isize| {
            let first = start.wrapping_add_signed(dy * cy as isize + dz * cz as isize);
            &stress[first..first + n]
        };
        let rows = [
            row(-1, -1),
            row(0, -1),
            row(1, -1),
            row(-1, 0),
            row(0, 0),
            row(1, 0),
            row(-1, 1),
            row(0, 1),
            row(1, 1),
        ];
        let (centre, minus, plus) = (
            &mut self.centre[..n],
            &mut self.minus[..n],
            &mut self.plus[..n],
        );
        let v = |row: usize, i: usize, field: usize| f64x4::from(rows[row][i][field]);
        const X: usize = 0;
        const Y: usize = 1;
        const Z: usize = 2;
        const KU: usize = 3;
        for i in 0..n {
            let edges = |f| (v(3, i, f) + v(5, i, f)) + (v(1, i, f) + v(7, i, f));
            let corners = |f| (v(0, i, f) + v(2, i, f)) + (v(6, i, f) + v(8, i, f));
            let (p, q) = (edges(X), corners(X));
            let g = k.cw[0].mul_add(v(4, i, X), k.cw[1].mul_add(p, k.cw[2] * q));
            let (p, q) = (edges(KU), corners(KU));
            let wc = k.w[0].mul_add(p, k.w[1] * q);
            let ws = k.w[0].mul_add(v(4, i, KU), k.w[1].mul_add(p, k.w[2] * q));
            let ey = v(5, i, Y) - v(3, i, Y);
            let fy = (v(2, i, Y) - v(0, i, Y)) + (v(8, i, Y) - v(6, i, Y));
            let ez = v(7, i, Z) - v(1, i, Z);
            let fz = (v(6, i, Z) - v(0, i, Z)) + (v(8, i, Z) - v(2, i, Z));
            let yc = k.cw[0].mul_add(ey, k.cw[1] * fy);
            let ys = k.cw[1].mul_add(ey, k.cw[2] * fy);
            let zc = k.cw[0].mul_add(ez, k.cw[1] * fz);
            let zs = k.cw[1].mul_add(ez, k.cw[2] * fz);
            let side = ws - (ys + zs);
            centre[i] = (wc - (yc + zc)).to_array();
            minus[i] = (side + g).to_array();
            plus[i] = (side - g).to_array();
        }
    }
}

/// What the passes keep along one span.
#[derive(Debug, Clone, Default)]
struct SpanScratch {
    /// Plane sums of the field at hand.
    sums: PlaneSums,
    /// The second pass's sums of a force component.
    gather: GatherPlanes,
    /// Per chunk: the stencil sums of u's components.
    u: [Vec<FieldSums>; 3],
    /// Per chunk: Σ w |u_j|², Σ w k.
    z: Vec<f64x4>,
    kw: Vec<f64x4>,
}

impl SpanScratch {
    fn fit(&mut self, chunks: usize) {
        self.sums.fit(chunks);
        self.gather.fit(chunks);
        for u in &mut self.u {
            u.clear();
            u.resize(chunks, FieldSums::default());
        }
        for v in [&mut self.z, &mut self.kw] {
            v.clear();
            v.resize(chunks, f64x4::ZERO);
        }
    }
}

/// Runs `a` and `b`, one after the other or as a `rayon::join`.
fn both<A: Send, B: Send>(
    threads: Threads,
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    match threads {
        Threads::One => (a(), b()),
        #[cfg(feature = "parallel")]
        Threads::Rayon => rayon::join(a, b),
    }
}

/// Each field cut at chunk `at`: the first parts, then the second.
fn split_each<T, const N: usize>(
    fields: &mut [Vec<T>; N],
    at: usize,
) -> ([&mut [T]; N], [&mut [T]; N]) {
    let mut parts = fields.each_mut().map(|f| {
        let (a, b) = f.split_at_mut(at);
        (Some(a), Some(b))
    });
    let first = std::array::from_fn(|i| parts[i].0.take().expect("taken once"));
    let second = std::array::from_fn(|i| parts[i].1.take().expect("taken once"));
    (first, second)
}

/// The spans clipped to the chunks `range`, each as (first chunk, length, index of its first
/// chunk's terms).
fn spans_within(
    spans: &[Span],
    range: std::ops::Range<usize>,
) -> impl Iterator<Item = (usize, usize, usize)> + '_ {
    spans.iter().filter_map(move |s| {
        let (first, end) = (s.chunk as usize, (s.chunk + s.len) as usize);
        let lo = first.max(range.start);
        let hi = end.min(range.end);
        (lo < hi).then(|| (lo, hi - lo, s.terms as usize + lo - first))
    })
}

/// Runs of consecutive chunks of a sorted list, with their terms, joined across gaps of up
/// to [`JOIN_GAP_CHUNKS`] chunks within one span (the lanes of a gap chunk have no stress in
/// the evaluation, and what is gathered there is not read): a short run costs its set-up and
/// the plane sums of a chunk on either side.
fn runs_of(stencil: &LatticeStencil, chunks: &[u32], runs: &mut Vec<Span>) {
    runs.clear();
    for &c in chunks {
        let terms = stencil.terms_of_chunk(c as usize);
        match runs.last_mut() {
            Some(last)
                if c - (last.chunk + last.len) <= JOIN_GAP_CHUNKS as u32
                    && terms - last.terms == c - last.chunk =>
            {
                last.len = c + 1 - last.chunk;
            }
            _ => runs.push(Span {
                chunk: c,
                len: 1,
                terms,
            }),
        }
    }
}

/// The chunk that splits `runs` into halves of about the same number of chunks.
fn halfway(runs: &[Span], end: usize) -> usize {
    let total: usize = runs.iter().map(|s| s.len as usize).sum();
    let mut left = total / 2;
    for s in runs {
        if (s.len as usize) > left {
            return s.chunk as usize + left;
        }
        left -= s.len as usize;
    }
    end
}

/// Evaluates the stencil's points at positions `p` (with `restriction`, those of an
/// evaluation set): their statistics (the first half of the chunks, then the second), and
/// in the fields the pair forces of their rows gathered at every site the evaluation
/// covers ([`StencilFields::forces`]). The halves run on one thread or two with the same
/// bits.
pub(crate) fn evaluate(
    inputs: StencilInputs<'_>,
    p: &[Vec3],
    restriction: Option<Restriction<'_>>,
    fields: &mut StencilFields,
    threads: Threads,
) -> (ForceStats, ForceStats) {
    let stencil = inputs.stencil;
    fields.fit(stencil);
    fields.scatter(stencil, p, restriction.map(|r| r.touched));
    // The sub-steps of a tick evaluate one set again and again: what the last evaluation
    // wrote is then exactly what this one overwrites.
    let same_set = matches!(
        (fields.written, restriction),
        (Written::Chunks, Some(r)) if fields.written_chunks == r.chunks.stress
    );
    if !same_set {
        fields.clear_written(restriction.is_none());
    }
    let [runs_one, runs_two] = &mut fields.runs;
    let (one, two): (&[Span], &[Span]) = match restriction {
        None => (stencil.spans(), stencil.spans()),
        Some(r) => {
            runs_of(stencil, &r.chunks.stress, runs_one);
            runs_of(stencil, &r.chunks.active, runs_two);
            // The second pass adds to the reaction the first writes: none where the first
            // does not run.
            for run in runs_two.iter() {
                for f in &mut fields.f {
                    f[run.chunk as usize..(run.chunk + run.len) as usize].fill([0.0; LANES]);
                }
            }
            (runs_one, runs_two)
        }
    };
    match restriction {
        None => fields.written = Written::Everything,
        Some(_) if same_set => {}
        Some(r) => {
            fields.written = Written::Chunks;
            fields.written_chunks.clear();
            fields.written_chunks.extend_from_slice(&r.chunks.stress);
        }
    }
    let split = halfway(two, stencil.chunks());
    let (half_a, half_b) = (0..split, split..stencil.chunks());
    let lanes = Lanes {
        stress: restriction.map(|r| r.stress),
    };
    let StencilFields {
        u,
        z,
        stress,
        k,
        f,
        spans: scratch,
        ..
    } = fields;
    let [scratch_a, scratch_b] = scratch;
    let (mut f_a, mut f_b) = split_each(f, split);
    let stats = {
        let (stress_a, stress_b) = split_each(stress, split);
        let (k_a, k_b) = k.split_at_mut(split);
        let read = PassOneIn { u, z };
        let mut a = PassOneOut {
            offset: 0,
            stress: stress_a,
            k: k_a,
            own: &mut f_a,
        };
        let mut b = PassOneOut {
            offset: split,
            stress: stress_b,
            k: k_b,
            own: &mut f_b,
        };
        both(
            threads,
            || {
                pass_one(
                    &inputs,
                    one,
                    half_a.clone(),
                    lanes,
                    &read,
                    scratch_a,
                    &mut a,
                )
            },
            || {
                pass_one(
                    &inputs,
                    one,
                    half_b.clone(),
                    lanes,
                    &read,
                    scratch_b,
                    &mut b,
                )
            },
        )
    };
    let read = PassTwoIn { stress, k, u };
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
        || pass_two(&inputs, two, half_a, &read, scratch_a, &mut a),
        || pass_two(&inputs, two, half_b, &read, scratch_b, &mut b),
    );
    stats
}

/// Which lanes of a chunk have stress: those the stencil evaluates, and of a restricted
/// evaluation only those in its set.
#[derive(Clone, Copy)]
struct Lanes<'a> {
    stress: Option<&'a [bool]>,
}

impl Lanes<'_> {
    #[inline(always)]
    fn of(&self, t: &ChunkTerms) -> [bool; LANES] {
        match self.stress {
            None => t.evaluated,
            Some(flags) => {
                std::array::from_fn(|lane| t.evaluated[lane] && flags[t.point[lane] as usize])
            }
        }
    }
}

/// What the first pass reads.
struct PassOneIn<'a> {
    u: &'a [Vec<Chunk>; 3],
    z: &'a [Chunk],
}

/// The fields the first pass writes, for the chunks from `offset` on.
struct PassOneOut<'a, 'b, 'f> {
    offset: usize,
    stress: [&'a mut [Stress]; 3],
    k: &'a mut [Chunk],
    /// The forces, where each point's reaction goes.
    own: &'b mut [&'f mut [Chunk]; 3],
}

/// What the second pass reads.
struct PassTwoIn<'a> {
    stress: &'a [Vec<Stress>; 3],
    k: &'a [Chunk],
    u: &'a [Vec<Chunk>; 3],
}

/// The forces the second pass adds to, for the chunks from `offset` on.
struct PassTwoOut<'a, 'b> {
    offset: usize,
    f: &'b mut [&'a mut [Chunk]; 3],
}

/// One span's slices of the first pass's outputs.
struct SpanOut<'a> {
    stress: [&'a mut [Stress]; 3],
    k: &'a mut [Chunk],
    own: [&'a mut [Chunk]; 3],
}

/// Stress of the points of the spans' chunks within `range`: M', k u, k and the reaction
/// −Σ g into the fields.
fn pass_one(
    inputs: &StencilInputs<'_>,
    runs: &[Span],
    range: std::ops::Range<usize>,
    lanes: Lanes<'_>,
    read: &PassOneIn<'_>,
    scratch: &mut SpanScratch,
    out: &mut PassOneOut<'_, '_, '_>,
) -> ForceStats {
    let stencil = inputs.stencil;
    let (cy, cz) = stencil.chunk_strides();
    let terms = stencil.terms();
    let coef = coefficients(stencil);
    let params = inputs.params;
    let alpha_e = f64x4::splat(params.hourglass_alpha * params.effective_youngs_modulus());
    let mut stats = ForceStats::EMPTY;
    let axes = stencil.axes();
    let SpanScratch { sums, u, z, .. } = scratch;
    for (chunk, len, first_term) in spans_within(runs, range) {
        let at = Place { chunk, len, cy, cz };
        for r in 0..3 {
            sums.fill(&read.u[r], at, Needs::All);
            field_sums(
                &coef,
                Shifted::of(&read.u[r], chunk, len),
                sums,
                &mut u[r][..len],
            );
        }
        sums.fill(read.z, at, Needs::PQ);
        weighted_sums(&coef, Shifted::of(read.z, chunk, len), sums, &mut z[..len]);
        let o = chunk - out.offset;
        let mut slices = SpanOut {
            stress: out.stress.each_mut().map(|f| &mut f[o..o + len]),
            k: &mut out.k[o..o + len],
            own: out.own.each_mut().map(|f| &mut f[o..o + len]),
        };
        let terms = &terms[first_term..first_term + len];
        let (u0, u1, u2, z) = (&u[0][..len], &u[1][..len], &u[2][..len], &z[..len]);
        for i in 0..len {
            let t = &terms[i];
            if !t.has_points() {
                // A gap: nothing is ever stored here but the reaction the second pass
                // adds to.
                for c in 0..3 {
                    slices.own[c][i] = [0.0; LANES];
                }
                continue;
            }
            let each = [&u0[i], &u1[i], &u2[i]];
            let uc = [each[0].centre, each[1].centre, each[2].centre];
            let sw = [each[0].weighted, each[1].weighted, each[2].weighted];
            // Σ w x ⊗ u with column c the lattice axis of the box axis the sum ran along.
            let mut grad = [[f64x4::ZERO; 3]; 3];
            for r in 0..3 {
                for (box_axis, &c) in axes.iter().enumerate() {
                    grad[r][c] = each[r].grad[box_axis];
                }
            }
            let sums = PointSums {
                grad,
                sw,
                uc,
                zs: z[i],
            };
            let mask = lanes.of(t);
            // Direct calls, so that each stays inlined.
            if t.diagonal {
                point_stress::<true>(inputs, t, mask, alpha_e, sums, &mut slices, i, &mut stats);
            } else {
                point_stress::<false>(inputs, t, mask, alpha_e, sums, &mut slices, i, &mut stats);
            }
        }
    }
    stats
}

/// One chunk's sums from the first pass.
struct PointSums {
    /// Σ w x ⊗ u (lattice axes).
    grad: [[f64x4; 3]; 3],
    /// S = Σ w u_j.
    sw: [f64x4; 3],
    /// u_i.
    uc: [f64x4; 3],
    /// Z = Σ w |u_j|².
    zs: f64x4,
}

/// The stress of a chunk's points from their sums, into chunk `i` of the span's outputs
/// and `stats`. `DIAGONAL`: the chunk's A⁻¹ are diagonal and its Σ w x zero
/// ([`ChunkTerms::diagonal`]), so the products with A⁻¹ are three columns scaled and the
/// reaction −M' Σ w x vanishes.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn point_stress<const DIAGONAL: bool>(
    inputs: &StencilInputs<'_>,
    t: &ChunkTerms,
    mask: [bool; LANES],
    alpha_e: f64x4,
    sums: PointSums,
    out: &mut SpanOut<'_>,
    i: usize,
    stats: &mut ForceStats,
) {
    let PointSums { grad, sw, uc, zs } = sums;
    let params = inputs.params;
    let a = &t.a_inv;
    let sum_wx = t.sum_wx;
    // B = Σ w x ⊗ u − u_i ⊗ Σ w x.
    let b: [[f64x4; 3]; 3] = std::array::from_fn(|r| {
        std::array::from_fn(|c| {
            if DIAGONAL {
                grad[r][c]
            } else {
                (-uc[r]).mul_add(sum_wx[c], grad[r][c])
            }
        })
    });
    let times_a = |m: &[[f64x4; 3]; 3], r: usize, c: usize| {
        if DIAGONAL {
            m[r][c] * a[4 * c]
        } else {
            m[r][0].mul_add(a[c], m[r][1].mul_add(a[3 + c], m[r][2] * a[6 + c]))
        }
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
    // Lanes without stress of their own write zeros: selected, not multiplied, so that
    // whatever a lane outside the evaluation computed (from stale neighbours) never leaks.
    let on = f64x4::from(mask.map(|m| if m { f64::from_bits(u64::MAX) } else { 0.0 }));
    let keep = |v: f64x4| on.bitselect(v, f64x4::ZERO).to_array();
    let axes = inputs.stencil.axes();
    let mut hb = f64x4::ZERO;
    let mut us = f64x4::ZERO;
    for r in 0..3 {
        let mr = [times_a(&kb, r, 0), times_a(&kb, r, 1), times_a(&kb, r, 2)];
        for c in 0..3 {
            hb = h[r][c].mul_add(b[r][c], hb);
        }
        out.stress[r][i] = [
            keep(mr[axes[0]]),
            keep(mr[axes[1]]),
            keep(mr[axes[2]]),
            keep(k * uc[r]),
        ];
        // −Σ_j g_ij = −M' Σ w x + k (S − u_i Σ w).
        let spring = k * (-uc[r]).mul_add(sum_w, sw[r]);
        out.own[r][i] = keep(if DIAGONAL {
            spring
        } else {
            spring - mr[0].mul_add(sum_wx[0], mr[1].mul_add(sum_wx[1], mr[2] * sum_wx[2]))
        });
        us = uc[r].mul_add(uc[r].mul_add(sum_w, f64x4::splat(-2.0) * sw[r]), us);
    }
    out.k[i] = keep(k);
    let hourglass = (f64x4::splat(0.5) * k * (zs + us - hb)).to_array();
    let strain = (psi * volume).to_array();
    for lane in 0..LANES {
        if mask[lane] {
            stats.add_point(strain[lane], hourglass[lane], checks[lane]);
        }
    }
}

/// Gathers at each site of the spans' chunks within `range` the pair forces of the stencil
/// points around it.
fn pass_two(
    inputs: &StencilInputs<'_>,
    runs: &[Span],
    range: std::ops::Range<usize>,
    read: &PassTwoIn<'_>,
    scratch: &mut SpanScratch,
    out: &mut PassTwoOut<'_, '_>,
) {
    let stencil = inputs.stencil;
    let (cy, cz) = stencil.chunk_strides();
    let coef = coefficients(stencil);
    let SpanScratch {
        sums, gather, kw, ..
    } = scratch;
    for (chunk, len, _) in spans_within(runs, range) {
        let at = Place { chunk, len, cy, cz };
        let kw = &mut kw[..len];
        sums.fill(read.k, at, Needs::PQ);
        weighted_sums(&coef, Shifted::of(read.k, chunk, len), sums, kw);
        for r in 0..3 {
            gather.fill(&coef, &read.stress[r], at);
            let centre = Shifted::of(&gather.centre, 1, len).centre;
            let minus = Shifted::of(&gather.minus, 1, len).minus;
            let plus = Shifted::of(&gather.plus, 1, len).plus;
            let u = &read.u[r][chunk..chunk + len];
            let o = chunk - out.offset;
            let f = &mut out.f[r][o..o + len];
            for i in 0..len {
                let uc = f64x4::from(u[i]);
                let gathered =
                    f64x4::from(centre[i]) + (f64x4::from(minus[i]) + f64x4::from(plus[i]));
                let sum = (-uc).mul_add(kw[i], gathered) + f64x4::from(f[i]);
                f[i] = sum.to_array();
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
mod tests;
