//! The evaluation set: the points an evaluation covers (the cutting-affected region), its
//! runs of whole rows, and the stencil's chunks over it.

use super::*;

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
    pub(crate) in_runs: Vec<bool>,
    pub(crate) in_stress: Vec<bool>,
    pub(crate) in_touched: Vec<bool>,
    /// Where the operator has a lattice stencil (and the set may use it): the box chunks
    /// holding a point of `stress` (the stencil's first pass) and of `active` (its second),
    /// sorted.
    pub(crate) stencil_chunks: Option<StencilChunks>,
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
    pub(crate) flags: Vec<u8>,
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
