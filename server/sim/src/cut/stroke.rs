//! A stroke's path opened on the surface: over intact skin it opens incisions, over an
//! earlier wound it takes the wound's walls down where it cut deeper (crossing cuts split
//! into separate incisions on either side of the earlier one).

use crate::geometry::TriMesh;
use crate::geometry::predicates::closest_point_on_triangle;
use crate::math::Vec3;

use super::deepen::deepen;
use super::incision::{Incised, IncisionError, IncisionParams, incise, source_through};
use super::wound::Wound;
use super::{FaceKind, PathSample};

/// What opening a stroke's path did.
#[derive(Debug, Clone)]
pub struct StrokeOutcome {
    /// The surface after it, its `source` mapping back to the surface before it; `None` if
    /// nothing changed.
    pub surface: Option<Incised>,
    /// Pieces over intact skin that opened an incision.
    pub opened: usize,
    /// Why pieces of the path were refused (the surface is left as it was under them).
    pub refusals: Vec<IncisionError>,
    /// Largest lip turn of the pieces (degrees).
    pub lip_max_turn_deg: f64,
    /// Smallest angle of the triangles they made (degrees; 180 when none).
    pub min_angle_deg: f64,
    /// Largest half-opening (m).
    pub opening_m: f64,
    /// Deepest wall they made (m).
    pub depth_m: f64,
}

/// Opens `samples` (a stroke's path, in order) on the surface `mesh` with face `kinds` and
/// `wounds`: samples within `margin` of a wound's faces (lid or walls) are over it, the
/// others over intact skin, and each run of either kind is opened in turn.
pub fn open_stroke(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    wounds: &[Wound],
    samples: &[PathSample],
    margin: f64,
    params: &IncisionParams,
) -> StrokeOutcome {
    let wound_faces: Vec<[Vec3; 3]> = (0..mesh.triangles.len())
        .filter(|&t| kinds[t] != FaceKind::Skin)
        .map(|t| mesh.corners(t))
        .collect();
    let mut pieces: Vec<(bool, Vec<PathSample>)> = Vec::new();
    for s in samples {
        let over = wound_faces
            .iter()
            .any(|t| (closest_point_on_triangle(&s.surface, t) - s.surface).norm() < margin);
        match pieces.last_mut() {
            Some((o, piece)) if *o == over => piece.push(*s),
            _ => pieces.push((over, vec![*s])),
        }
    }
    let mut outcome = StrokeOutcome {
        surface: None,
        opened: 0,
        refusals: Vec::new(),
        lip_max_turn_deg: 0.0,
        min_angle_deg: 180.0,
        opening_m: 0.0,
        depth_m: 0.0,
    };
    // Each piece is opened on the surface the pieces before it left; `source` composes
    // their vertex maps back to the input.
    let mut source: Vec<Option<u32>> = (0..mesh.positions.len() as u32).map(Some).collect();
    let mut current: Option<Incised> = None;
    for (over, piece) in &pieces {
        let (m, k, w) = match &current {
            Some(c) => (&c.mesh, c.kinds.as_slice(), c.wounds.as_slice()),
            None => (mesh, kinds, wounds),
        };
        let out = if *over {
            match deepen(m, k, w, piece, params) {
                Some(out) => out,
                None => continue,
            }
        } else {
            match incise_trimming_ends(m, k, w, piece, params) {
                Ok(out) => {
                    outcome.opened += 1;
                    out
                }
                Err(IncisionError::TooShort { .. }) => continue,
                Err(e) => {
                    outcome.refusals.push(e);
                    continue;
                }
            }
        };
        source = source_through(&out.source, &source);
        outcome.lip_max_turn_deg = outcome.lip_max_turn_deg.max(out.lip_max_turn_deg);
        outcome.min_angle_deg = outcome.min_angle_deg.min(out.min_angle_deg);
        outcome.opening_m = outcome.opening_m.max(out.opening_m);
        outcome.depth_m = outcome.depth_m.max(out.depth_m);
        current = Some(out);
    }
    outcome.surface = current.map(|mut out| {
        out.source = source;
        out
    });
    outcome
}

