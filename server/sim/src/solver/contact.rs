//! A rigid tool pressed into the tissue (cutting-physics.md §2): material samples of the
//! surface under it follow the points (`embedded`) and are pushed out of the tool by stiff
//! one-sided penalties. The force on the tool is minus the sum of what the samples receive,
//! so the tissue and the tool balance exactly; a penalty's compliance is in series with the
//! tissue's and is reported (`max_penetration`) rather than hidden.

use serde::Serialize;

use super::contact_set::ContactSet;
use super::embedded::EmbeddedRows;
use crate::math::Vec3;

/// The tool's shape about its frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ToolShape {
    /// A flat cylindrical punch: its face a disc of `radius` normal to the axis.
    Punch {
        /// Face radius (m).
        radius: f64,
    },
    /// A scalpel blade pressed edge first: a slab `thickness` thick about the plane of the
    /// axis and `along`, its straight edge `length` long across the axis, its flats
    /// `width` from the edge to the spine.
    Blade {
        /// Edge length (m).
        length: f64,
        /// Edge to spine (m).
        width: f64,
        /// Between the flats (m).
        thickness: f64,
    },
}

/// A rigid tool pressed into the tissue along `axis`: its shape's leading face (the
/// punch's disc, the blade's edge) starts at `centre` and has gone `depth` past it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Tool {
    /// Where the leading face starts: a point of the undeformed surface (m).
    pub centre: Vec3,
    /// Unit direction of the press, into the tissue.
    pub axis: Vec3,
    /// Unit direction across the axis: the blade's edge (unused by a punch).
    pub along: Vec3,
    /// The shape.
    pub shape: ToolShape,
    /// How far the leading face has been pressed past `centre` along `axis` (m).
    pub depth: f64,
}

impl Tool {
    /// A flat punch of `radius` at `centre` pressing along `axis`.
    pub fn flat_punch(centre: Vec3, axis: Vec3, radius: f64) -> Self {
        let along = axis.cross(&if axis.x.abs() < 0.9 {
            Vec3::x()
        } else {
            Vec3::y()
        });
        Self {
            centre,
            axis,
            along: along.normalize(),
            shape: ToolShape::Punch { radius },
            depth: 0.0,
        }
    }

    /// Where a point at `x` is against the tool: its gap to the face it is held by (m,
    /// negative inside) and that face's outward normal; an infinite gap where it cannot
    /// touch. A point in line with the leading face (the disc, the edge) is held by it: a
    /// surface pressed by a blade's edge wraps round the edge, it does not jump to the
    /// nearer flat 0.2 mm away. One beside a blade is held by the flat or end it would
    /// come in through, while it is within the blade's reach along the axis.
    pub fn gap(&self, x: &Vec3) -> (f64, Vec3) {
        let r = x - self.centre;
        let ahead = r.dot(&self.axis) - self.depth;
        if self.under_face(x) {
            return (ahead, self.axis);
        }
        match self.shape {
            ToolShape::Punch { .. } => (f64::INFINITY, self.axis),
            ToolShape::Blade {
                length,
                width,
                thickness,
            } => {
                if ahead > 0.0 || ahead < -width {
                    return (f64::INFINITY, self.axis);
                }
                let side_dir = self.axis.cross(&self.along);
                let (e, s) = (r.dot(&self.along), r.dot(&side_dir));
                // Outside the footprint: the side it is on, by how far past it it is.
                let beyond_flat = s.abs() - 0.5 * thickness;
                let beyond_end = e.abs() - 0.5 * length;
                if beyond_flat >= beyond_end {
                    (beyond_flat, side_dir * s.signum())
                } else {
                    (beyond_end, self.along * e.signum())
                }
            }
        }
    }

    /// Whether a point at `x` is in line with the leading face (the disc, the edge), so
    /// that pressing on would meet it face first.
    pub fn under_face(&self, x: &Vec3) -> bool {
        let r = x - self.centre;
        let across = r - self.axis * r.dot(&self.axis);
        match self.shape {
            ToolShape::Punch { radius } => across.norm() <= radius,
            ToolShape::Blade {
                length, thickness, ..
            } => {
                let side_dir = self.axis.cross(&self.along);
                across.dot(&self.along).abs() <= 0.5 * length
                    && across.dot(&side_dir).abs() <= 0.5 * thickness
            }
        }
    }

    /// How far a point at `x` is inside the tool (m, zero if outside).
    pub fn penetration(&self, x: &Vec3) -> f64 {
        (-self.gap(x).0).max(0.0)
    }
}

