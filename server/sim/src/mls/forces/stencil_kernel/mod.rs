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

use super::StencilChunks;
use super::{ForceStats, Threads, lane_stress_scalar, lane_stvk};
use crate::math::Vec3;
use crate::mls::material::ElasticParams;
use crate::mls::operator::LANES;
use crate::mls::operator::stencil::{ChunkTerms, JOIN_GAP_CHUNKS, LatticeStencil, NONE, Span};

mod passes;
mod plane_sums;
mod spans;

use passes::*;
use plane_sums::*;
use spans::*;

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
    // Each pass split where its own chunks are halved (pass one runs over the stress
    // chunks, a wider set than pass two's active ones): a chunk's results do not depend on
    // the half it falls in.
    let split = halfway(one, stencil.chunks());
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
    let stats = {
        let (mut f_a, mut f_b) = split_each(f, split);
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
    let split = halfway(two, stencil.chunks());
    let (half_a, half_b) = (0..split, split..stencil.chunks());
    let (mut f_a, mut f_b) = split_each(f, split);
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

/// What the evaluation reads besides the fields.
#[derive(Clone, Copy)]
pub(crate) struct StencilInputs<'a> {
    /// The box and its terms.
    pub stencil: &'a LatticeStencil,
    /// Material.
    pub params: &'a ElasticParams,
    /// Rest volumes of the operator's points (m³).
    pub volumes: &'a [f64],
    /// The surface layer's prestress of every point, if any (`mls::prestress`).
    pub prestress: Option<&'a [super::Sym]>,
}

#[cfg(test)]
pub(crate) mod tests;
