//! The blade's faces inside stiff mode's global solve (physics.md §2.4, cutting-physics.md
//! §2): after each global solve, the samples the blade holds are put back on its faces
//! by one-sided constraints solved exactly against the same matrix — the Schur complement
//! of the contacts, `C λ = −g`, with `C_st = (n_s·n_t) S_s A⁻¹ S_tᵀ`, λ ≥ 0 by dropping
//! the samples the solve would pull — so the whole body deforms around the blade instead
//! of the few points under it being moved after the step.
//!
//! `A⁻¹ S_sᵀ` is one scalar solve per sample (the matrix is `L ⊗ I₃`), kept in a slot
//! while the sample keeps its place in the blade's list and the matrix is the same: a
//! press asks for it when a sample first touches. Coulomb friction follows the normal
//! solve through the same matrix: each pushing sample is taken back along its face toward
//! where it stuck (`S A⁻¹ Sᵀ` per component, the matrix being `L ⊗ I₃`), at most μ × its
//! normal push; past that it slides, and on the global solve's last iteration sticks again
//! where it got to, as the explicit projection does (docs/CUTTING-DECISIONS.md, "Stiff
//! mode").

use super::blade::{BLADE_FRICTION, BladeBody};
use crate::math::Vec3;
use crate::sparse_llt::SparseLlt;

/// Samples held at once in one solve; more are left to the next iteration.
pub(super) const MAX_HELD: usize = 64;
/// Rounds of dropping the samples the solve would pull.
const ACTIVE_SET_ROUNDS: usize = 4;

/// Scratch and kept solves for the contacts, sized when the projective system is built.
pub(super) struct FaceContacts {
    /// Free rows of the (single) system.
    rows: usize,
    /// `A⁻¹ S_sᵀ` per slot, `rows` values each.
    z: Vec<f64>,
    /// The sample each slot holds the solve of (its rest place, its index), and when it was
    /// last used.
    key: Vec<Option<(Vec3, usize)>>,
    used: Vec<u64>,
    clock: u64,
    /// This iteration's held samples: (sample, slot, normal, offset).
    held: Vec<(usize, usize, Vec3, f64)>,
    gap: Vec<f64>,
    lambda: Vec<f64>,
    /// `S_a A⁻¹ S_bᵀ` of the held samples (k × k, row-major), from the last normal solve:
    /// the normal Schur complement weighs it by `n_a·n_b`, friction solves with it as is.
    coupling: Vec<f64>,
    schur: Vec<f64>,
    /// Friction's scratch: each held sample's way back to its anchor, the push that takes
    /// it there, one component's right-hand side.
    slip: Vec<Vec3>,
    tangent: Vec<Vec3>,
    rhs: Vec<f64>,
    sliding: Vec<bool>,
    /// The force the contacts put on the tissue at the last iteration (N).
    pub(super) on_tissue: Vec3,
}

impl FaceContacts {
    pub(super) fn with_room(rows: usize) -> Self {
        Self {
            rows,
            z: vec![0.0; MAX_HELD * rows],
            key: vec![None; MAX_HELD],
            used: vec![0; MAX_HELD],
            clock: 0,
            held: Vec::with_capacity(MAX_HELD),
            gap: Vec::with_capacity(MAX_HELD),
            lambda: Vec::with_capacity(MAX_HELD),
            coupling: vec![0.0; MAX_HELD * MAX_HELD],
            schur: vec![0.0; MAX_HELD * MAX_HELD],
            slip: Vec::with_capacity(MAX_HELD),
            tangent: Vec::with_capacity(MAX_HELD),
            rhs: Vec::with_capacity(MAX_HELD),
            sliding: vec![false; MAX_HELD],
            on_tissue: Vec3::zeros(),
        }
    }