/// The samples the tool can touch, their penalty stiffnesses and the tool.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolContact {
    samples: EmbeddedRows,
    /// Penalty stiffness of each sample (N/m): a stiffness per area times its area.
    stiffness: Vec<f64>,
    tool: Tool,
    /// The samples a static solve holds against the face.
    set: ContactSet,
    /// Each sample's multiplier over its stiffness (m): the face acts on it as if this much
    /// further in, so that the penalty's give can be taken out (`absorb_give`).
    extra: Vec<f64>,
}

impl ToolContact {
    /// `samples` with penalty stiffnesses `stiffness` (N/m each) against `tool`.
    pub fn new(samples: EmbeddedRows, stiffness: Vec<f64>, tool: Tool) -> Self {
        assert_eq!(samples.len(), stiffness.len(), "one stiffness per sample");
        Self {
            set: ContactSet::new(samples.len()),
            extra: vec![0.0; samples.len()],
            samples,
            stiffness,
            tool,
        }
    }

    /// The tool.
    pub fn tool(&self) -> &Tool {
        &self.tool
    }

    /// Moves the face's starting place along the axis to where it first touches a sample
    /// with the points at `p` (a sloped or curved surface meets a flat face at its
    /// highest point first), so that depth counts from first touch.
    pub fn touch_down(&mut self, p: &[Vec3]) {
        let first = (0..self.samples.len())
            .map(|s| self.samples.position(s, p))
            .filter(|x| self.tool.under_face(x))
            .map(|x| (x - self.tool.centre).dot(&self.tool.axis))
            .fold(f64::INFINITY, f64::min);
        if first.is_finite() {
            self.tool.centre += self.tool.axis * first;
        }
    }

