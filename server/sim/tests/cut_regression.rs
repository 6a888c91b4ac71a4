//! Regression against stored references: the default scripted cut on each built-in organ,
//! and a lab session of several strokes on the liver, compared with what an earlier,
//! checked build did (the force on the tool through the stroke; the surface and the
//! meshless field every second of it), within bands far below what a trainee can feel or
//! see and far above rounding.
//!
//! The checks of `cutting.rs` say a cut is right (rupture force, J_c d, a sound surface);
//! these say it has not *changed*. A change that moves the force by a tenth of a millinewton
//! or a point by a micrometre fails here with what moved, where and by how much. If the
//! change is meant (a physics fix, a new default), re-record the references and commit them
//! with it, saying why in the commit:
//!
//! ```sh
//! SCALPEL_BLESS=1 cargo test --workspace --locked --release --test cut_regression
//! ```

use std::path::PathBuf;

use scalpel_sim::cut::FaceKind;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::{CutScript, NoClock, SIMULATION_TICK_S, Simulation};
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{build_scene, builtin};
use serde::{Deserialize, Serialize};

/// Force on the tool (N): a thousandth of the smallest difference a hand tells apart at a
/// few newtons (about 7 %), and ~10⁹ times the rounding of a force sum.
const FORCE_BAND_N: f64 = 1e-4;
/// Positions (m): a micrometre, well below a pixel of any view of an organ.
const POSITION_BAND_M: f64 = 1e-6;
/// A force sample every this many ticks (20 ms: the ripple's wavelength at 5 mm/s is
/// several of them).
const FORCE_EVERY_TICKS: usize = 20;
/// Random-sign sums of a field (below): several, so that changes of many entries that
/// happen to cancel in one sum show in another.
const PROJECTIONS: usize = 4;
/// The surface and the field every second of the stroke.
const SNAPSHOT_EVERY_TICKS: usize = 1000;

/// What a cut is compared on. Stored as TOML beside this file (`reference/<scene>_cut.toml`).
#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct CutReference {
    scene: String,
    ticks: usize,
    /// Ticks whose force crossed the rupture threshold.
    ruptures: usize,
    /// Force on the tool every `FORCE_EVERY_TICKS` ticks (N).
    force_n: Vec<[f64; 3]>,
    /// The surface and the field every `SNAPSHOT_EVERY_TICKS` ticks, at rupture (the dent
    /// under the blade at its deepest) and at the end.
    snapshots: Vec<Snapshot>,
}

#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct Snapshot {
    tick: usize,
    surface_triangles: usize,
    wall_triangles: usize,
    /// The drawn surface's vertex positions.
    surface: FieldSummary,
    /// The meshless points' (and virtual points') displacements from rest.
    points: FieldSummary,
}

/// A field of 3-vectors seen through a few fixed random signs: Σ_i s_k,i · x_i for each
/// k. One entry moving by δ moves every sum by δ (a sum, not a mean, so that one vertex
/// among thousands still counts); many entries moving together cancel in some sums and
/// add up in others, so a coherent change shows too. A reference stays a few lines long.
#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct FieldSummary {
    count: usize,
    /// Largest entry's length (m).
    largest_m: f64,
    sums_m: Vec<[f64; 3]>,
}

impl FieldSummary {
    fn of(values: impl ExactSizeIterator<Item = Vec3> + Clone) -> Self {
        let sums_m = (0..PROJECTIONS)
            .map(|k| {
                let mut sum = Vec3::zeros();
                for (i, x) in values.clone().enumerate() {
                    sum += x * sign(k, i);
                }
                sum.into()
            })
            .collect();
        Self {
            count: values.len(),
            largest_m: values.clone().map(|x| x.norm()).fold(0.0, nan_max),
            sums_m,
        }
    }
}

/// A fixed pseudo-random sign for entry `i` of projection `k` (splitmix64: the same on
/// every machine and in every release, unlike a library's generator). ±1, not a weight in
/// [−1, 1]: one entry moving by more than the band then moves every sum by more than it.
fn sign(k: usize, i: usize) -> f64 {
    let mut z = (((k as u64) << 32) ^ i as u64).wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    if z >> 63 == 0 { 1.0 } else { -1.0 }
}

/// The larger of two lengths, NaN if either is (`f64::max` would drop a NaN).
fn nan_max(m: f64, d: f64) -> f64 {
    if d.is_nan() || d > m { d } else { m }
}

/// A scripted cut that has a reference.
#[derive(Clone, Copy)]
enum Cut {
    /// The default stroke, as `scalpel cut <scene>` runs it.
    Default,
    /// A lab session, as `scalpel cut <scene> --strokes N --seed S` runs it: several
    /// wounds, crossing and beside each other, with virtual points on all of them.
    Session { strokes: usize, seed: u64 },
}

