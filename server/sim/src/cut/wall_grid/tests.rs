//! The wall grids' tests: graded ends, shallow ends, spread bottoms, eased floors.

use std::collections::{HashMap, HashSet};

use super::*;
use crate::cut::wound::edge_key;
use crate::geometry::predicates::distance_sq_to_segment;

/// A first incision's floor where a thin part stopped the end column 0.52 mm down
/// beside columns 3.7 mm deep, 1.84 mm apart (a deltoid stroke: 4.9° wall cells): eased
/// to 45°, never deeper than it was; a smooth floor is left alone.
#[test]
fn a_first_incisions_floor_is_eased_beside_a_shallow_end() {
    let gap = 1.84e-3;
    let columns = |depths_mm: &[f64]| -> Vec<WallColumn> {
        depths_mm
            .iter()
            .enumerate()
            .map(|(c, &d)| WallColumn {
                param: c as f64 / (depths_mm.len() - 1) as f64,
                top: Vec3::new(c as f64 * gap, 0.0, 0.0),
                inward: -Vec3::z(),
                depth: d * 1e-3,
            })
            .collect()
    };
    let depths = |c: &[WallColumn]| -> Vec<f64> {
        c.iter().map(|c| (c.depth * 1e5).round() / 100.0).collect()
    };
    let mut cut = columns(&[2.81, 3.12, 3.26, 3.25, 3.29, 3.51, 3.65, 3.68, 3.69, 0.52]);
    limit_slope(&mut cut, None, gap);
    assert_eq!(
        depths(&cut),
        vec![2.81, 3.12, 3.26, 3.25, 3.29, 3.51, 3.65, 3.68, 2.36, 0.52]
    );
    let smooth = columns(&[1.0, 2.0, 3.0, 3.5, 3.5, 3.0, 2.0, 1.2]);
    let mut eased = smooth.clone();
    limit_slope(&mut eased, None, gap);
    assert_eq!(eased, smooth);
}

/// A straight wound 12 mm long along x with columns 1.2 mm apart straight down, `depths`
/// deep (mm), and lips 1 mm apart at most, with vertices at `params` along it: the
/// surface with the lips alone (no triangles yet).
fn straight_wound(depths_mm: &[f64], params: &[f64]) -> (Wound, Assembly) {
    straight_wound_with(depths_mm, params, params)
}

/// The same with the upper and lower lips' vertices at `upper` and `lower`.
fn straight_wound_with(depths_mm: &[f64], upper: &[f64], lower: &[f64]) -> (Wound, Assembly) {
    let (length, opening) = (0.012, 0.0005);
    let mut out = Assembly {
        positions: Vec::new(),
        source: Vec::new(),
        triangles: Vec::new(),
        kinds: Vec::new(),
        created: Vec::new(),
    };
    let a = out.vertex(Vec3::zeros());
    let b = out.vertex(Vec3::new(length, 0.0, 0.0));
    let lip = |params: &[f64], side: f64, out: &mut Assembly| -> Vec<(f64, u32)> {
        params
            .iter()
            .map(|&t| match t {
                0.0 => (t, a),
                1.0 => (t, b),
                _ => {
                    let half_opening = opening * 4.0 * t * (1.0 - t);
                    (
                        t,
                        out.vertex(Vec3::new(t * length, side * half_opening, 0.0)),
                    )
                }
            })
            .collect()
    };
    let upper = lip(upper, 1.0, &mut out);
    let lower = lip(lower, -1.0, &mut out);
    let n = depths_mm.len();
    let columns = depths_mm
        .iter()
        .enumerate()
        .map(|(c, &d)| {
            let param = c as f64 / (n - 1) as f64;
            WallColumn {
                param,
                top: Vec3::new(param * length, 0.0, 0.0),
                inward: -Vec3::z(),
                depth: d * 1e-3,
            }
        })
        .collect();
    let wound = Wound {
        upper,
        lower,
        columns,
        opening_m: opening,
        length_m: length,
        spacing_m: 0.0012,
    };
    (wound, out)
}