    /// Presses the tool to `depth` (m).
    pub fn set_depth(&mut self, depth: f64) {
        self.tool.depth = depth;
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Sample s's position with the points at `p`.
    pub fn sample_position(&self, s: usize, p: &[Vec3]) -> Vec3 {
        self.samples.position(s, p)
    }

    /// The tool's force on sample s with the points at `p`: out of the face while it is
    /// pressed (with the set frozen, also pulling a pressed sample that lifted off).
    fn push(&self, s: usize, p: &[Vec3]) -> Vec3 {
        let (gap, normal) = self.gap(s, p);
        if self.set.pressed(s, gap) {
            normal * (-self.stiffness[s] * gap)
        } else {
            Vec3::zeros()
        }
    }

    /// Freezes the pressed samples to those inside the face with the points at `p`;
    /// returns how many changed (`contact_set`).
    pub fn freeze(&mut self, p: &[Vec3]) -> usize {
        let Self {
            samples,
            tool,
            extra,
            set,
            ..
        } = self;
        set.freeze((0..samples.len()).map(|s| (s, sample_gap(samples, tool, extra, s, p).0)))
    }

    /// Sample s's gap to the face the penalty sees (m, negative inside) and the face's
    /// normal.
    fn gap(&self, s: usize, p: &[Vec3]) -> (f64, Vec3) {
        sample_gap(&self.samples, &self.tool, &self.extra, s, p)
    }

    /// One augmented-Lagrangian (Uzawa) update: each sample's multiplier grows by how far
    /// it is inside the face (and shrinks, not below zero, by how far it is off it), so
    /// that the next static solve holds it closer to the face with the same force.
    pub fn absorb_give(&mut self, p: &[Vec3]) {
        for s in 0..self.samples.len() {
            let (gap, _) = self.tool.gap(&self.samples.position(s, p));
            self.extra[s] = if gap.is_finite() {
                (self.extra[s] - gap).max(0.0)
            } else {
                0.0
            };
        }
    }

    /// Each sample pressed while inside the face again.
    pub fn thaw(&mut self) {
        self.set.thaw();
    }

    /// Writes the tool's forces on the points at `p` into `out` (zeroing the points the
    /// samples follow first); returns the penalties' stored energy (J).
    pub fn forces(&self, p: &[Vec3], out: &mut [Vec3]) -> f64 {
        for &k in self.samples.reached() {
            out[k as usize] = Vec3::zeros();
        }
        let mut energy = 0.0;
        for s in 0..self.samples.len() {
            let f = self.push(s, p);
            if f != Vec3::zeros() {
                energy += 0.5 * f.norm_squared() / self.stiffness[s];
                self.samples.spread(s, f, out);
            }
        }
        energy
    }

    /// `y += K x` with K = −∂f/∂p of the contacts as they stand (frictionless: a touching
    /// sample is held along its face's normal only).
    pub fn add_stiffness_product(&self, p: &[Vec3], x: &[Vec3], y: &mut [Vec3]) {
        for s in 0..self.samples.len() {
            let (gap, n) = self.gap(s, p);
            if self.set.pressed(s, gap) {
                let along = n.dot(&self.samples.moved(s, x));
                self.samples.spread(s, n * (self.stiffness[s] * along), y);
            }
        }
    }

    /// The force the tissue puts on the tool (N): minus the sum of the tool's pushes.
    pub fn on_tool(&self, p: &[Vec3]) -> Vec3 {
        -(0..self.samples.len()).fold(Vec3::zeros(), |sum, s| sum + self.push(s, p))
    }

    /// How many samples the tool pushes.
    pub fn touching(&self, p: &[Vec3]) -> usize {
        (0..self.samples.len())
            .filter(|&s| self.gap(s, p).0 < 0.0)
            .count()
    }

    /// The deepest a sample is inside the tool (m): the penalties' give.
    pub fn max_penetration(&self, p: &[Vec3]) -> f64 {
        (0..self.samples.len())
            .map(|s| self.tool.penetration(&self.samples.position(s, p)))
            .fold(0.0, f64::max)
    }
}

/// Sample s's geometric gap to `tool` less its multiplier `extra[s]`, and the face's
/// normal (a free function so that `freeze` can borrow the set beside it).
fn sample_gap(
    samples: &EmbeddedRows,
    tool: &Tool,
    extra: &[f64],
    s: usize,
    p: &[Vec3],
) -> (f64, Vec3) {
    let (gap, normal) = tool.gap(&samples.position(s, p));
    (gap - extra[s], normal)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_sample() -> (ToolContact, Vec<Vec3>) {
        let rest = vec![Vec3::zeros(), Vec3::new(0.0, 0.0, -0.01)];
        let row = [(0u32, 0.8), (1u32, 0.2)];
        let at = Vec3::new(0.0, 0.0, -0.002);
        let samples = EmbeddedRows::new([(&row[..], at)].into_iter(), &rest);
        let punch = Tool {
            depth: 0.003,
            ..Tool::flat_punch(Vec3::zeros(), -Vec3::z(), 0.005)
        };
        (ToolContact::new(samples, vec![1000.0], punch), rest)
    }

    /// A sample 1 mm inside the face is pushed 1 mm × k along the axis; the tool gets the
    /// opposite; the stiffness product is the forces' finite difference.
    #[test]
    fn the_punch_pushes_along_its_axis_and_gets_the_opposite() {
        let (contact, rest) = one_sample();
        let mut f = vec![Vec3::zeros(); 2];
        let e = contact.forces(&rest, &mut f);
        assert!((f[0] + f[1] - Vec3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
        assert!((e - 0.5 * 1000.0 * 1e-6).abs() < 1e-15);
        assert!((contact.on_tool(&rest) + f[0] + f[1]).norm() < 1e-15);
        let dx = vec![Vec3::new(3e-7, 0.0, -1e-7), Vec3::new(0.0, 1e-7, 2e-7)];
        let mut kx = vec![Vec3::zeros(); 2];
        contact.add_stiffness_product(&rest, &dx, &mut kx);
        let moved: Vec<Vec3> = rest.iter().zip(&dx).map(|(a, b)| a + b).collect();
        let mut f2 = vec![Vec3::zeros(); 2];
        contact.forces(&moved, &mut f2);
        for k in 0..2 {
            assert!((f[k] - f2[k] - kx[k]).norm() < 1e-12, "{k}");
        }
        // Outside the radius, nothing.
        let aside: Vec<Vec3> = rest
            .iter()
            .map(|x| x + Vec3::new(0.006, 0.0, 0.0))
            .collect();
        assert_eq!(contact.touching(&aside), 0);
        assert_eq!(contact.forces(&aside, &mut f), 0.0);
    }

    /// A blade pressed 5 mm edge first holds what is under its edge along the axis (the
    /// surface wraps round the edge, it does not slip to a flat 0.2 mm away), pushes what
    /// comes in beside it out through the flat, and does not reach past its spine.
    #[test]
    fn a_blade_holds_under_its_edge_and_pushes_beside_it_sideways() {
        let blade = Tool {
            along: Vec3::x(),
            shape: ToolShape::Blade {
                length: 0.025,
                width: 0.008,
                thickness: 0.0004,
            },
            depth: 0.005,
            ..Tool::flat_punch(Vec3::zeros(), -Vec3::z(), 0.001)
        };
        let side = blade.axis.cross(&blade.along);
        let (gap, n) = blade.gap(&Vec3::new(0.003, 0.0, -0.001));
        assert!((gap + 0.004).abs() < 1e-12 && n == -Vec3::z(), "{gap} {n}");
        let beside = side * 0.001 + Vec3::new(0.0, 0.0, -0.003);
        let (gap, n) = blade.gap(&beside);
        assert!((gap - 0.0008).abs() < 1e-12 && n == side, "{gap} {n}");
        assert!(
            blade
                .gap(&(side * 0.001 + Vec3::new(0.0, 0.0, -0.02)))
                .0
                .is_infinite()
        );
    }
}
