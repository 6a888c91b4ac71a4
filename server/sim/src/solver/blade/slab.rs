//! The blade's volume in its own frame (along the edge, toward the spine, across the
//! flats) and the faces that hold what meets it.

use crate::math::Vec3;

/// The blade's volume: a slab from its tip along its edge (`length`), from its edge back
/// to its spine (`width`), `thickness` between its flats.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slab {
    /// The tip (m).
    pub tip: Vec3,
    /// Unit direction along the edge, tip to the far end.
    pub edge: Vec3,
    /// Unit direction from the edge to the spine, across the flats.
    pub back: Vec3,
    /// Along the edge (m).
    pub length: f64,
    /// Edge to spine (m).
    pub width: f64,
    /// Between the flats (m).
    pub thickness: f64,
}

impl Slab {
    /// Normal of the flats (edge × back).
    pub fn side(&self) -> Vec3 {
        self.edge.cross(&self.back)
    }

    /// `x` in the blade's frame: (along the edge, toward the spine, across the flats).
    pub fn local(&self, x: &Vec3) -> Vec3 {
        let r = x - self.tip;
        Vec3::new(r.dot(&self.edge), r.dot(&self.back), r.dot(&self.side()))
    }

    /// A direction given in the blade's frame, in the world's.
    pub(super) fn world(&self, l: &Vec3) -> Vec3 {
        self.edge * l.x + self.back * l.y + self.side() * l.z
    }

    /// Whether a point at local `l` is inside the steel.
    pub(super) fn inside(&self, l: &Vec3) -> bool {
        self.inside_across(l, 0.5 * self.thickness)
    }

    /// Whether a point at local `l` is within the blade's length and width, and within
    /// `half` of its mid-plane across the flats.
    pub(super) fn inside_across(&self, l: &Vec3, half: f64) -> bool {
        l.x > 0.0 && l.x < self.length && l.y > 0.0 && l.y < self.width && l.z.abs() < half
    }

    /// The slab a fraction `frac` of the way from `a` to `b` (positions and axes blended,
    /// the axes made orthonormal again; sizes from `b`).
    pub fn between(a: &Slab, b: &Slab, frac: f64) -> Slab {
        let edge = (a.edge + (b.edge - a.edge) * frac)
            .try_normalize(1e-12)
            .unwrap_or(b.edge);
        let back = a.back + (b.back - a.back) * frac;
        let back = (back - edge * back.dot(&edge))
            .try_normalize(1e-12)
            .unwrap_or(b.back);
        Slab {
            tip: a.tip + (b.tip - a.tip) * frac,
            edge,
            back,
            ..*b
        }
    }

    /// The gap of a point at local `l` to `face` (m, negative inside) and the face's
    /// outward normal in the blade's frame.
    pub(super) fn gap(&self, l: &Vec3, face: Face) -> (f64, Vec3) {
        let half = 0.5 * self.thickness;
        match face {
            Face::Tip => (-l.x, -Vec3::x()),
            Face::Edge => (-l.y, -Vec3::y()),
            Face::Spine => (l.y - self.width, Vec3::y()),
            Face::FlatPlus => (l.z - half, Vec3::z()),
            Face::FlatMinus => (-l.z - half, -Vec3::z()),
        }
    }

    /// The face a point now at local `l` came in through: of those it was outside of at
    /// local `before`, the one it is least deep behind (any face if it was inside already).
    pub(super) fn entry_face(&self, l: &Vec3, before: &Vec3) -> Face {
        let outside = |f: Face| self.gap(before, f).0 >= 0.0;
        let any = Face::ALL.iter().any(|&f| outside(f));
        Face::ALL
            .into_iter()
            .filter(|&f| !any || outside(f))
            .max_by(|&a, &b| self.gap(l, a).0.total_cmp(&self.gap(l, b).0))
            .unwrap_or(Face::Tip)
    }
}

/// A face of the blade that holds a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Face {
    /// The tip's end, facing away from the edge's far end.
    Tip,
    /// The cutting edge, facing away from the spine.
    Edge,
    /// The spine.
    Spine,
    /// The flat on the +side (edge × back).
    FlatPlus,
    /// The other flat.
    FlatMinus,
}

impl Face {
    pub(super) const ALL: [Face; 5] = [
        Face::Tip,
        Face::Edge,
        Face::Spine,
        Face::FlatPlus,
        Face::FlatMinus,
    ];
}
