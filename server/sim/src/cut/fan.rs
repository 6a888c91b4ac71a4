//! Covering a surface triangle whose edges got new vertices (the triangles just outside an
//! incision region whose boundary the refinement split).

use crate::geometry::triangle_min_angle_deg;
use crate::math::Vec3;

/// A corner fan whose smallest angle is at least this is kept without a search.
const FAN_FAIR_DEG: f64 = 20.0;
/// A new vertex inside must beat the corner fan's smallest angle by this much.
const FAN_GAIN_DEG: f64 = 2.0;
/// Stands for the new vertex inside in [`FanPlan::cells`].
const INNER: u32 = u32::MAX;

/// Cells covering a split triangle, before anything is added to the mesh.
#[derive(Debug, Clone)]
pub(crate) struct FanPlan {
    /// Over the ring of corners and splits; [`INNER`] is the new vertex, if any.
    cells: Vec<[u32; 3]>,
    /// Where the new vertex inside goes, if the fan is made from one.
    inner: Option<Vec3>,
}

impl FanPlan {
    /// The smallest angle of each of its cells (degrees).
    pub(crate) fn angles<'a>(&'a self, positions: &'a [Vec3]) -> impl Iterator<Item = f64> + 'a {
        let at = move |v: u32| match (v, self.inner) {
            (INNER, Some(p)) => p,
            _ => positions[v as usize],
        };
        self.cells
            .iter()
            .map(move |c| triangle_min_angle_deg(c.map(at)))
    }

    /// The smallest angle of its cells (degrees).
    fn worst(&self, positions: &[Vec3]) -> f64 {
        self.angles(positions).fold(180.0, f64::min)
    }

    /// Its cells, the vertex inside (if any) pushed onto `positions` with no source.
    pub(crate) fn commit(
        self,
        positions: &mut Vec<Vec3>,
        source: &mut Vec<Option<u32>>,
    ) -> Vec<[u32; 3]> {
        let Some(p) = self.inner else {
            return self.cells;
        };
        positions.push(p);
        source.push(None);
        let id = (positions.len() - 1) as u32;
        self.cells
            .into_iter()
            .map(|c| c.map(|v| if v == INNER { id } else { v }))
            .collect()
    }
}

