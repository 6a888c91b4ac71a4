//! What holds the body through its surface (cutting-physics.md §1): elastic attachments
//! tie surface vertices to their rest places; a tray pushes samples of the surface (one
//! per lattice spacing, `pipeline::supports`) out of its plane, with Coulomb friction.
//! Both are "held vertices" here.
//!
//! A held vertex follows the points as the surface does, linearised about the rest state:
//! `x_v = Σ_k ŵ_vk p_k + (X_v − Σ_k ŵ_vk X_k)` (the F_k term's change is left out), so its
//! force reaches the points through the embedding's transpose, `f_k = ŵ_vk f_v`, and the
//! springs are exactly the gradient of their energy: the explicit step counts their work
//! as applied work, and the stiffness product (for the critical step and static solves)
//! is `Σ_v k_v ŵ_v ŵ_vᵀ`.

use super::contact_set::ContactSet;
use super::embedded::EmbeddedRows;
use crate::math::Vec3;

/// The tray's plane: `n·x ≥ offset` outside it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrayPlane {
    /// Unit normal toward the body.
    pub normal: Vec3,
    /// `n·x` on the plane (m).
    pub offset: f64,
    /// Coulomb friction coefficient.
    pub friction: f64,
}

impl TrayPlane {
    /// How far `x` is above the plane (m, negative inside the tray).
    pub fn gap(&self, x: &Vec3) -> f64 {
        self.normal.dot(x) - self.offset
    }
}

/// One held vertex, as the caller describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldVertex {
    /// The points it follows and their weights (summing to 1).
    pub row: Vec<(u32, f64)>,
    /// Its rest position (m).
    pub rest: Vec3,
    /// Attachment stiffness k_a·A_v (N/m); 0 for none.
    pub spring_n_per_m: f64,
    /// Tray penalty stiffness k_t·A_v (N/m); 0 when it cannot touch the tray.
    pub tray_n_per_m: f64,
}

/// The held vertices of a body, their weights in compressed rows, and the tray's
/// friction state.
#[derive(Debug, Clone, PartialEq)]
pub struct Held {
    rows: EmbeddedRows,
    rest: Vec<Vec3>,
    spring: Vec<f64>,
    tray_stiffness: Vec<f64>,
    tray: Option<TrayPlane>,
    /// Where each vertex sticks on the tray (its tangential anchor), while it touches.
    anchor: Vec<Vec3>,
    touching: Vec<bool>,
    /// The vertices a static solve holds on the tray.
    set: ContactSet,
    /// Each point's rest height along the tray's normal (m; empty without a tray).
    rest_height: Vec<f64>,
    /// The vertices following at least one integrated point ([`Held::wake`]): the only
    /// ones whose forces an explicit tick over a restricted active set reads.
    awake: Vec<u32>,
}

/// Which held vertices a force evaluation takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Vertices {
    /// Every one (static solves, the stiff mode: the whole body moves).
    All,
    /// Those following an integrated point (the explicit tick).
    Awake,
}

impl Held {
    /// The held vertices `vertices` over points at rest positions `rest_points`, with the
    /// tray `tray` (if any).
    pub fn new(vertices: &[HeldVertex], rest_points: &[Vec3], tray: Option<TrayPlane>) -> Self {
        Held {
            rows: EmbeddedRows::new(vertices.iter().map(|v| (&v.row[..], v.rest)), rest_points),
            rest: vertices.iter().map(|v| v.rest).collect(),
            spring: vertices.iter().map(|v| v.spring_n_per_m).collect(),
            tray_stiffness: vertices
                .iter()
                .map(|v| if tray.is_some() { v.tray_n_per_m } else { 0.0 })
                .collect(),
            tray,
            anchor: vec![Vec3::zeros(); vertices.len()],
            touching: vec![false; vertices.len()],
            set: ContactSet::new(vertices.len()),
            rest_height: tray.map_or(Vec::new(), |t| {
                rest_points.iter().map(|x| t.normal.dot(x)).collect()
            }),
            awake: (0..vertices.len() as u32).collect(),
        }
    }

