//! The two passes over a span: stress of its points into the box fields, then the pair
//! forces gathered at every site.

use super::*;
use crate::mls::prestress;

/// What the passes keep along one span.
#[derive(Debug, Clone, Default)]
pub(super) struct SpanScratch {
    /// Plane sums of the field at hand.
    pub(super) sums: PlaneSums,
    /// The second pass's sums of a force component.
    pub(super) gather: GatherPlanes,
    /// Per chunk: the stencil sums of u's components.
    pub(super) u: [Vec<FieldSums>; 3],
    /// Per chunk: Σ w |u_j|², Σ w k.
    pub(super) z: Vec<f64x4>,
    pub(super) kw: Vec<f64x4>,
}

impl SpanScratch {
    pub(super) fn fit(&mut self, chunks: usize) {
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

/// Which lanes of a chunk have stress: those the stencil evaluates, and of a restricted
/// evaluation only those in its set.
#[derive(Clone, Copy)]
pub(super) struct Lanes<'a> {
    pub(super) stress: Option<&'a [bool]>,
}

impl Lanes<'_> {
    #[inline(always)]
    pub(super) fn of(&self, t: &ChunkTerms) -> [bool; LANES] {
        match self.stress {
            None => t.evaluated,
            Some(flags) => {
                std::array::from_fn(|lane| t.evaluated[lane] && flags[t.point[lane] as usize])
            }
        }
    }
}

/// What the first pass reads.
pub(super) struct PassOneIn<'a> {
    pub(super) u: &'a [Vec<Chunk>; 3],
    pub(super) z: &'a [Chunk],
}

/// The fields the first pass writes, for the chunks from `offset` on.
pub(super) struct PassOneOut<'a, 'b, 'f> {
    pub(super) offset: usize,
    pub(super) stress: [&'a mut [Stress]; 3],
    pub(super) k: &'a mut [Chunk],
    /// The forces, where each point's reaction goes.
    pub(super) own: &'b mut [&'f mut [Chunk]; 3],
}

/// What the second pass reads.
pub(super) struct PassTwoIn<'a> {
    pub(super) stress: &'a [Vec<Stress>; 3],
    pub(super) k: &'a [Chunk],
    pub(super) u: &'a [Vec<Chunk>; 3],
}

/// The forces the second pass adds to, for the chunks from `offset` on.
pub(super) struct PassTwoOut<'a, 'b> {
    pub(super) offset: usize,
    pub(super) f: &'b mut [&'a mut [Chunk]; 3],
}

/// One span's slices of the first pass's outputs.
pub(super) struct SpanOut<'a> {
    stress: [&'a mut [Stress]; 3],
    k: &'a mut [Chunk],
    own: [&'a mut [Chunk]; 3],
}

/// Stress of the points of the spans' chunks within `range`: M', k u, k and the reaction
/// −Σ g into the fields.
pub(super) fn pass_one(
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
pub(super) struct PointSums {
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
pub(super) fn point_stress<const DIAGONAL: bool>(
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
    let (mut p_stress, psi, checks) = match lane_stvk(params, &f) {
        Some(stressed) => stressed,
        None => lane_stress_scalar(params, &f),
    };
    let volume_of = |lane: usize| match t.point[lane] {
        NONE => 0.0,
        i => inputs.volumes[i as usize],
    };
    let volume = f64x4::from([volume_of(0), volume_of(1), volume_of(2), volume_of(3)]);
    let layer = inputs.prestress.and_then(|field| {
        let points = std::array::from_fn(|l| match t.point[l] {
            NONE => None,
            i => mask[l].then_some(i as usize),
        });
        prestress::gather(field, points)
    });
    if let Some(s0) = layer {
        let e = (prestress::add_to_lanes(&f, &s0, &mut p_stress) * volume).to_array();
        for lane in 0..LANES {
            if mask[lane] {
                stats.prestress_energy += e[lane];
            }
        }
    }
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
pub(super) fn pass_two(
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