/// Lip vertices graded to 0.24 mm segments at the ends, as an incision grades them.
const GRADED_LIPS: [f64; 15] = [
    0.0, 0.02, 0.04, 0.06, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 0.94, 0.96, 0.98, 1.0,
];

/// Lip vertices at the columns.
const EVEN_LIPS: [f64; 11] = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0];

/// End columns 0.18 mm deep beside columns 1.2 mm apart (the deltoid's shallow ends).
const SHALLOW_ENDS: [f64; 11] = [0.18, 1.38, 2.5, 3.0, 3.0, 3.0, 3.0, 3.0, 2.5, 1.38, 0.18];

/// The walls of `wound` in `out` are two sheets hanging from its lips: every edge of
/// theirs is used once each way (a lip edge once), and every lip edge is used.
fn assert_sound_walls(wound: &Wound, out: &Assembly) {
    let mut uses: HashMap<(u32, u32), usize> = HashMap::new();
    for &t in &out.created {
        let tri = out.triangles[t as usize];
        assert!(
            tri[0] != tri[1] && tri[1] != tri[2] && tri[2] != tri[0],
            "{tri:?}"
        );
        for k in 0..3 {
            *uses.entry((tri[k], tri[(k + 1) % 3])).or_default() += 1;
        }
    }
    let lips: HashSet<(u32, u32)> = wound.lip_edges().collect();
    for (&(u, v), &n) in &uses {
        assert_eq!(n, 1, "edge {u}-{v} used {n} times one way");
        let back = uses.contains_key(&(v, u));
        assert_eq!(back, !lips.contains(&edge_key(u, v)), "edge {u}-{v}");
    }
    for (u, v) in lips {
        assert!(uses.contains_key(&(u, v)) || uses.contains_key(&(v, u)));
    }
}

/// The smallest angle of the walls `build` gives the straight wound with its columns as
/// they are (checked sound).
fn walls_built_by(depths_mm: &[f64], lips: &[f64], build: impl Fn(&Wound, &mut Assembly)) -> f64 {
    let (wound, mut out) = straight_wound(depths_mm, lips);
    build(&wound, &mut out);
    assert_sound_walls(&wound, &out);
    out.min_created_angle_deg()
}

/// The straight wound as [`build_walls_choosing_ends`] leaves it, and its walls'
/// smallest angle (checked sound).
fn walls_chosen(depths_mm: &[f64], lips: &[f64], old: Option<&[WallColumn]>) -> (Wound, f64) {
    let (mut wound, mut out) = straight_wound(depths_mm, lips);
    build_walls_choosing_ends(&mut wound, old, &mut out);
    assert_sound_walls(&wound, &out);
    let angle = out.min_created_angle_deg();
    (wound, angle)
}

/// The wound's column depths (mm, to a hundredth).
fn depths_mm(wound: &Wound) -> Vec<f64> {
    wound
        .columns
        .iter()
        .map(|c| (c.depth * 1e5).round() / 100.0)
        .collect()
}

/// Shallow end columns under lips graded at the ends: as gridded on the wound's
/// columns the walls' end cells are slivers (3.5°: the end columns' two rows 0.09 mm
/// tall, and the short lip segments zipped to a row a gap away). With columns graded
/// like the lips near the ends and the walls flipped to their better diagonals, none
/// is under 19°, the walls are sound and the floor is kept.
#[test]
fn wall_columns_are_graded_like_the_lips_at_the_ends() {
    let before = walls_built_by(&SHALLOW_ENDS, &GRADED_LIPS, |wound, out| {
        build_wall_grids(wound, &wound.columns, false, out);
    });
    assert!(before < 5.0, "{before}");
    let (chosen, after) = walls_chosen(&SHALLOW_ENDS, &GRADED_LIPS, None);
    assert!(after >= 19.0, "{before}° → {after}°");
    assert_eq!(depths_mm(&chosen), SHALLOW_ENDS);
}