impl Cut {
    /// The reference's file name (without `_cut.toml`) and how a failure names the cut.
    fn names(self, scene: &str) -> (String, String) {
        match self {
            Cut::Default => (scene.to_owned(), format!("the default cut on {scene}")),
            Cut::Session { strokes, seed } => (
                format!("{scene}_session_{strokes}_seed_{seed}"),
                format!("the {strokes}-stroke session (seed {seed}) on {scene}"),
            ),
        }
    }
}

/// `cut` on a built-in scene, recorded.
fn run_cut(scene_name: &str, cut: Cut) -> CutReference {
    let spec = builtin(scene_name).unwrap();
    let scene = build_scene(&spec, None, &mut Silent).unwrap();
    let surface = &scalpel_sim::pipeline::start_surface(&scene);
    let script = match cut {
        Cut::Default => CutScript::default_for(surface),
        Cut::Session { strokes, seed } => CutScript::session_for(surface, strokes, seed),
    }
    .unwrap();
    let dt = SIMULATION_TICK_S;
    let mut sim = Simulation::new(&scene);
    sim.prepare(dt);
    let ticks = script.tick_count(dt);
    let mut force_n = Vec::with_capacity(ticks / FORCE_EVERY_TICKS + 1);
    let mut snapshots = Vec::new();
    let mut ruptures = 0;
    for k in 0..ticks {
        sim.handle_tool_pose(Some(script.pose_at(k as f64 * dt)));
        let report = sim.tick(dt, &mut NoClock);
        let ruptured = report.cut.as_ref().is_some_and(|c| c.force.ruptured);
        ruptures += usize::from(ruptured);
        if k % FORCE_EVERY_TICKS == 0 {
            force_n.push(report.tool_force_n.into());
        }
        if k % SNAPSHOT_EVERY_TICKS == 0 || ruptured || k + 1 == ticks {
            snapshots.push(snapshot(k, &sim));
        }
    }
    // As `scalpel cut` ends a run (a re-cut still on its worker lands now).
    if sim.settle_incision() {
        snapshots.push(snapshot(ticks, &sim));
    }
    CutReference {
        scene: scene_name.to_owned(),
        ticks,
        ruptures,
        force_n,
        snapshots,
    }
}

fn snapshot(tick: usize, sim: &Simulation) -> Snapshot {
    let (drawn, kinds) = sim.current_surface().drawn();
    let solver = sim.solver();
    let displacements = solver
        .positions()
        .iter()
        .zip(solver.rest())
        .map(|(x, x0)| x - x0);
    Snapshot {
        tick,
        surface_triangles: drawn.triangles.len(),
        wall_triangles: kinds.iter().filter(|k| **k == FaceKind::Wall).count(),
        surface: FieldSummary::of(drawn.positions.iter().copied()),
        points: FieldSummary::of(displacements),
    }
}

fn reference_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/reference")
        .join(format!("{name}_cut.toml"))
}

/// Every difference between a run and its reference, one line each.
fn differences(run: &CutReference, reference: &CutReference) -> Vec<String> {
    let mut out = Vec::new();
    if run.scene != reference.scene {
        out.push(format!(
            "scene: {}, reference {}",
            run.scene, reference.scene
        ));
    }
    let mut exact = |what: &str, a: usize, b: usize| {
        if a != b {
            out.push(format!("{what}: {a}, reference {b}"));
        }
    };
    exact("ticks", run.ticks, reference.ticks);
    exact("ruptures", run.ruptures, reference.ruptures);
    exact("force samples", run.force_n.len(), reference.force_n.len());
    exact("snapshots", run.snapshots.len(), reference.snapshots.len());
    for (a, b) in run.snapshots.iter().zip(&reference.snapshots) {
        let at = |what: &str| format!("tick {}: {what}", b.tick);
        exact(&at("tick"), a.tick, b.tick);
        exact(
            &at("surface triangles"),
            a.surface_triangles,
            b.surface_triangles,
        );
        exact(
            &at("wound wall triangles"),
            a.wall_triangles,
            b.wall_triangles,
        );
        exact(&at("surface vertices"), a.surface.count, b.surface.count);
        exact(&at("points"), a.points.count, b.points.count);
        exact(
            &at("surface sums"),
            a.surface.sums_m.len(),
            b.surface.sums_m.len(),
        );
        exact(
            &at("point sums"),
            a.points.sums_m.len(),
            b.points.sums_m.len(),
        );
    }
    let mut near = |what: String, a: &[f64], b: &[f64], band: f64, unit: &str| {
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, nan_max);
        if worst.is_nan() || worst > band {
            out.push(format!(
                "{what}: {a:?} {unit}, reference {b:?} (off by {worst:.3e}, band {band:.0e})"
            ));
        }
    };
    for (k, (a, b)) in run.force_n.iter().zip(&reference.force_n).enumerate() {
        let t = (k * FORCE_EVERY_TICKS) as f64 * SIMULATION_TICK_S;
        near(format!("force at {t:.3} s"), a, b, FORCE_BAND_N, "N");
    }
    for (a, b) in run.snapshots.iter().zip(&reference.snapshots) {
        let fields = [
            ("surface positions", &a.surface, &b.surface),
            ("point displacements", &a.points, &b.points),
        ];
        for (name, fa, fb) in fields {
            let at = format!("tick {}: {name}", b.tick);
            near(
                format!("{at}, largest"),
                &[fa.largest_m],
                &[fb.largest_m],
                POSITION_BAND_M,
                "m",
            );
            for (k, (sa, sb)) in fa.sums_m.iter().zip(&fb.sums_m).enumerate() {
                near(format!("{at}, sum {k}"), sa, sb, POSITION_BAND_M, "m");
            }
        }
    }
    out
}

