//! Residual tension in a surface layer (`[material] prestrain`, cutting-physics.md §4).
//!
//! Living tissue is pre-tensioned: a capsule, a fascia, skin along Langer's lines. Here the
//! points within a layer under the surface carry a constant second Piola–Kirchhoff prestress
//! `S₀ = σ (I − n nᵀ)` in the surface's tangent plane (n the outward normal of the nearest
//! surface point at rest), with `σ = E ε / (1 − ν)`: the stress of an in-plane biaxial stretch
//! ε with the normal free, i.e. the layer's stress-free state is ε shorter than the mesh.
//! It is the small-strain form of the growth metric `F = F_e F_pre` of the spec.
//!
//! Its energy is `ψ = S₀ : E` with `E = ½(FᵀF − I)`, so `P = F S₀` — linear in F, an exact
//! gradient (the rank completion's dependence on p left out, as in the elastic kernels),
//! and its tangent `dP = dF S₀` is constant. The intact body settles against its supports
//! with the layer in tension (the scene's start state); a cut removes the pairs across the
//! wound, the lips' layer points lose the neighbours that balanced their tension, and the
//! wound gapes by itself. The force kernels add `F S₀` to their P where a point has one
//! (`field`), and the whole-body tangent product its constant `dF S₀` (`stress_of`).

use crate::geometry::TriMesh;
use crate::geometry::parry_adapter::TriangleBvh;
use crate::geometry::predicates::closest_point_on_triangle;
use crate::math::{Mat3, Vec3};
use crate::mls::operator::LANES;
use wide::f64x4;

/// The layer's points and their prestress; empty when the material has none.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Prestress {
    /// Layer points, sorted.
    points: Vec<u32>,
    /// S₀ of every body point (zero off the layer) as xx, yy, zz, xy, xz, yz (Pa): what the
    /// force kernels read. Nodes after the body points (virtual points) carry none.
    field: Vec<Sym>,
}

/// A symmetric 3×3 matrix's entries xx, yy, zz, xy, xz, yz.
pub(crate) type Sym = [f64; 6];

/// Whether a point's S₀ is the layer's (its trace is 2σ > 0) or none.
#[inline(always)]
fn carries(s: &Sym) -> bool {
    s[0] + s[1] + s[2] != 0.0
}

/// The slot of entry (r, c) in a [`Sym`].
#[inline(always)]
const fn slot(r: usize, c: usize) -> usize {
    match (r, c) {
        (0, 0) => 0,
        (1, 1) => 1,
        (2, 2) => 2,
        (0, 1) | (1, 0) => 3,
        (0, 2) | (2, 0) => 4,
        _ => 5,
    }
}

impl Prestress {
    /// σ (Pa) for prestrain `eps` in a material of Young's modulus `e` (Pa) and ratio `nu`.
    pub fn tension_pa(e: f64, nu: f64, eps: f64) -> f64 {
        e * eps / (1.0 - nu)
    }

    /// The layer of the body points at `rest` within `depth` (m) of `surface`, each with
    /// `S₀ = sigma (I − n nᵀ)`.
    pub fn surface_layer(rest: &[Vec3], surface: &TriMesh, depth: f64, sigma: f64) -> Self {
        let mut layer = Self::default();
        if sigma == 0.0 || depth <= 0.0 || surface.triangles.is_empty() {
            return layer;
        }
        let bvh = TriangleBvh::build(surface);
        let reach = Vec3::repeat(depth);
        let mut field = vec![[0.0; 6]; rest.len()];
        for (i, x) in rest.iter().enumerate() {
            let mut best: Option<(f64, Vec3, usize)> = None;
            bvh.for_each_overlapping(&(x - reach), &(x + reach), |t| {
                let c = closest_point_on_triangle(x, &surface.corners(t));
                let d = (c - x).norm();
                if best.is_none_or(|(b, _, _)| d < b) {
                    best = Some((d, c, t));
                }
            });
            let Some((d, c, t)) = best.filter(|&(d, _, _)| d <= depth) else {
                continue;
            };
            // The direction to the nearest surface point is the outward normal, smooth
            // round edges and corners; on the surface itself, the triangle's own normal.
            let Some(n) = (c - x)
                .try_normalize(1e-9 * depth.max(d))
                .or_else(|| surface.doubled_area_normal(t).try_normalize(0.0))
            else {
                continue;
            };
            let s0 = (Mat3::identity() - n * n.transpose()) * sigma;
            layer.points.push(i as u32);
            field[i] = std::array::from_fn(|k| {
                let (r, c) = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)][k];
                s0[(r, c)]
            });
        }
        if !layer.points.is_empty() {
            layer.field = field;
        }
        layer
    }

    /// S₀ of point `i` as a matrix (Pa), `None` off the layer.
    pub(crate) fn stress_of(&self, i: usize) -> Option<Mat3> {
        let s = self.field.get(i).filter(|s| carries(s))?;
        Some(Mat3::from_fn(|r, c| s[slot(r, c)]))
    }

    /// S₀ of every body point, for the force kernels; `None` without prestress.
    pub(crate) fn field(&self) -> Option<&[Sym]> {
        (!self.is_empty()).then_some(&self.field[..])
    }

    /// Scales the layer's stress by `ratio` in place (no allocation): the tension is the
    /// material's stiffness times its prestrain, so a change of E (an instructor's
    /// stiffness fault) changes it in proportion.
    pub fn scale(&mut self, ratio: f64) {
        for s in &mut self.field {
            s.iter_mut().for_each(|x| *x *= ratio);
        }
    }

    /// No prestress anywhere.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The layer's points, sorted.
    pub fn points(&self) -> &[u32] {
        &self.points
    }
}