/// Shallow end columns under lips with no short segments: as gridded (and flipped) the
/// end columns' rows make slivers; ended at the surface, the floor rising to the ends
/// at 45°, the walls fan from the end vertices with no cell under 18°. Ends deeper than
/// three quarters of a gap are kept (their rows make fine cells), as is a floor that
/// was deeper there before (a deeper pass never raises a wall).
#[test]
fn shallow_wall_ends_rise_to_the_surface_where_that_shapes_the_cells_better() {
    let before = walls_built_by(&SHALLOW_ENDS, &EVEN_LIPS, build_walls);
    assert!(before < 10.0, "{before}");
    let (chosen, after) = walls_chosen(&SHALLOW_ENDS, &EVEN_LIPS, None);
    assert!(after >= 18.0, "{before}° → {after}°");
    assert_eq!(
        depths_mm(&chosen),
        [0.0, 1.2, 2.4, 3.0, 3.0, 3.0, 3.0, 3.0, 2.4, 1.2, 0.0]
    );

    let deeper = [0.95, 1.38, 2.5, 3.0, 3.0, 3.0, 3.0, 3.0, 2.5, 1.38, 0.95];
    let (kept, angle) = walls_chosen(&deeper, &EVEN_LIPS, None);
    assert_eq!(depths_mm(&kept), deeper);
    assert!(angle >= 18.0, "{angle}");

    let old = straight_wound(&[0.1; 11], &EVEN_LIPS).0.columns;
    let (held, _) = walls_chosen(&SHALLOW_ENDS, &EVEN_LIPS, Some(&old));
    for (new, old) in held.columns.iter().zip(&old) {
        assert!(new.depth >= old.depth, "{:?}", depths_mm(&held));
    }
}

/// An end at the surface beside columns graded like the lips, also under lips whose
/// vertices differ (one graded at its ends, one not), each end and both: two sound
/// sheets, no cell near a line (7.2° at worst here; the walls' choice of ends, which
/// weighs the cells, is not asked). Before the lip zip left an end vertex along the lip
/// first, a coarse lip beside columns graded to the other drew cells of three points
/// on a line.
#[test]
fn walls_ending_at_the_surface_beside_graded_columns_are_sound() {
    let ends = [
        [0.0, 1.2, 2.4, 3.0, 3.0, 3.0, 3.0, 3.0, 2.4, 1.2, 0.0],
        [0.0, 1.2, 2.4, 3.0, 3.0, 3.0, 3.0, 3.0, 2.5, 1.38, 0.9],
        [0.9, 1.38, 2.5, 3.0, 3.0, 3.0, 3.0, 3.0, 2.4, 1.2, 0.0],
    ];
    for depths in ends {
        for (upper, lower) in [
            (&GRADED_LIPS[..], &GRADED_LIPS[..]),
            (&GRADED_LIPS[..], &EVEN_LIPS[..]),
            (&EVEN_LIPS[..], &GRADED_LIPS[..]),
        ] {
            let (wound, mut out) = straight_wound_with(&depths, upper, lower);
            build_walls(&wound, &mut out);
            assert_sound_walls(&wound, &out);
            let angle = out.min_created_angle_deg();
            assert!(angle > 5.0, "{depths:?}: {angle}");
        }
    }
}