/// How to cover the triangle `corners` whose edges got new vertices (`splits[e]` on the
/// edge from corner e to e + 1, in order): the triangle itself if there are none, a fan
/// from the corner opposite a lone split edge, or from a new vertex inside the triangle —
/// whichever candidate has the larger smallest angle (the corner kept unless its fan is
/// under [`FAN_FAIR_DEG`] and the inside point gains [`FAN_GAIN_DEG`]). Candidates inside
/// are a barycentric grid in twelfths (55 points; a few such triangles per incision), so a
/// short piece can get a near apex. Fanned from a point inside, the cells keep the
/// triangle's plane.
pub(crate) fn plan_fan(positions: &[Vec3], corners: [u32; 3], splits: &[Vec<u32>; 3]) -> FanPlan {
    let split_edges: Vec<usize> = (0..3).filter(|&e| !splits[e].is_empty()).collect();
    if split_edges.is_empty() {
        return FanPlan {
            cells: vec![corners],
            inner: None,
        };
    }
    // The polygon around the triangle with the new vertices on its edges.
    let ring: Vec<u32> = (0..3)
        .flat_map(|e| std::iter::once(corners[e]).chain(splits[e].iter().copied()))
        .collect();
    let at = |v: u32| positions[v as usize];
    let [pa, pb, pc] = corners.map(at);
    let worst_from = |apex: Vec3| {
        (0..ring.len())
            .map(|i| {
                let (u, w) = (ring[i], ring[(i + 1) % ring.len()]);
                triangle_min_angle_deg([at(u), at(w), apex])
            })
            .fold(180.0, f64::min)
    };
    // The lone split edge's opposite corner, its triangles all but the ring's edges at it.
    let apex_fan = (split_edges.len() == 1).then(|| {
        let e = split_edges[0];
        let apex = corners[(e + 2) % 3];
        let mut chain = vec![corners[e]];
        chain.extend(splits[e].iter().copied());
        chain.push(corners[(e + 1) % 3]);
        let fan = FanPlan {
            cells: chain.windows(2).map(|w| [w[0], w[1], apex]).collect(),
            inner: None,
        };
        (fan.worst(positions), fan)
    });
    // A corner fan of fair cells is kept as it is (no new vertex on skin the cut did not
    // reach, no search).
    let apex_fan = match apex_fan {
        Some((worst, fan)) if worst >= FAN_FAIR_DEG => return fan,
        other => other,
    };
    // The best of a barycentric grid's points strictly inside (a fan from any of them is
    // valid: the ring is the triangle itself); the centroid is one of them.
    const STEPS: usize = 12;
    let centroid = (pa + pb + pc) / 3.0;
    let mut inner = (worst_from(centroid), centroid);
    for i in 1..STEPS {
        for j in 1..STEPS - i {
            let (u, v) = (i as f64 / STEPS as f64, j as f64 / STEPS as f64);
            let p = pa * u + pb * v + pc * (1.0 - u - v);
            let worst = worst_from(p);
            if worst > inner.0 {
                inner = (worst, p);
            }
        }
    }
    match apex_fan {
        Some((worst, fan)) if worst + FAN_GAIN_DEG >= inner.0 => fan,
        _ => FanPlan {
            cells: (0..ring.len())
                .map(|i| [ring[i], ring[(i + 1) % ring.len()], INNER])
                .collect(),
            inner: Some(inner.1),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::triangle_angles_deg;

    /// A triangle 1.4 mm on a side whose edge was split 0.25 mm from a corner (the
    /// tumour's default cut) fanned from its far corner has a 9° cell; the fan is now
    /// made from a point inside, over 14°. The cells cover the triangle exactly, facing
    /// its way; an edge split in the middle still fans from the corner (30°, no new vertex).
    #[test]
    fn a_split_next_to_a_corner_is_not_fanned_into_a_needle() {
        let side = 0.0014;
        let corners_at = [
            Vec3::zeros(),
            Vec3::new(side, 0.0, 0.0),
            Vec3::new(0.5 * side, 0.5 * 3f64.sqrt() * side, 0.0),
        ];
        let smallest = |positions: &[Vec3], fan: &[[u32; 3]]| {
            fan.iter()
                .flat_map(|t| triangle_angles_deg(t.map(|v| positions[v as usize])))
                .fold(180.0, f64::min)
        };
        let area_normal = |positions: &[Vec3], fan: &[[u32; 3]]| {
            fan.iter()
                .map(|t| {
                    let [a, b, c] = t.map(|v| positions[v as usize]);
                    (b - a).cross(&(c - a))
                })
                .fold(Vec3::zeros(), |s, n| {
                    assert!(n.z > 0.0, "a cell faces the other way");
                    s + n
                })
        };
        let whole = (corners_at[1] - corners_at[0]).cross(&(corners_at[2] - corners_at[0]));
        // (split points as fractions along edges 0, 1, 2; smallest angle wanted; new
        // vertices): next to a corner on the first edge and on the second, in the middle,
        // and 0.14 mm from a corner on both its edges (fanned from the centroid before: 5.8°;
        // 10.9° now).
        let cases: [([&[f64]; 3], f64, usize); 4] = [
            ([&[0.25 / 1.4, 0.68 / 1.4], &[], &[]], 14.0, 1),
            ([&[], &[0.18, 0.5], &[]], 14.0, 1),
            ([&[0.5], &[], &[]], 29.9, 0),
            ([&[0.1, 0.5], &[], &[0.5, 0.9]], 10.5, 1),
        ];
        for (fractions, smallest_wanted, new_vertices) in cases {
            let mut positions = corners_at.to_vec();
            let mut splits: [Vec<u32>; 3] = Default::default();
            for e in 0..3 {
                for &f in fractions[e] {
                    let (a, b) = (corners_at[e], corners_at[(e + 1) % 3]);
                    positions.push(a + (b - a) * f);
                    splits[e].push((positions.len() - 1) as u32);
                }
            }
            let mut source: Vec<Option<u32>> = vec![None; positions.len()];
            let before = positions.len();
            let fan = plan_fan(&positions, [0, 1, 2], &splits).commit(&mut positions, &mut source);
            assert!(
                smallest(&positions, &fan) >= smallest_wanted,
                "{fractions:?}: {}",
                smallest(&positions, &fan)
            );
            assert_eq!(positions.len() - before, new_vertices, "{fractions:?}");
            assert_eq!(source.len(), positions.len());
            assert!((area_normal(&positions, &fan) - whole).norm() < 1e-12 * whole.norm());
        }
        // The far corner's fan of the first case, for the record: 9.6°.
        let mut positions = corners_at.to_vec();
        positions.extend([0.25e-3, 0.68e-3].map(|x| Vec3::new(x, 0.0, 0.0)));
        let from_corner = [[0, 3, 2], [3, 4, 2], [4, 1, 2]];
        assert!(smallest(&positions, &from_corner) < 10.0);
    }
}
