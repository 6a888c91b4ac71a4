//! The implicit mode's two-level preconditioner: the diagonal plus a coarse correction,
//! `P⁻¹ = D⁻¹ + Rᵀ (R P_f Rᵀ)⁻¹ R`, where R sums the points of each 2×2×2 block of lattice
//! cells (an aggregate) and P_f is the projective-dynamics matrix the factored
//! preconditioner uses. The diagonal takes the error's fast modes, the coarse solve its
//! slow ones, whose count is what made Jacobi's iterations grow with 1/spacing; the coarse
//! matrix has an eighth of the unknowns and far less fill than the fine one.

use std::collections::HashMap;

use super::Solver;
use super::projective::ComponentSystem;
use crate::math::Vec3;

pub(super) struct Coarse {
    /// Point → aggregate, `u32::MAX` for a point fixed in every direction.
    aggregate_of: Vec<u32>,
    system: ComponentSystem,
    rc: Vec<Vec3>,
    zc: Vec<Vec3>,
}

impl Coarse {
    /// Aggregates the points of `s` and factors `R P_f Rᵀ`, P_f given by its full columns
    /// (`projective::assemble_columns`).
    pub(super) fn build(s: &Solver, fine: &[Vec<(u32, f64)>]) -> Result<Self, String> {
        let n = s.p.len();
        let mut origin = Vec3::repeat(f64::INFINITY);
        for x in &s.rest {
            origin = origin.inf(x);
        }
        let block = 2.0 * s.spacing_m;
        let mut index: HashMap<[i64; 3], u32> = HashMap::new();
        let mut aggregate_of = vec![u32::MAX; n];
        for i in 0..n {
            if s.fixed[i] == [true; 3] {
                continue;
            }
            let cell = (s.rest[i] - origin) / block;
            let key = [cell.x as i64, cell.y as i64, cell.z as i64];
            let next = index.len() as u32;
            aggregate_of[i] = *index.entry(key).or_insert(next);
        }
        let count = index.len();
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); count];
        for (i, &a) in aggregate_of.iter().enumerate() {
            if a != u32::MAX {
                members[a as usize].push(i as u32);
            }
        }
        let mut acc = vec![0.0; count];
        let mut listed = vec![false; count];
        let mut touched: Vec<usize> = Vec::new();
        let mut columns = Vec::with_capacity(count);
        for group in &members {
            touched.clear();
            for &k in group {
                for &(r, v) in &fine[k as usize] {
                    let a = aggregate_of[r as usize];
                    if a == u32::MAX {
                        continue;
                    }
                    let a = a as usize;
                    if !std::mem::replace(&mut listed[a], true) {
                        touched.push(a);
                    }
                    acc[a] += v;
                }
            }
            touched.sort_unstable();
            columns.push(
                touched
                    .iter()
                    .map(|&a| (a as u32, std::mem::take(&mut acc[a])))
                    .collect::<Vec<_>>(),
            );
            for &a in &touched {
                listed[a] = false;
            }
        }
        let mut system = ComponentSystem::factor(&columns, &vec![false; count], 0)?;
        system.components = vec![0, 1, 2];
        Ok(Self {
            aggregate_of,
            system,
            rc: vec![Vec3::zeros(); count],
            zc: vec![Vec3::zeros(); count],
        })
    }

    /// Adds `Rᵀ (R P_f Rᵀ)⁻¹ R r` to `z` over the awake points (P_f is the matrix over h²).
    pub(super) fn add_correction(&mut self, r: &[Vec3], z: &mut [Vec3], h: f64, active: &[u32]) {
        self.rc.iter_mut().for_each(|x| *x = Vec3::zeros());
        self.zc.iter_mut().for_each(|x| *x = Vec3::zeros());
        for &i in active {
            let a = self.aggregate_of[i as usize];
            if a != u32::MAX {
                self.rc[a as usize] += r[i as usize] / (h * h);
            }
        }
        self.system.solve(&self.rc, &mut self.zc);
        for &i in active {
            let a = self.aggregate_of[i as usize];
            if a != u32::MAX {
                z[i as usize] += self.zc[a as usize];
            }
        }
    }
}