    /// Number of held vertices.
    pub fn len(&self) -> usize {
        self.rest.len()
    }

    /// Whether no vertex is held.
    pub fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }

    /// The points the held vertices follow.
    pub fn reached(&self) -> &[u32] {
        self.rows.reached()
    }

    /// Vertex v's position with the points at `p`.
    pub fn position(&self, v: usize, p: &[Vec3]) -> Vec3 {
        self.rows.position(v, p)
    }

    /// Lists the vertices that follow a point with `is_active` set (call when the active
    /// set changes; no allocation).
    pub fn wake(&mut self, is_active: &[bool]) {
        self.awake.clear();
        for v in 0..self.rest.len() {
            if self.rows.row(v).any(|(k, _)| is_active[k]) {
                self.awake.push(v as u32);
            }
        }
    }

    /// Writes the forces of the held vertices `which` takes on the points at `p` into
    /// `out` and returns their stored energy (J). `out` is zeroed first on the points those
    /// vertices follow (with [`Vertices::All`], on every point any vertex follows); other
    /// entries are left as they are. With `slide`, a vertex on the tray whose tangential
    /// pull exceeds friction slips (its anchor follows), and one that leaves the tray lets
    /// go; without it the friction state is only read (a static solve's trial positions
    /// must not move it).
    pub fn forces(&mut self, p: &[Vec3], out: &mut [Vec3], slide: bool, which: Vertices) -> f64 {
        match which {
            Vertices::All => {
                for &k in self.rows.reached() {
                    out[k as usize] = Vec3::zeros();
                }
            }
            Vertices::Awake => {
                for &v in &self.awake {
                    for &k in self.rows.points_of(v as usize) {
                        out[k as usize] = Vec3::zeros();
                    }
                }
            }
        }
        let sunk = self.deepest_sink(p);
        let mut energy = 0.0;
        for index in 0..self.count(which) {
            let v = self.vertex(which, index);
            // A tray sample whose points have not come down as far as its height above
            // the tray cannot touch it (its weights are a convex combination): no need to
            // place it. Most of a body's samples, most of the time.
            if self.spring[v] == 0.0
                && !self.touching[v]
                && !self.set.frozen_pressed(v)
                && self.tray.is_some_and(|t| t.gap(&self.rest[v]) > sunk)
            {
                continue;
            }
            let x = self.position(v, p);
            let mut f = Vec3::zeros();
            let k = self.spring[v];
            if k > 0.0 {
                let d = x - self.rest[v];
                f -= d * k;
                energy += 0.5 * k * d.norm_squared();
            }
            if let Some(tray) = self.tray
                && self.tray_stiffness[v] > 0.0
            {
                let (ft, e) = self.tray_force(v, &x, &tray, slide);
                f += ft;
                energy += e;
            }
            if f != Vec3::zeros() {
                self.rows.spread(v, f, out);
            }
        }
        energy
    }

    /// How far any point a vertex follows has come down toward the tray since rest (m;
    /// minus infinity without a tray).
    fn deepest_sink(&self, p: &[Vec3]) -> f64 {
        let Some(tray) = self.tray else {
            return f64::NEG_INFINITY;
        };
        self.rows
            .reached()
            .iter()
            .map(|&k| self.rest_height[k as usize] - tray.normal.dot(&p[k as usize]))
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// The tray's force on vertex v at `x` and its stored energy: a penalty out of the
    /// plane, and a tangential spring to the vertex's anchor bounded by μ times it.
    fn tray_force(&mut self, v: usize, x: &Vec3, tray: &TrayPlane, slide: bool) -> (Vec3, f64) {
        let k = self.tray_stiffness[v];
        let n = tray.normal;
        let gap = tray.gap(x);
        if !self.set.pressed(v, gap) {
            if slide {
                self.touching[v] = false;
            }
            return (Vec3::zeros(), 0.0);
        }
        let tangential = x - n * n.dot(x);
        if !self.touching[v] {
            if !slide {
                // A trial position touching where the vertex does not yet: no friction.
                return (n * (-k * gap), 0.5 * k * gap * gap);
            }
            self.touching[v] = true;
            self.anchor[v] = tangential;
        }
        let normal_force = -k * gap;
        let mut pull = (self.anchor[v] - tangential) * k;
        let limit = tray.friction * normal_force;
        let size = pull.norm();
        if size > limit {
            pull *= limit / size;
            if slide {
                self.anchor[v] = tangential + pull / k;
            }
        }
        let stretch = pull.norm_squared() / k;
        (n * normal_force + pull, 0.5 * k * gap * gap + 0.5 * stretch)
    }

    /// `y += K x` with K = −∂f/∂p of the springs and of the tray contacts as they stand: a
    /// vertex stuck to its anchor holds in every direction, a free one along the normal.
    /// Over the vertices `which` takes (the implicit tick: those following an awake point).
    pub fn add_stiffness_product(&self, p: &[Vec3], x: &[Vec3], y: &mut [Vec3], which: Vertices) {
        for index in 0..self.count(which) {
            let v = self.vertex(which, index);
            let k = self.spring[v];
            let moved = self.rows.moved(v, x);
            let mut f = moved * k;
            if let Some(tray) = self.tray
                && self.tray_stiffness[v] > 0.0
                && self.set.pressed(v, tray.gap(&self.position(v, p)))
            {
                let kt = self.tray_stiffness[v];
                f += if self.touching[v] {
                    moved * kt
                } else {
                    tray.normal * (kt * tray.normal.dot(&moved))
                };
            }
            if f != Vec3::zeros() {
                self.rows.spread(v, f, y);
            }
        }
    }

    /// How many vertices `which` takes.
    fn count(&self, which: Vertices) -> usize {
        match which {
            Vertices::All => self.rest.len(),
            Vertices::Awake => self.awake.len(),
        }
    }

    /// The `index`th vertex `which` takes.
    fn vertex(&self, which: Vertices, index: usize) -> usize {
        match which {
            Vertices::All => index,
            Vertices::Awake => self.awake[index] as usize,
        }
    }

    /// Freezes the vertices a static solve holds on the tray to those in it with the
    /// points at `p`; returns how many changed (`contact_set`).
    pub fn freeze(&mut self, p: &[Vec3]) -> usize {
        let Some(tray) = self.tray else {
            return 0;
        };
        let (rows, stiffness) = (&self.rows, &self.tray_stiffness);
        self.set.freeze(
            (0..rows.len())
                .filter(|&v| stiffness[v] > 0.0)
                .map(|v| (v, tray.gap(&rows.position(v, p)))),
        )
    }

    /// Each vertex on the tray while inside its plane again.
    pub fn thaw(&mut self) {
        self.set.thaw();
    }

    /// The vertices pressed into the tray with the points at `p`.
    pub fn on_tray(&self, p: &[Vec3]) -> usize {
        let Some(tray) = self.tray else {
            return 0;
        };
        (0..self.rest.len())
            .filter(|&v| self.tray_stiffness[v] > 0.0 && tray.gap(&self.position(v, p)) < 0.0)
            .count()
    }

    /// The tray, if the body has one.
    pub fn tray(&self) -> Option<&TrayPlane> {
        self.tray.as_ref()
    }

    /// Vertices holding a friction anchor on the tray.
    #[cfg(test)]
    fn touching(&self) -> usize {
        self.touching.iter().filter(|&&t| t).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_vertex(spring: f64, tray: f64) -> (Held, Vec<Vec3>) {
        let rest = vec![Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.01, 0.0, 0.0)];
        let v = HeldVertex {
            row: vec![(0, 0.25), (1, 0.75)],
            rest: Vec3::new(0.0075, 0.0, 0.0),
            spring_n_per_m: spring,
            tray_n_per_m: tray,
        };
        let plane = TrayPlane {
            normal: Vec3::z(),
            offset: 0.0,
            friction: 0.5,
        };
        (Held::new(&[v], &rest, Some(plane)), rest)
    }

    /// The spring's force is the negative gradient of its energy, and reaches the points
    /// by the weights (their sum is the vertex's force).
    #[test]
    fn attachment_forces_are_the_energy_gradient() {
        let (mut held, rest) = one_vertex(100.0, 0.0);
        let p: Vec<Vec3> = rest
            .iter()
            .map(|x| x + Vec3::new(1e-3, -2e-3, 3e-3))
            .collect();
        let mut f = vec![Vec3::zeros(); 2];
        let e = held.forces(&p, &mut f, true, Vertices::All);
        assert!((e - 0.5 * 100.0 * 14e-6).abs() < 1e-15);
        let total = f[0] + f[1];
        assert!((total - Vec3::new(-0.1, 0.2, -0.3)).norm() < 1e-12);
        assert!((f[1] - total * 0.75).norm() < 1e-12);
        // K x against a finite difference of the forces.
        let dx = vec![Vec3::new(1e-6, 0.0, 0.0), Vec3::new(0.0, 2e-6, 0.0)];
        let mut kx = vec![Vec3::zeros(); 2];
        held.add_stiffness_product(&p, &dx, &mut kx, Vertices::All);
        let moved: Vec<Vec3> = p.iter().zip(&dx).map(|(a, b)| a + b).collect();
        let mut f2 = vec![Vec3::zeros(); 2];
        held.forces(&moved, &mut f2, true, Vertices::All);
        for k in 0..2 {
            assert!((f[k] - f2[k] - kx[k]).norm() < 1e-12);
        }
    }

    /// A vertex that follows no integrated point is left out of the explicit tick's
    /// forces: nothing written, no energy; woken, it is back.
    #[test]
    fn an_asleep_vertex_costs_nothing() {
        let (mut held, rest) = one_vertex(100.0, 0.0);
        let p: Vec<Vec3> = rest.iter().map(|x| x + Vec3::new(1e-3, 0.0, 0.0)).collect();
        let mut f = vec![Vec3::new(7.0, 7.0, 7.0); 2];
        held.wake(&[false, false]);
        assert_eq!(held.forces(&p, &mut f, true, Vertices::Awake), 0.0);
        assert_eq!(f, vec![Vec3::new(7.0, 7.0, 7.0); 2]);
        held.wake(&[false, true]);
        assert!(held.forces(&p, &mut f, true, Vertices::Awake) > 0.0);
        assert!((f[0] + f[1] - Vec3::new(-0.1, 0.0, 0.0)).norm() < 1e-12);
    }

    /// Pressed into the tray the vertex is pushed out; dragged along it, friction holds it
    /// up to μ times the push, then it slides.
    #[test]
    fn the_tray_pushes_out_and_holds_by_friction_up_to_mu() {
        let (mut held, rest) = one_vertex(0.0, 1000.0);
        let mut f = vec![Vec3::zeros(); 2];
        // The total force on the points with them all moved by (x, 0, z) mm.
        let mut push = |x_mm: f64, z_mm: f64| {
            let p: Vec<Vec3> = rest
                .iter()
                .map(|r| r + Vec3::new(x_mm, 0.0, z_mm) * 1e-3)
                .collect();
            held.forces(&p, &mut f, true, Vertices::All);
            f[0] + f[1]
        };
        let total = push(0.0, -1.0);
        assert!((total - Vec3::new(0.0, 0.0, 1.0)).norm() < 1e-12, "{total}");
        // 0.2 mm sideways: 0.2 N of friction, under μ N = 0.5 N: sticks.
        let total = push(0.2, -1.0);
        assert!((total.x + 0.2).abs() < 1e-12, "{total}");
        // 2 mm: capped at 0.5 N, and the anchor slides along (twice: it stays capped).
        assert!((push(2.0, -1.0).x + 0.5).abs() < 1e-12);
        assert!((push(2.0, -1.0).x + 0.5).abs() < 1e-12);
        // Lifted off: nothing, and the contact lets go.
        assert_eq!(push(2.0, 1.0), Vec3::zeros());
        assert_eq!(held.touching(), 0);
    }
}
