//! A wound: what an incision leaves below its lips — the two lips (vertices of the
//! surface) and the columns its walls hang from (a point on the path, the direction into the
//! tissue, the depth) — and the surface being assembled around it. The walls themselves are
//! gridded by `wall_grid`; a deeper pass along a wound is `deepen`'s.

use std::collections::HashMap;

use crate::geometry::triangle_min_angle_deg;
use crate::math::Vec3;

use super::cells::FaceKind;

/// One column of a wound's walls.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallColumn {
    /// Where it is along the path, in [0, 1].
    pub param: f64,
    /// Its top, on the path (rest space, m).
    pub top: Vec3,
    /// Unit direction into the tissue.
    pub inward: Vec3,
    /// Depth of the walls here (m).
    pub depth: f64,
}

impl WallColumn {
    pub(crate) fn bottom(&self) -> Vec3 {
        self.top + self.inward * self.depth
    }
}

/// An opened incision: what a later, deeper pass needs to take its walls further down.
#[derive(Debug, Clone, PartialEq)]
pub struct Wound {
    /// The upper lip from end A to end B: (parameter along the path in [0, 1], vertex).
    pub upper: Vec<(f64, u32)>,
    /// The lower lip, A to B (the same end vertices).
    pub lower: Vec<(f64, u32)>,
    /// The wall columns, evenly spaced from A (parameter 0) to B (parameter 1).
    pub columns: Vec<WallColumn>,
    /// Largest half-opening (m).
    pub opening_m: f64,
    /// Path length (m).
    pub length_m: f64,
    /// The spacing the incision was meshed at (m).
    pub spacing_m: f64,
}

impl Wound {
    /// Deepest column (m).
    pub fn depth_m(&self) -> f64 {
        self.columns.iter().map(|c| c.depth).fold(0.0, f64::max)
    }

    /// The same wound in another numbering of the vertices, with the vertices `splits` put
    /// on its lip edges; `None` if a lip vertex is gone.
    pub(crate) fn renumbered(&self, new_id: &[Option<u32>], splits: &EdgeSplits) -> Option<Wound> {
        let map = |lip: &[(f64, u32)]| -> Option<Vec<(f64, u32)>> {
            let mut out = Vec::with_capacity(lip.len());
            for (i, &(t, v)) in lip.iter().enumerate() {
                out.push((t, new_id.get(v as usize).copied().flatten()?));
                let Some(&(t1, v1)) = lip.get(i + 1) else {
                    continue;
                };
                let inserted: Vec<(f64, u32)> = match (splits.get(&(v, v1)), splits.get(&(v1, v))) {
                    (Some(along), _) => along.clone(),
                    (None, Some(against)) => {
                        against.iter().rev().map(|&(f, id)| (1.0 - f, id)).collect()
                    }
                    (None, None) => Vec::new(),
                };
                out.extend(inserted.iter().map(|&(f, id)| (t + f * (t1 - t), id)));
            }
            Some(out)
        };
        Some(Wound {
            upper: map(&self.upper)?,
            lower: map(&self.lower)?,
            ..self.clone()
        })
    }

    /// Distance between neighbouring columns (m).
    pub(crate) fn column_gap_m(&self) -> f64 {
        self.length_m / (self.columns.len() - 1).max(1) as f64
    }

    /// Its lip edges (unordered vertex pairs).
    pub(crate) fn lip_edges(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        [&self.upper, &self.lower]
            .into_iter()
            .flat_map(|lip| lip.windows(2).map(|e| edge_key(e[0].1, e[1].1)))
    }
}

/// Vertices a re-mesh put on edges of its input: input edge (a, b) → (fraction from a,
/// output vertex), in order from a.
pub(crate) type EdgeSplits = HashMap<(u32, u32), Vec<(f64, u32)>>;

pub(crate) fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// The wounds of `wounds` after a re-mesh whose vertex `v` came from input vertex
/// `source[v]` and which split the input edges in `splits` (a later incision's region can
/// reach an earlier wound's lip and split it); wounds that lost a lip vertex are dropped.
pub(crate) fn carry_wounds(
    wounds: &[Wound],
    source: &[Option<u32>],
    inputs: usize,
    splits: &EdgeSplits,
) -> Vec<Wound> {
    let mut new_id = vec![None; inputs];
    for (v, s) in source.iter().enumerate() {
        if let Some(s) = s {
            new_id[*s as usize] = Some(v as u32);
        }
    }
    wounds
        .iter()
        .filter_map(|w| w.renumbered(&new_id, splits))
        .collect()
}

/// A surface being assembled: vertices with the input vertex each one is, triangles with
/// their kind, and which triangles are new.
pub(crate) struct Assembly {
    pub positions: Vec<Vec3>,
    pub source: Vec<Option<u32>>,
    pub triangles: Vec<[u32; 3]>,
    pub kinds: Vec<FaceKind>,
    pub created: Vec<u32>,
}

impl Assembly {
    pub(crate) fn vertex(&mut self, p: Vec3) -> u32 {
        self.positions.push(p);
        self.source.push(None);
        (self.positions.len() - 1) as u32
    }

    /// Where the surface is now, to measure or undo what is added after it.
    pub(crate) fn mark(&self) -> AssemblyMark {
        AssemblyMark {
            positions: self.positions.len(),
            triangles: self.triangles.len(),
            created: self.created.len(),
        }
    }

    /// Smallest angle of the drawn triangles created since `mark` (degrees).
    pub(crate) fn min_angle_since_deg(&self, mark: &AssemblyMark) -> f64 {
        self.created[mark.created..]
            .iter()
            .filter(|&&t| self.kinds[t as usize] != FaceKind::Lid)
            .map(|&t| {
                triangle_min_angle_deg(
                    self.triangles[t as usize].map(|v| self.positions[v as usize]),
                )
            })
            .fold(180.0, f64::min)
    }

    /// Back to what it was at `mark`.
    pub(crate) fn truncate(&mut self, mark: AssemblyMark) {
        self.positions.truncate(mark.positions);
        self.source.truncate(mark.positions);
        self.triangles.truncate(mark.triangles);
        self.kinds.truncate(mark.triangles);
        self.created.truncate(mark.created);
    }

    /// Smallest angle of the created triangles that are drawn (degrees).
    pub fn min_created_angle_deg(&self) -> f64 {
        self.min_angle_since_deg(&AssemblyMark::default())
    }
}

/// A point in the assembly of a surface ([`Assembly::mark`]; the default: its start).
#[derive(Default)]
pub(crate) struct AssemblyMark {
    pub(crate) positions: usize,
    pub(crate) triangles: usize,
    pub(crate) created: usize,
}