/// S₀ of four points as lanes (zeros where `points` has none), or `None` when none of
/// them has one (the layer is a shell: most of a thick organ's points are not in it).
#[inline(always)]
pub(crate) fn gather(field: &[Sym], points: [Option<usize>; LANES]) -> Option<[f64x4; 6]> {
    let s = points.map(|i| i.and_then(|i| field.get(i)).copied().unwrap_or([0.0; 6]));
    if !s.iter().any(carries) {
        return None;
    }
    Some(std::array::from_fn(|k| {
        f64x4::from([s[0][k], s[1][k], s[2][k], s[3][k]])
    }))
}

/// `P += F S₀` for four points as lanes (F and P by row and column), and their `S₀ : E`
/// (J/m³ per lane), E = ½(FᵀF − I).
#[inline(always)]
pub(crate) fn add_to_lanes(f: &[[f64x4; 3]; 3], s: &[f64x4; 6], p: &mut [[f64x4; 3]; 3]) -> f64x4 {
    for r in 0..3 {
        for c in 0..3 {
            p[r][c] = f[r][0].mul_add(
                s[slot(0, c)],
                f[r][1].mul_add(s[slot(1, c)], f[r][2].mul_add(s[slot(2, c)], p[r][c])),
            );
        }
    }
    // S₀ : E = ½ Σ_kc S_kc (FᵀF)_kc − ½ tr S₀.
    let mut e = f64x4::ZERO;
    for k in 0..3 {
        for c in 0..3 {
            let ftf = f[0][k].mul_add(f[0][c], f[1][k].mul_add(f[1][c], f[2][k] * f[2][c]));
            e = s[slot(k, c)].mul_add(ftf, e);
        }
    }
    let half = f64x4::splat(0.5);
    half * (e - s[0] - s[1] - s[2])
}

/// The same for one point whose F and P are column vectors (x, y, z, 0), if `field` gives
/// it an S₀; its `S₀ : E`, 0 otherwise.
#[inline(always)]
pub(crate) fn add_to_columns(field: &[Sym], i: usize, fc: &[f64x4; 3], pc: &mut [f64x4; 3]) -> f64 {
    let Some(s) = field.get(i).filter(|s| carries(s)) else {
        return 0.0;
    };
    for c in 0..3 {
        pc[c] = fc[0].mul_add(
            f64x4::splat(s[slot(0, c)]),
            fc[1].mul_add(
                f64x4::splat(s[slot(1, c)]),
                fc[2].mul_add(f64x4::splat(s[slot(2, c)]), pc[c]),
            ),
        );
    }
    let dot = |a: usize, b: usize| (fc[a] * fc[b]).to_array()[..3].iter().sum::<f64>();
    let mut e = 0.0;
    for k in 0..3 {
        for c in 0..3 {
            e += s[slot(k, c)] * dot(k, c);
        }
    }
    0.5 * (e - s[0] - s[1] - s[2])
}

#[cfg(test)]
mod tests;
