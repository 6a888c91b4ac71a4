//! Box-shaped bodies for the benchmarks, built through the scene pipeline; a bare lattice
//! cube for tests that cut neighbour lists by hand.

use crate::geometry::organs::box_mesh;
use crate::geometry::{ValidationOptions, validate};
use crate::math::Vec3;
use crate::model::{CoupledModel, Kernel, Neighbourhoods, RestGrid, SamplingParams, SpacingRule};
use crate::progress::Silent;
use crate::scene::Material;
use crate::solver::{Solver, SolverConfig};

/// A box body: its model (lattice, neighbours) and a solver on it.
pub struct BoxBody {
    /// The coupled model.
    pub model: CoupledModel,
    /// The solver.
    pub solver: Solver,
    /// Box edge lengths (m); the box is centred on the origin.
    pub size: Vec3,
}

impl BoxBody {
    /// Points whose rest coordinate on `axis` is at the box's `side` (−1 min, +1 max).
    pub fn face(&self, axis: usize, side: f64) -> Vec<usize> {
        let s = self.model.lattice.spacing;
        let at = side * 0.5 * self.size[axis];
        (0..self.model.points.len())
            .filter(|&i| (self.model.points.rest[i][axis] - at).abs() < 1e-6 * s)
            .collect()
    }

    /// Volume-weighted mean downward (−z) displacement of the face at `side` of `axis`
    /// (m): a cantilever's tip, a column's top.
    pub fn face_sag(&self, axis: usize, side: f64) -> f64 {
        let face = self.face(axis, side);
        let rest = &self.model.points.rest;
        let p = self.solver.positions();
        let vol = &self.model.points.volume_m3;
        let total: f64 = face.iter().map(|&i| vol[i]).sum();
        -face
            .iter()
            .map(|&i| (p[i].z - rest[i].z) * vol[i])
            .sum::<f64>()
            / total
    }

    /// Number of lattice points along `axis`.
    pub fn points_along(&self, axis: usize) -> usize {
        self.model.lattice.dims[axis]
    }

    /// Stands the box on rollers on its −`axis` face: the face holds `axis` only; of the
    /// rigid motions left, the face's point nearest its centre is pinned, and the point
    /// farthest along the first other axis on the centre row also holds the second (the
    /// spin about `axis`).
    pub fn on_rollers(&mut self, axis: usize) {
        let (a, b) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let base = self.face(axis, -1.0);
        let rest = &self.model.points.rest;
        let nearest = |key: &dyn Fn(usize) -> f64| {
            *base
                .iter()
                .min_by(|&&i, &&j| key(i).total_cmp(&key(j)))
                .expect("a face has points")
        };
        let centre = nearest(&|i| rest[i][a].abs() + rest[i][b].abs());
        let far = nearest(&|i| rest[i][b].abs() * 1e3 - rest[i][a]);
        let mut rollers = [false; 3];
        rollers[axis] = true;
        for &i in &base {
            self.solver.fix(i, rollers);
        }
        self.solver.fix(centre, [true; 3]);
        rollers[b] = true;
        self.solver.fix(far, rollers);
    }

    /// Cuts the body by `triangles` of Σ (rest space, the product's visibility criterion):
    /// the pairs they cross are removed from its neighbour lists and the solver's rows;
    /// how many, and the points whose lists changed (sorted).
    pub fn cut_by(&mut self, triangles: &[[Vec3; 3]]) -> (usize, Vec<u32>) {
        let (mut changed, mut candidates) = (Vec::new(), Vec::new());
        let mut removed = 0;
        for tri in triangles {
            removed += crate::cut::cut_pairs(
                tri,
                &self.model.points.rest,
                &self.model.grid,
                &mut self.model.neighbours,
                self.model.kernel.support_m,
                &mut changed,
                &mut candidates,
            );
        }
        changed.sort_unstable();
        changed.dedup();
        self.solver
            .topology_changed(&changed, &self.model.neighbours);
        (removed, changed)
    }
}

/// The quasi-static solver, with the product's hourglass control or (`hourglass` false)
/// without it: the bare discretisation.
pub fn static_config(hourglass: bool) -> SolverConfig {
    let base = SolverConfig::default();
    SolverConfig {
        mode: crate::solver::SolverMode::QuasiStatic,
        hourglass_alpha: if hourglass { base.hourglass_alpha } else { 0.0 },
        ..base
    }
}