/// Samples an incision may leave out at either end of a piece whose region cannot be laid
/// out (see [`incise_trimming_ends`]).
const MOST_TRIMMED: usize = 2;

/// [`incise`], and where the path's region cannot be laid out — the path outside it, or
/// no disk — again without its last, then its first, samples (up to [`MOST_TRIMMED`] at
/// either end). A stroke that runs off the top of a thin sheet onto its rim ends on faces
/// at 90° to the path's mean normal, which the region leaves out (the deltoid scan's
/// random strokes at 100 trials: 2 of the 137 that open were refused so); trimmed, its
/// incision is drawn up to the rim. The internal cut is the blade's whatever is drawn. A
/// piece that stays refused costs up to five `incise` calls instead of one: in a station,
/// which re-runs a stroke's incision as it grows, every run while the blade is past a rim.
fn incise_trimming_ends(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    wounds: &[Wound],
    piece: &[PathSample],
    params: &IncisionParams,
) -> Result<Incised, IncisionError> {
    let first = incise(mesh, kinds, wounds, piece, params);
    let Err(IncisionError::PathOutsideRegion | IncisionError::NotDisk { .. }) = first else {
        return first;
    };
    let n = piece.len();
    for trimmed in 1..=MOST_TRIMMED.min(n) {
        for (from, to) in [(0, n - trimmed), (trimmed, n)] {
            if to <= from + 1 {
                continue;
            }
            if let Ok(out) = incise(mesh, kinds, wounds, &piece[from..to], params) {
                return Ok(out);
            }
        }
    }
    first
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cut::checks::{check_topology, uniform};
    use crate::pipeline::script::vertical_extent;
    use crate::scene::BuiltinMesh;

    /// A path on the top of `mesh` through `centre` at `angle`, `half` long either side,
    /// `offset` to its left, bowed by `bend` in the middle, sampled every `step` as the
    /// tracker samples it, `depth` deep, by an upright blade.
    #[allow(clippy::too_many_arguments)]
    fn stroke(
        mesh: &TriMesh,
        centre: [f64; 2],
        angle: f64,
        half: f64,
        offset: f64,
        bend: f64,
        depth: f64,
        step: f64,
    ) -> Vec<PathSample> {
        tilted_stroke(
            mesh,
            centre,
            angle,
            [half, offset, bend],
            depth,
            step,
            [0.0, 0.0],
        )
    }

    /// [`stroke`] by a blade tilted sideways (its tip toward the path's left) and raked
    /// (its tip ahead of where the edge enters) by `tilt` (radians), its tip `depth` below
    /// the top.
    fn tilted_stroke(
        mesh: &TriMesh,
        centre: [f64; 2],
        angle: f64,
        [half, offset, bend]: [f64; 3],
        depth: f64,
        step: f64,
        tilt: [f64; 2],
    ) -> Vec<PathSample> {
        let (c, s) = (angle.cos(), angle.sin());
        let edge = Vec3::new(
            c * tilt[1].tan() - s * tilt[0].tan(),
            s * tilt[1].tan() + c * tilt[0].tan(),
            -1.0,
        );
        let n = ((2.0 * half / step).ceil() as usize).max(2);
        (0..=n)
            .filter_map(|k| {
                let f = k as f64 / n as f64;
                let along = (2.0 * f - 1.0) * half;
                let off = offset + bend * (1.0 - (2.0 * f - 1.0).powi(2));
                let (x, y) = (
                    centre[0] + along * c - off * s,
                    centre[1] + along * s + off * c,
                );
                let (top, _) = vertical_extent(mesh, x, y)?;
                let surface = Vec3::new(x, y, top);
                Some(PathSample {
                    surface,
                    bottom: surface + edge * depth,
                })
            })
            .collect()
    }

    /// A stroke begun with a stab, as the tracker gets it: a blade `width` wide went in
    /// point first at the path's start, as deep as the path, and the slit its flat made
    /// (min(depth, width) long) is the path's first stretch, its floor rising at 45° toward
    /// the start; where the floor reaches the surface the slit, and the path, begin.
    fn stab_start(path: &mut Vec<PathSample>, width: f64) {
        let Some(depth) = path.first().map(|s| (s.bottom - s.surface).norm()) else {
            return;
        };
        let (start, slit) = (path[0].surface, depth.min(width));
        for s in path.iter_mut() {
            let behind = (slit - (s.surface - start).norm()).max(0.0);
            let cut = s.bottom - s.surface;
            s.bottom = s.surface + cut * ((depth - behind) / depth.max(1e-12)).max(0.0);
        }
        path.retain(|s| (s.bottom - s.surface).norm() > 0.0);
    }

    /// Strokes one after another on every organ — a first cut (half of them begun with a
    /// stab), then one along it deeper, across it or beside it, then one more anywhere
    /// through the middle by a blade tilted and raked at random — opened as the tracker
    /// opens them: the surface stays closed, edge-manifold and oriented after every
    /// stroke, no vertex is left unused, the new triangles have angles ≥ 15°, and a pass
    /// along a wound deeper than its walls takes them down (and mostly opens it wider).
    /// (With the stabs, greedy wall zips made 10° cells under the tapered slit; with the
    /// tilted blades, in a 540-stroke run, a crossing pass deepening a wound's end column
    /// made 13.5° cells.)
    /// (Before the walls' columns were averaged over the depth, short deep pieces of
    /// crossing cuts on the cerebroma made wall slivers down to 0.4°.)
    #[test]
    fn random_strokes_over_earlier_wounds_keep_the_surface_sound() {
        let organs = [
            BuiltinMesh::Liver,
            BuiltinMesh::Shoulder,
            BuiltinMesh::Cerebroma,
        ]
        .map(|organ| (organ.name().to_string(), organ.generate(), 1.0));
        let tallies = random_strokes(&organs, 20, true);
        let sum = |f: fn(&Tally) -> usize| tallies.iter().map(f).sum::<usize>();
        let (changed, deepened, widened) =
            (sum(|t| t.changed), sum(|t| t.deepened), sum(|t| t.widened));
        for ((name, ..), tally) in organs.iter().zip(&tallies) {
            println!("{name}: {tally}");
            assert_eq!(tally.skipped, 0, "{name}: {tally}");
        }
        assert!(
            changed >= 100 && deepened >= 15 && 2 * widened >= deepened,
            "{changed} {deepened} {widened}"
        );
    }

    /// A stroke over the top of an 8 mm slab that runs off its end: its last sample lies
    /// on the slab's vertical end face, at 90° to the path's mean normal, which the region
    /// leaves out — the path is outside it and `incise` refuses the whole incision. Opened
    /// as a stroke, the incision is drawn up to the rim (the last sample left out), sound and
    /// above 15°; and a stroke on the top alone is opened as before, untrimmed.
    #[test]
    fn a_stroke_running_off_a_rim_is_drawn_up_to_it() {
        use crate::cut::checks::{check, top_path};
        use crate::geometry::organs::box_mesh;
        let (thick, depth) = (0.008, 0.002);
        let slab = box_mesh(Vec3::new(0.040, 0.040, thick), [10, 10, 2]);
        let kinds = vec![FaceKind::Skin; slab.triangles.len()];
        let params = IncisionParams::default();
        let mut path = top_path(&slab, [0.004, 0.0013], [0.0195, 0.0013], depth);
        // Down the end face, half a millimetre below the rim.
        let surface = Vec3::new(0.020, 0.0013, 0.5 * thick - 0.0005);
        path.push(PathSample {
            surface,
            bottom: surface - Vec3::x() * depth,
        });
        let refused = incise(&slab, &kinds, &[], &path, &params).err();
        assert!(
            matches!(
                refused,
                Some(IncisionError::PathOutsideRegion | IncisionError::NotDisk { .. })
            ),
            "{refused:?}"
        );
        let outcome = open_stroke(&slab, &kinds, &[], &path, 0.002, &params);
        assert!(outcome.refusals.is_empty(), "{:?}", outcome.refusals);
        assert_eq!(outcome.opened, 1);
        let out = outcome.surface.expect("drawn");
        check(&out, "off the rim");
        // The drawn wound reaches to within a sample of the rim.
        let reach = (out.mesh.positions.iter())
            .zip(&out.source)
            .filter(|(_, s)| s.is_none())
            .map(|(p, _)| p.x)
            .fold(f64::MIN, f64::max);
        assert!(reach > 0.0185, "new vertices reach x = {reach} m");
        // On the top alone nothing is trimmed: the same surface as `incise` draws.
        let top = &path[..path.len() - 1];
        let whole = incise(&slab, &kinds, &[], top, &params).expect("on the top");
        let stroke = open_stroke(&slab, &kinds, &[], top, 0.002, &params);
        assert_eq!(
            stroke.surface.expect("drawn").mesh.positions,
            whole.mesh.positions
        );
    }

    /// What a run of [`random_strokes`] did.
    #[derive(Debug, Default)]
    struct Tally {
        strokes: usize,
        changed: usize,
        deepened: usize,
        widened: usize,
        /// Strokes whose new triangles had an angle under 15° (name, smallest angle),
        /// when not strict.
        small_angles: Vec<(String, f64)>,
        /// Strokes left out: their path has a gap (a vertical cast missed the surface).
        skipped: usize,
    }

    impl std::fmt::Display for Tally {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(
                f,
                "{} strokes ({} with gaps left out), {} changed the surface, {} deepened a \
                 wound, {} of those opened it wider, {} with angles under 15°",
                self.strokes,
                self.skipped,
                self.changed,
                self.deepened,
                self.widened,
                self.small_angles.len()
            )
        }
    }

    /// `trials` sets of three strokes on each (name, surface, depth scale), checked as
    /// [`random_strokes_over_earlier_wounds_keep_the_surface_sound`] says. `strict` holds
    /// the built-in organs to all of it; otherwise angles under 15° are counted, not
    /// failed, and a deeper pass must deepen only where the organ is thick enough. One
    /// tally per organ.
    fn random_strokes(
        organs: &[(String, TriMesh, f64)],
        trials: usize,
        strict: bool,
    ) -> Vec<Tally> {
        let mut next = uniform(0x9e37_79b9_7f4a_7c15u64);
        let params = IncisionParams::default();
        let mut tallies = Vec::with_capacity(organs.len());
        for (organ, original, depth_scale) in organs {
            let mut tally = Tally::default();
            let edge = original.mean_edge_length();
            let (step, margin) = (0.25 * edge, 0.5 * edge);
            let bb = original.bbox();
            let size = (bb.max[0] - bb.min[0]).min(bb.max[1] - bb.min[1]);
            let centre = [0.5 * (bb.max[0] + bb.min[0]), 0.5 * (bb.max[1] + bb.min[1])];
            for trial in 0..trials {
                let mut mesh = original.clone();
                let mut kinds = vec![FaceKind::Skin; mesh.triangles.len()];
                let mut wounds: Vec<Wound> = Vec::new();
                let angle = next() * std::f64::consts::TAU;
                let half = (0.1 + 0.15 * next()) * size;
                let depth = (0.2 + 0.3 * next()) * 0.01 * depth_scale;
                let bend = if trial % 2 == 0 { 0.2 * half } else { 0.0 };
                let mut first = stroke(&mesh, centre, angle, half, 0.0, bend, depth, step);
                if trial % 2 == 1 {
                    stab_start(&mut first, 0.008 * depth_scale);
                }
                let second = match trial % 3 {
                    0 => {
                        let deeper = depth + 0.005 * depth_scale;
                        stroke(&mesh, centre, angle, half, 0.0, bend, deeper, step)
                    }
                    1 => {
                        let across = angle + std::f64::consts::FRAC_PI_2;
                        let deeper = depth + 0.004 * depth_scale;
                        stroke(&mesh, centre, across, half, 0.0, 0.0, deeper, step)
                    }
                    _ => {
                        let beside = (0.3 + 1.2 * next()) * margin;
                        stroke(&mesh, centre, angle, half, beside, bend, depth, step)
                    }
                };
                // The last by a blade tilted sideways up to 40° and raked up to 45°.
                let third_angle = next() * std::f64::consts::TAU;
                let tilt = [
                    (next() - 0.5) * 80f64.to_radians(),
                    next() * 45f64.to_radians(),
                ];
                let third = tilted_stroke(
                    &mesh,
                    centre,
                    third_angle,
                    [half, 0.0, 0.0],
                    0.008 * depth_scale,
                    step,
                    tilt,
                );
                for (k, path) in [first, second, third].iter().enumerate() {
                    // A blade drawn along a surface leaves no gaps in its path: a vertical
                    // cast that misses a steep part (the deltoid's sheet) is no stroke.
                    // (Samples are at most a step apart, and more than three quarters of
                    // one: a missing one leaves a gap of 1.5 steps or more.)
                    let gap = path
                        .windows(2)
                        .any(|w| (w[1].surface - w[0].surface).xy().norm() > 1.5 * step);
                    if gap {
                        tally.skipped += 1;
                        continue;
                    }
                    let name = format!("{organ} trial {trial} stroke {k}");
                    let before = wounds.iter().map(Wound::depth_m).fold(0.0, f64::max);
                    let was_open = wounds.iter().map(|w| w.opening_m).fold(0.0, f64::max);
                    let outcome = open_stroke(&mesh, &kinds, &wounds, path, margin, &params);
                    tally.strokes += 1;
                    // A pass along an open wound, 5 mm deeper than it, must deepen it
                    // (where the organ is thick enough: a thin part stops the walls short).
                    let thick = path.get(path.len() / 2).is_some_and(|s| {
                        vertical_extent(&mesh, s.surface.x, s.surface.y).is_some_and(
                            |(top, bottom)| top - bottom > 2.0 * (s.bottom - s.surface).norm(),
                        )
                    });
                    let deeper_pass =
                        k == 1 && trial % 3 == 0 && !wounds.is_empty() && (thick || strict);
                    assert!(
                        !deeper_pass || outcome.surface.is_some(),
                        "{name}: the deeper pass changed nothing ({:?})",
                        outcome.refusals
                    );
                    let Some(out) = outcome.surface else {
                        continue;
                    };
                    check_topology(&out, &name);
                    tally.changed += 1;
                    if outcome.min_angle_deg < 15.0 {
                        assert!(
                            !strict,
                            "{name}: {} (last stroke's blade tilted {:.1}° sideways, raked \
                             {:.1}°)",
                            outcome.min_angle_deg,
                            tilt[0].to_degrees(),
                            tilt[1].to_degrees()
                        );
                        tally
                            .small_angles
                            .push((name.clone(), outcome.min_angle_deg));
                    }
                    if deeper_pass {
                        assert_eq!(out.wounds.len(), wounds.len(), "{name}: a new wound");
                        let after = out.wounds.iter().map(Wound::depth_m).fold(0.0, f64::max);
                        // (A thin part stops the walls short of its far side.)
                        assert!(after > before + 0.001, "{name}: {before} → {after}");
                        tally.deepened += 1;
                        let open = out.wounds.iter().map(|w| w.opening_m).fold(0.0, f64::max);
                        if open > was_open + 1e-6 {
                            tally.widened += 1;
                        }
                    }
                    mesh = out.mesh;
                    kinds = out.kinds;
                    wounds = out.wounds;
                }
            }
            tallies.push(tally);
        }
        tallies
    }

    /// The same on the real organ meshes of ../shared/meshes, with strokes and depths scaled
    /// to the organ (a tumour 12 mm across takes strokes a few millimetres deep). Every
    /// stroke leaves the surface sound. The scans come as a scanner left them (under 15° are
    /// 42 of the pig liver's 500 triangles, down to 6.0°; 3 of the tumour's 592, 10.6°; 862
    /// of the deltoid's 2672, 1.1°), and the scene build remeshes them (`mesh.remesh =
    /// "auto"`, docs/SCENES.md): on what it gives them the pig liver and the tumour hold the
    /// 15° bound like the built-in organs. Measured at 100 trials (strokes opened; under
    /// 15°; smallest), remeshed — as they came: pig liver lobe 281 of 300, none — 266, 3,
    /// 7.2°; sphere (not remeshed: 50° and up) 269 of 300, none; tumour 268 of 300, none —
    /// 264, 16, 10.9°; deltoid (a muscle sheet, strongly curved across the strokes, whose
    /// ends run onto its steep sides) 137 of 265 (135 before a piece refused past the rim
    /// was tried trimmed; 35 more had gaps), none (2, 12.1° before a deeper pass spread its
    /// columns' bottoms as a first incision does; 106 before outside triangles split next to
    /// a corner were fanned from a point inside, 81 before such splits were collapsed, 51
    /// before a first incision's floor was eased beside a shallow column, 39 and 0.63°
    /// before the walls were graded like the lips at their ends, flipped, and let end at the
    /// surface where an end column is shallow, 30 before new vertices inside moved to better
    /// cells, 28 and 4.2° before the region was laid flat in a conformal chart and let grow
    /// onto the sheet's rim) — 121, 106, 0.2°: not held to 15° here (docs/CUTTING.md, "Real
    /// organ meshes"). (The figures as the scans came were measured before the conformal
    /// chart.) The bounds below hold at 20 trials, one random sequence across the meshes
    /// (deltoid: none of 28).
    #[test]
    #[ignore = "reads ../shared/meshes"]
    fn shared_meshes_take_random_strokes() {
        use crate::geometry::LengthUnit;
        use crate::progress::Silent;
        use crate::scene::{build_scene, for_mesh_file};
        // (file, units, smallest share of strokes that open, largest share of those under
        // 15°, smallest angle allowed)
        let meshes = [
            (
                "pig_liver_lobe0_surface500.obj",
                LengthUnit::M,
                0.85,
                0.0,
                15.0,
            ),
            ("sofa_sphere_05.obj", LengthUnit::Mm, 0.8, 0.0, 15.0),
            ("liver_tumour_PPP_Tumor.obj", LengthUnit::Cm, 0.8, 0.0, 15.0),
            ("deltoid_tri.obj", LengthUnit::Mm, 0.4, 0.0, 15.0),
        ];
        let organs: Vec<(String, TriMesh, f64)> = meshes
            .iter()
            .map(|&(file, units, ..)| {
                let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                    .join("../../../shared/meshes")
                    .join(file);
                let bytes = std::fs::read(&path).unwrap_or_else(|e| {
                    panic!("{}: {e} (is ../shared beside the project?)", path.display())
                });
                let spec = for_mesh_file(path, units);
                let scene = build_scene(&spec, Some(&bytes), &mut Silent).expect(file);
                let bb = scene.model.surface.bbox();
                let size = (bb.max[0] - bb.min[0]).min(bb.max[1] - bb.min[1]);
                (
                    file.to_string(),
                    scene.model.surface,
                    (size / 0.04).min(1.0),
                )
            })
            .collect();
        let tallies = random_strokes(&organs, 20, false);
        for ((file, _, opens, share, smallest), tally) in meshes.iter().zip(&tallies) {
            println!("{file}: {tally}");
            let worst = tally.small_angles.iter().map(|s| s.1).fold(180.0, f64::min);
            assert!(
                tally.strokes >= 45 && tally.changed as f64 >= opens * tally.strokes as f64,
                "{file}: {tally}"
            );
            assert!(
                tally.small_angles.len() as f64 <= share * tally.changed as f64
                    && worst >= *smallest,
                "{file}: {tally}: {:?}",
                tally.small_angles
            );
        }
    }
}