fn check_against_reference(scene: &str, cut: Cut) {
    let run = run_cut(scene, cut);
    let (name, what) = cut.names(scene);
    let path = reference_path(&name);
    if std::env::var_os("SCALPEL_BLESS").is_some_and(|v| v == "1") {
        let text = format!(
            "# {what}, recorded by tests/cut_regression.rs (SCALPEL_BLESS=1). \
             Do not edit by hand.\n{}",
            toml::to_string(&run).unwrap()
        );
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, text).unwrap();
        println!("recorded {}", path.display());
        return;
    }
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "no reference for {what} at {} ({e}); record one with SCALPEL_BLESS=1",
            path.display()
        )
    });
    let reference: CutReference = toml::from_str(&text)
        .unwrap_or_else(|e| panic!("{}: not a cut reference: {e}", path.display()));
    let found = differences(&run, &reference);
    // The first differences say where it starts; a broken cut differs everywhere after.
    const SHOWN: usize = 12;
    let more = match found.len().saturating_sub(SHOWN) {
        0 => String::new(),
        n => format!("\n  … and {n} more"),
    };
    assert!(
        found.is_empty(),
        "{what} differs from {}:\n  {}{more}\n\
         If the change is meant, re-record with SCALPEL_BLESS=1 and say why in the commit.",
        path.display(),
        found[..found.len().min(SHOWN)].join("\n  ")
    );
}

#[test]
fn the_default_liver_cut_is_what_it_was() {
    check_against_reference("liver", Cut::Default);
}

#[test]
fn the_default_shoulder_cut_is_what_it_was() {
    check_against_reference("shoulder", Cut::Default);
}

#[test]
fn the_default_cerebroma_cut_is_what_it_was() {
    check_against_reference("cerebroma", Cut::Default);
}

#[test]
fn a_six_stroke_liver_session_is_what_it_was() {
    check_against_reference(
        "liver",
        Cut::Session {
            strokes: 6,
            seed: 1,
        },
    );
}

/// The comparison itself: a reference differs from a copy of itself nowhere, and from a
/// copy with one force sample nudged past the band exactly there; NaN never passes.
#[test]
fn a_nudged_force_sample_is_reported_where_it_is() {
    let field = |x: f64| FieldSummary {
        count: 2,
        largest_m: x,
        sums_m: vec![[x, 0.0, 0.0]; PROJECTIONS],
    };
    let reference = CutReference {
        scene: "s".into(),
        ticks: 100,
        ruptures: 1,
        force_n: vec![[1.0, 2.0, 3.0]; 5],
        snapshots: vec![Snapshot {
            tick: 99,
            surface_triangles: 1,
            wall_triangles: 0,
            surface: field(0.1),
            points: field(0.001),
        }],
    };
    let text = toml::to_string(&reference).unwrap();
    let copy: CutReference = toml::from_str(&text).unwrap();
    assert_eq!(copy, reference, "TOML must round-trip every bit");
    assert!(differences(&copy, &reference).is_empty());
    let mut nudged = copy;
    nudged.force_n[3][1] += 2.0 * FORCE_BAND_N;
    nudged.snapshots[0].points.sums_m[2][0] += 0.5 * POSITION_BAND_M;
    let found = differences(&nudged, &reference);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].starts_with("force at 0.060 s"), "{found:?}");
    nudged.snapshots[0].surface.largest_m = f64::NAN;
    let found = differences(&nudged, &reference);
    assert_eq!(found.len(), 2, "NaN must not pass: {found:?}");
    assert!(found[1].starts_with("tick 99: surface positions, largest"));
    // A reference with fewer sums (recorded with another PROJECTIONS) is no match.
    let mut fewer = toml::from_str::<CutReference>(&text).unwrap();
    fewer.snapshots[0].points.sums_m.pop();
    let found = differences(&fewer, &reference);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].starts_with("tick 99: point sums"), "{found:?}");
}