/// A box of `size` (m), centred on the origin, sampled with `points_across` points along its
/// shortest side (so points sit on all faces when the sides are multiples of the spacing).
pub fn box_body(
    size: Vec3,
    points_across: usize,
    material: &Material,
    support_ratio: f64,
    config: SolverConfig,
) -> BoxBody {
    let spacing = size.min() / (points_across - 1) as f64;
    let mesh = box_mesh(size, [1, 1, 1]);
    let surface = validate(mesh, "benchmark box", &ValidationOptions::default())
        .expect("a box is a valid mesh")
        .mesh;
    let params = SamplingParams {
        spacing: SpacingRule::Spacing(spacing),
        support_ratio,
        ..SamplingParams::default()
    };
    let model = CoupledModel::build(surface, &params, material.density_kg_m3, &mut Silent)
        .expect("a box always samples");
    let solver = Solver::for_model(&model, material, config);
    BoxBody {
        model,
        solver,
        size,
    }
}

/// Timoshenko tip deflection of a square cantilever (m): `PL³/(3EI) + PL/(κGA)` with
/// `κ = 10(1+ν)/(12+11ν)`.
pub fn timoshenko_tip_deflection(load_n: f64, length: f64, side: f64, e: f64, nu: f64) -> f64 {
    let inertia = side.powi(4) / 12.0;
    let area = side * side;
    let shear = e / (2.0 * (1.0 + nu));
    let kappa = 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu);
    load_n * length.powi(3) / (3.0 * e * inertia) + load_n * length / (kappa * shear * area)
}

/// A cube of n × n × n points `spacing` apart from the origin, for tests that cut a
/// lattice's neighbour lists by hand.
pub struct LatticeCube {
    /// The points, index (i·n + j)·n + k for lattice cell (i, j, k).
    pub rest: Vec<Vec3>,
    n: usize,
    spacing: f64,
}

impl LatticeCube {
    /// The cube of `n`³ points `spacing` apart.
    pub fn new(n: usize, spacing: f64) -> Self {
        let mut rest = Vec::with_capacity(n * n * n);
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    rest.push(Vec3::new(i as f64, j as f64, k as f64) * spacing);
                }
            }
        }
        Self { rest, n, spacing }
    }

    /// The index of the middle point, (n/2, n/2, n/2).
    pub fn centre(&self) -> usize {
        let c = self.n / 2;
        self.id(c, c, c)
    }

    /// The index of point (i, j, k).
    pub fn id(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.n + j) * self.n + k
    }

    /// The neighbour lists of points at `rest` (the cube's, perhaps moved) within the
    /// solver's support of two spacings, with room for `headroom` more per point.
    pub fn neighbours(&self, rest: &[Vec3], headroom: usize) -> Neighbourhoods {
        let h = 2.0 * self.spacing;
        Neighbourhoods::build(rest, &RestGrid::build(rest, h), h, headroom)
    }

    /// A solver for soft tissue (5 kPa, ν 0.45) on points at `rest` (the cube's, moved or
    /// with nodes after them), support two spacings, the default configuration.
    pub fn soft_solver(
        &self,
        rest: &[Vec3],
        volume: &[f64],
        mass: &[f64],
        neighbours: &Neighbourhoods,
    ) -> Solver {
        let spacing = self.spacing;
        let kernel = Kernel {
            support_m: 2.0 * spacing,
        };
        let config = SolverConfig::default();
        Solver::new(
            rest, volume, mass, neighbours, kernel, spacing, None, 5e3, 0.45, config,
        )
    }

    /// The centre point's four neighbours in its layer (±x, ±y).
    pub fn layer_around_centre(&self) -> [u32; 4] {
        let c = self.n / 2;
        [
            self.id(c + 1, c, c),
            self.id(c - 1, c, c),
            self.id(c, c + 1, c),
            self.id(c, c - 1, c),
        ]
        .map(|i| i as u32)
    }
}

/// Cuts point `i` down to the neighbours in `keep` (its other pairs removed both ways, as
/// a cut would); the points whose lists changed, `i` first.
pub fn cut_down_to(neighbours: &mut Neighbourhoods, i: usize, keep: &[u32]) -> Vec<u32> {
    let mut changed = vec![i as u32];
    for j in neighbours.of(i).to_vec() {
        if !keep.contains(&j) {
            neighbours.remove(i, j);
            neighbours.remove(j as usize, i as u32);
            changed.push(j);
        }
    }
    changed
}
