//! A sparse Cholesky factor (faer, AMD ordering) of a symmetric positive definite matrix,
//! solved in place without allocating. Shared by the projective-dynamics solver (factored
//! once, solved every tick on the real-time path) and the incision's conformal chart
//! (factored and solved once per incision).

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use thiserror::Error;

/// Why a matrix could not be factored.
#[derive(Debug, Error)]
pub enum LltError {
    /// The ordering and symbolic factor could not be made (faer's message).
    #[error("symbolic factorisation failed: {0}")]
    Symbolic(String),
    /// A pivot was not positive (faer's message).
    #[error("the matrix is not positive definite: {0}")]
    NotPositiveDefinite(String),
}

/// L Lᵀ of an n × n matrix, with scratch memory for solves of up to a fixed number of
/// right-hand sides at once.
pub struct SparseLlt {
    n: usize,
    symbolic: SymbolicCholesky<usize>,
    factor: Vec<f64>,
    solve_memory: MemBuffer,
}

impl SparseLlt {
    /// Factors the n × n matrix whose lower triangle is given column by column
    /// (compressed sparse columns: `col_ptr` of n + 1 offsets into `row_idx` and `values`,
    /// rows sorted within each column), for solves of up to `max_rhs` right-hand sides.
    pub fn factor(
        n: usize,
        col_ptr: &[usize],
        row_idx: &[usize],
        values: &[f64],
        max_rhs: usize,
    ) -> Result<Self, LltError> {
        let symbolic_ref = SymbolicSparseColMatRef::new_checked(n, n, col_ptr, None, row_idx);
        let matrix = SparseColMatRef::new(symbolic_ref, values);
        let symbolic = factorize_symbolic_cholesky(
            symbolic_ref,
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| LltError::Symbolic(format!("{e:?}")))?;
        let mut factor = vec![0.0; symbolic.len_val()];
        let mut memory = MemBuffer::new(
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
        );
        symbolic
            .factorize_numeric_llt(
                &mut factor,
                matrix,
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut memory),
                Default::default(),
            )
            .map_err(|e| LltError::NotPositiveDefinite(format!("{e:?}")))?;
        let solve_memory =
            MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(max_rhs, Par::Seq));
        Ok(Self {
            n,
            symbolic,
            factor,
            solve_memory,
        })
    }

    /// Overwrites the `k` right-hand sides in `rhs` (column-major, n rows each; k at most
    /// the `max_rhs` it was factored for) with the solutions. Does not allocate.
    pub fn solve_in_place(&mut self, rhs: &mut [f64], k: usize) {
        let llt = LltRef::new(&self.symbolic, &self.factor);
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut rhs[..k * self.n], self.n, k),
            Par::Seq,
            MemStack::new(&mut self.solve_memory),
        );
    }
}