    /// Puts the samples `blade` holds at `p` back on its faces through the system
    /// (`llt`, free rows `row_of` / `point_of`); `rest` are the points' rest places (the
    /// samples' identity for the kept solves). On the `last` iteration of the global solve
    /// the samples that slid stick again where they got to.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn resolve(
        &mut self,
        blade: &mut BladeBody,
        p: &mut [Vec3],
        rest: &[Vec3],
        llt: &mut SparseLlt,
        row_of: &[u32],
        point_of: &[u32],
        last: bool,
    ) {
        self.on_tissue = Vec3::zeros();
        self.clock += 1;
        self.held.clear();
        for s in 0..blade.len() {
            if self.held.len() == MAX_HELD {
                break;
            }
            let free = |k: usize| row_of[k] != u32::MAX;
            let Some((n, offset)) = blade.constraint(s, p, free) else {
                continue;
            };
            if n.dot(&blade.position(s, p)) - offset >= 0.0 {
                continue;
            }
            let slot = self.slot_for(s, blade, rest, llt, row_of);
            self.held.push((s, slot, n, offset));
        }
        for round in 1..=ACTIVE_SET_ROUNDS {
            if self.held.is_empty() {
                return;
            }
            self.solve_held(blade, p, row_of);
            if round == ACTIVE_SET_ROUNDS {
                // Out of rounds: what would still pull pushes nothing.
                self.lambda.iter_mut().for_each(|l| *l = l.max(0.0));
                break;
            }
            let before = self.held.len();
            let mut k = 0;
            while k < self.held.len() {
                if self.lambda[k] < 0.0 {
                    self.held.swap_remove(k);
                    self.lambda.swap_remove(k);
                } else {
                    k += 1;
                }
            }
            if self.held.len() == before {
                break;
            }
        }
        // The λ solved for the set that pushes: apply them. (A round that drops samples
        // is solved again, so these are never a larger set's.)
        for k in 0..self.held.len() {
            let (_, slot, n, _) = self.held[k];
            self.push(slot, n * self.lambda[k], p, point_of);
        }
        self.friction(blade, p, point_of, last);
    }

    /// Moves the points by `push` through slot `slot`'s solve, and books it on the tissue.
    fn push(&mut self, slot: usize, push: Vec3, p: &mut [Vec3], point_of: &[u32]) {
        self.on_tissue += push;
        let rows = self.rows;
        let z = &self.z[slot * rows..(slot + 1) * rows];
        for (row, &i) in point_of.iter().enumerate() {
            if z[row] != 0.0 {
                p[i as usize] += push * z[row];
            }
        }
    }

    /// Coulomb friction on the held samples after their normal push: `C_t λ_t = slip` for
    /// the pushes that take each back to its anchor (`C_t` = `S A⁻¹ Sᵀ`, the same for the
    /// three components), each bounded by μ × its normal λ.
    fn friction(&mut self, blade: &mut BladeBody, p: &mut [Vec3], point_of: &[u32], last: bool) {
        let k = self.held.len();
        if k == 0 {
            return;
        }
        self.slip.clear();
        for &(s, ..) in &self.held {
            self.slip
                .push(blade.back_to_anchor(s, p).unwrap_or_else(Vec3::zeros));
        }
        // The held set is the last normal solve's: its coupling is the friction's matrix.
        self.schur[..k * k].copy_from_slice(&self.coupling[..k * k]);
        factor_spd(&mut self.schur[..k * k], k);
        self.tangent.clear();
        self.tangent.resize(k, Vec3::zeros());
        for d in 0..3 {
            self.rhs.clear();
            self.rhs.extend(self.slip.iter().map(|v| v[d]));
            solve_factored(&self.schur[..k * k], &mut self.rhs, k);
            for (t, r) in self.tangent.iter_mut().zip(&self.rhs) {
                t[d] = *r;
            }
        }
        // Bounded per sample by μ × its normal λ. (Through the coupling a push may have a
        // part along another sample's normal; the next iteration's normal solve takes it
        // out, all but the last iteration's.)
        for a in 0..k {
            let most = BLADE_FRICTION * self.lambda[a].max(0.0);
            let size = self.tangent[a].norm();
            self.sliding[a] = size > most;
            if self.sliding[a] {
                self.tangent[a] *= most / size.max(1e-300);
            }
        }
        for a in 0..k {
            let (_, slot, ..) = self.held[a];
            let tangent = self.tangent[a];
            if tangent != Vec3::zeros() {
                self.push(slot, tangent, p, point_of);
            }
        }
        // A sample that slid sticks again where all the pushes left it.
        if last {
            for a in 0..k {
                if self.sliding[a] {
                    blade.stick_here(self.held[a].0, p);
                }
            }
        }
    }

    /// The slot holding sample `s`'s solve, solving it into the least recently used slot
    /// if none does.
    fn slot_for(
        &mut self,
        s: usize,
        blade: &BladeBody,
        rest: &[Vec3],
        llt: &mut SparseLlt,
        row_of: &[u32],
    ) -> usize {
        let key = (blade.position(s, rest), s);
        if let Some(slot) = self.key.iter().position(|k| *k == Some(key)) {
            self.used[slot] = self.clock;
            return slot;
        }
        let slot = (0..MAX_HELD)
            .min_by_key(|&k| self.used[k])
            .expect("there are slots");
        let rows = self.rows;
        let z = &mut self.z[slot * rows..(slot + 1) * rows];
        z.fill(0.0);
        for (k, w) in blade.row(s) {
            let r = row_of[k];
            if r != u32::MAX {
                z[r as usize] += w;
            }
        }
        llt.solve_in_place(z, 1);
        self.key[slot] = Some(key);
        self.used[slot] = self.clock;
        slot
    }

    /// λ for the held samples at `p` (no positions changed): `C λ = −g`.
    fn solve_held(&mut self, blade: &BladeBody, p: &[Vec3], row_of: &[u32]) {
        let k = self.held.len();
        let rows = self.rows;
        self.gap.clear();
        for &(s, _, n, offset) in &self.held {
            self.gap.push(n.dot(&blade.position(s, p)) - offset);
        }
        for a in 0..k {
            let (sa, _, na, _) = self.held[a];
            for b in 0..=a {
                let (_, slot_b, nb, _) = self.held[b];
                let zb = &self.z[slot_b * rows..(slot_b + 1) * rows];
                let mut s_z = 0.0;
                for (point, w) in blade.row(sa) {
                    let r = row_of[point];
                    if r != u32::MAX {
                        s_z += w * zb[r as usize];
                    }
                }
                self.coupling[a * k + b] = s_z;
                self.coupling[b * k + a] = s_z;
                let c = na.dot(&nb) * s_z;
                self.schur[a * k + b] = c;
                self.schur[b * k + a] = c;
            }
        }
        self.lambda.clear();
        self.lambda.extend(self.gap.iter().map(|g| -g));
        solve_spd(&mut self.schur[..k * k], &mut self.lambda, k);
    }
}