/// Columns whose lean turns quickly bring two bottoms within 0.04 of a gap of each
/// other — on a straight path, and on a curved one whose bottoms are spread more widely
/// than its tops: spread out, the bunched gap is at least a third of the others, the
/// bottoms stay in order along the path, on the old bottom curve where they reached
/// their place, and every column turns by at most 15°; columns away from the bunch,
/// the end columns and all tops are kept. Evenly spread bottoms are left alone. On a
/// shallow wall the way to its place would turn a column by more: it goes as far as 15°.
#[test]
fn bunched_column_bottoms_are_spread_along_their_curve() {
    let column = |top: Vec3, lean: Vec3, depth: f64| WallColumn {
        param: 0.0,
        top,
        inward: (lean - Vec3::z()).normalize(),
        depth: depth * (1.0 + lean.norm_squared()).sqrt(),
    };
    let gap = |c: &[WallColumn], k: usize| (c[k + 1].bottom() - c[k].bottom()).norm();
    let turn = |a: &WallColumn, b: &WallColumn| a.inward.angle(&b.inward).to_degrees();
    // Tops 1 mm apart along x, or on a 10 mm arc; 3 mm deep, leaning outward on the
    // arc (bottoms further apart than tops); columns 4 and 5 lean toward each other.
    for curved in [false, true] {
        let original: Vec<WallColumn> = (0..11)
            .map(|k| {
                let (top, out) = if curved {
                    let a = 0.1 * k as f64;
                    (
                        Vec3::new(0.01 * a.sin(), 0.01 * a.cos(), 0.0),
                        Vec3::new(a.sin(), a.cos(), 0.0),
                    )
                } else {
                    (Vec3::new(0.001 * k as f64, 0.0, 0.0), Vec3::zeros())
                };
                let tangent = out
                    .cross(&Vec3::z())
                    .try_normalize(1e-12)
                    .unwrap_or(Vec3::x());
                // (0.48 mm along the path either way, 0.51 on the arc, whose bottoms
                // are 6 % further apart.)
                let toward = if curved { 0.17 } else { 0.16 };
                let lean = match k {
                    4 => tangent * toward,
                    5 => -tangent * toward,
                    _ => Vec3::zeros(),
                } + out * 0.2;
                column(top, lean, 0.003)
            })
            .collect();
        assert!(gap(&original, 4) < 0.0001, "curved {curved}");
        let mut columns = original.clone();
        assert_eq!(even_out_bottoms(&mut columns), [4, 5]);
        let others = (0..10).filter(|&k| k != 4).map(|k| gap(&original, k));
        let least_other = others.fold(f64::INFINITY, f64::min);
        assert!(gap(&columns, 4) >= least_other / 3.0, "curved {curved}");
        let old_bottoms: Vec<Vec3> = original.iter().map(WallColumn::bottom).collect();
        let mut along = f64::NEG_INFINITY;
        for (k, c) in columns.iter().enumerate() {
            assert_eq!(c.top, original[k].top);
            assert!(turn(c, &original[k]) <= 15.0 + 1e-9, "column {k}");
            // In order: each bottom further along the path than the one before.
            let a = if curved {
                c.bottom().x.atan2(c.bottom().y)
            } else {
                c.bottom().x
            };
            assert!(a > along, "column {k} out of order");
            along = a;
            if turn(c, &original[k]) < 15.0 - 1e-6 {
                let on_curve = old_bottoms
                    .windows(2)
                    .map(|w| distance_sq_to_segment(&c.bottom(), &w[0], &w[1]).sqrt())
                    .fold(f64::INFINITY, f64::min);
                assert!(on_curve < 1e-12, "column {k} off the curve by {on_curve}");
            }
        }
        for k in [0, 1, 2, 7, 8, 9, 10] {
            assert_eq!(columns[k], original[k], "column {k} moved");
        }
    }
    // Even bottoms: nothing to do.
    let even: Vec<WallColumn> = (0..11)
        .map(|k| column(Vec3::new(0.001 * k as f64, 0.0, 0.0), Vec3::zeros(), 0.003))
        .collect();
    let mut kept = even.clone();
    assert!(even_out_bottoms(&mut kept).is_empty());
    assert_eq!(kept, even);
    // A wall 0.5 mm deep whose two middle bottoms crossed 0.8 mm along the path: the way
    // back under their tops is a turn of about 60°; they turn 15° toward it.
    let mut shallow: Vec<WallColumn> = (0..11)
        .map(|k| {
            let lean = match k {
                4 => Vec3::x() * 1.6,
                5 => -Vec3::x() * 1.6,
                _ => Vec3::zeros(),
            };
            column(Vec3::new(0.001 * k as f64, 0.0, 0.0), lean, 0.0005)
        })
        .collect();
    let before = shallow.clone();
    assert!(!even_out_bottoms(&mut shallow).is_empty());
    for k in [4, 5] {
        assert!(
            (turn(&shallow[k], &before[k]) - 15.0).abs() < 1e-6,
            "column {k}"
        );
    }
}
