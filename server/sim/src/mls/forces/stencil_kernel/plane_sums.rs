//! Plane sums: the sums over the yz-plane around each site of a span that reduce every
//! stencil sum to a few terms in x, and the stencil sums built from them.

use super::*;

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
pub(super) struct PlaneSums {
    p: Vec<Chunk>,
    q: Vec<Chunk>,
    ey: Vec<Chunk>,
    fy: Vec<Chunk>,
    ez: Vec<Chunk>,
    fz: Vec<Chunk>,
}

/// Which plane sums a field needs.
#[derive(Clone, Copy)]
pub(super) enum Needs {
    /// All six (a displacement component: every stencil sum of it).
    All,
    /// P and Q (weighted sums).
    PQ,
}

/// Where a span is in the box: its first chunk, its length, and the chunk steps in y, z.
#[derive(Clone, Copy)]
pub(super) struct Place {
    pub(super) chunk: usize,
    pub(super) len: usize,
    pub(super) cy: usize,
    pub(super) cz: usize,
}

impl Place {
    /// A field's chunks from the one before the span to the one after it, moved by
    /// (dy, dz) rows.
    #[inline(always)]
    pub(super) fn around<'a>(&self, field: &'a [Chunk], dy: usize, dz: usize) -> Chunks<'a> {
        // dy, dz are 0, 1, 2 for −1, 0, +1.
        let start = self.chunk - 1 - self.cy - self.cz + dy * self.cy + dz * self.cz;
        &field[start..start + self.len + 2]
    }
}

impl PlaneSums {
    /// Room for spans of up to `chunks` chunks.
    pub(super) fn fit(&mut self, chunks: usize) {
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
    pub(super) fn fill(&mut self, field: &[Chunk], at: Place, needs: Needs) {
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
pub(super) fn chunks_at(flat: &[f64], start: usize, n: usize) -> Chunks<'_> {
    &flat[start..start + LANES * n].as_chunks::<LANES>().0[..n]
}

/// A buffer's lanes at x − 1, x and x + 1 of each chunk of a span: three views of it one
/// site apart (an unaligned vector load each).
#[derive(Clone, Copy)]
pub(super) struct Shifted<'a> {
    pub(super) minus: Chunks<'a>,
    pub(super) centre: Chunks<'a>,
    pub(super) plus: Chunks<'a>,
}

impl<'a> Shifted<'a> {
    /// The views of `n` chunks of `buffer` from chunk `first`.
    #[inline(always)]
    pub(super) fn of(buffer: &'a [Chunk], first: usize, n: usize) -> Self {
        let flat = buffer.as_flattened();
        let start = LANES * first;
        Self {
            minus: chunks_at(flat, start - 1, n),
            centre: chunks_at(flat, start, n),
            plus: chunks_at(flat, start + 1, n),
        }
    }

    #[inline(always)]
    pub(super) fn at(&self, i: usize) -> (f64x4, f64x4, f64x4) {
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
pub(super) struct FieldSums {
    pub(super) grad: [f64x4; 3],
    pub(super) weighted: f64x4,
    pub(super) centre: f64x4,
}

/// `out[i]` for the chunks of a span: the stencil sums of a field (`v` its own chunks, `s`
/// its plane sums).
pub(super) fn field_sums(k: &Coefficients, v: Shifted<'_>, s: &PlaneSums, out: &mut [FieldSums]) {
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
pub(super) fn weighted_sums(k: &Coefficients, v: Shifted<'_>, s: &PlaneSums, out: &mut [f64x4]) {
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
pub(super) struct GatherPlanes {
    /// Read at x.
    pub(super) centre: Vec<Chunk>,
    /// Read at x − 1.
    pub(super) minus: Vec<Chunk>,
    /// Read at x + 1.
    pub(super) plus: Vec<Chunk>,
}

impl GatherPlanes {
    pub(super) fn fit(&mut self, chunks: usize) {
        for v in [&mut self.centre, &mut self.minus, &mut self.plus] {
            v.clear();
            v.resize(chunks + 2, [0.0; LANES]);
        }
    }

    /// The three sums of one component's `stress` around the span at `at`.
    pub(super) fn fill(&mut self, k: &Coefficients, stress: &[Stress], at: Place) {
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