/// Solves `C x = b` in place for a symmetric positive semi-definite `k × k` C (row-major,
/// overwritten by its Cholesky factor): pivots at or below a relative floor (two samples
/// on the same points and face) are taken as that floor.
fn solve_spd(c: &mut [f64], b: &mut [f64], k: usize) {
    factor_spd(c, k);
    solve_factored(c, b, k);
}

/// The Cholesky factor of a symmetric positive semi-definite `k × k` C, in place (lower
/// triangle), pivots floored as [`solve_spd`] says.
fn factor_spd(c: &mut [f64], k: usize) {
    let scale = (0..k).map(|i| c[i * k + i]).fold(0.0, f64::max);
    let floor = scale * 1e-10 + f64::MIN_POSITIVE;
    for j in 0..k {
        let mut d = c[j * k + j];
        for m in 0..j {
            d -= c[j * k + m] * c[j * k + m];
        }
        let d = d.max(floor).sqrt();
        c[j * k + j] = d;
        for i in j + 1..k {
            let mut v = c[i * k + j];
            for m in 0..j {
                v -= c[i * k + m] * c[j * k + m];
            }
            c[i * k + j] = v / d;
        }
    }
}

/// Solves `C x = b` in place with C's factor from [`factor_spd`].
fn solve_factored(c: &[f64], b: &mut [f64], k: usize) {
    for i in 0..k {
        let mut v = b[i];
        for m in 0..i {
            v -= c[i * k + m] * b[m];
        }
        b[i] = v / c[i * k + i];
    }
    for i in (0..k).rev() {
        let mut v = b[i];
        for m in i + 1..k {
            v -= c[m * k + i] * b[m];
        }
        b[i] = v / c[i * k + i];
    }
}

#[cfg(test)]
mod tests {
    use super::solve_spd;

    #[test]
    fn the_small_cholesky_solves_a_spd_system() {
        let mut c = vec![4.0, 2.0, 0.6, 2.0, 5.0, 1.0, 0.6, 1.0, 3.0];
        let a = c.clone();
        let x = [1.0, -2.0, 0.5];
        let mut b: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|j| a[i * 3 + j] * x[j]).sum())
            .collect();
        solve_spd(&mut c, &mut b, 3);
        for i in 0..3 {
            assert!((b[i] - x[i]).abs() < 1e-12, "{b:?}");
        }
    }
}
