//! Tests of `mod`.

use super::*;
use crate::validate::{LatticeCube, cut_down_to};

/// A slaved node hands its forces back to its masters, so it puts them into the fits
/// it is in. A cut leaves the centre of a lattice four neighbours in a plane, and a
/// virtual point a tenth of a spacing off it spans the weak direction alone: the
/// centre's fit is 21 times over the cap, a third of it (by columns) through the
/// node's 34 masters, one of them a light point. Counted as fixed, the masters took no
/// mass for it (in the shoulder's session one such master swung: a rollback); now,
/// with the masses it leaves, the fit's ω² — the points' terms and the masters' — is
/// within the cap (1.33× with the masters counted as fixed), and a pushed body rings
/// down calm at the uncut sub-steps (in a cube this small it did with the old masses
/// too: the bound is what tells the two apart).
#[test]
fn masters_of_a_slaved_node_in_a_fit_over_the_cap_take_mass_by_their_columns() {
    let s = 0.003;
    let cube = LatticeCube::new(7, s);
    let mut rest = cube.rest.clone();
    let centre = cube.centre();
    let h = 2.0 * s;
    let body = rest.len();
    let mut neighbours = cube.neighbours(&rest, 40).with_spare_lists(1);
    let node = body;
    rest.push(rest[centre]);
    let mut volume = vec![s * s * s; body];
    volume.push(0.0);
    let mut mass: Vec<f64> = vec![s * s * s * 1060.0; body + 1];
    // A light point beside the centre (a boundary point's small share of the volume).
    let light = cube.id(4, 4, 3);
    mass[light] /= 10.0;
    let mut solver = cube.soft_solver(&rest, &volume, &mass, &neighbours);
    // The light point stays light: this is about the masses a cut asks for.
    solver.config.mass_scaling_budget = 0.0;
    solver.fixed[node] = [true; 3];
    solver.material_points = body;
    solver.slaves = Slaves::new(body, 1, 0);
    let uncut = solver.step(1e-3).substeps;
    // The centre cut down to its four neighbours in its layer.
    let mut changed = cut_down_to(&mut neighbours, centre, &cube.layer_around_centre());
    // The node beside it, joined to every point within reach.
    let x = rest[centre] + Vec3::new(0.4 * s, 0.3 * s, 0.1 * s);
    for i in 0..body {
        if (rest[i] - x).norm() < h {
            neighbours.add(i, node as u32).expect("room");
            neighbours.add(node, i as u32).expect("room");
            changed.push(i as u32);
        }
    }
    assert!(solver.slave_node(node, x, neighbours.of(node)));
    changed.push(node as u32);
    changed.sort_unstable();
    changed.dedup();
    solver.topology_changed(&changed, &neighbours);
    let cap = solver.omega_sq_cap.expect("cap");
    let (built, own, through) = solver.fit_omega_sq_of(centre);
    // The centre's fit's ω² with the masses as they are now.
    let now = solver.fit_omega_sq_with(centre, &solver.mass).0;
    let masters = solver.slaves.masters_of(node).len();
    let heavier = (solver.slaves.masters_of(node).iter())
        .filter(|m| solver.mass[m.0 as usize] > solver.base_mass[m.0 as usize])
        .count();
    // Push the body and let it ring.
    for k in [light, centre] {
        solver.set_external_force(k, Vec3::new(0.0, 0.0, -1e-3));
    }
    let (mut rolled, mut most) = (0, 0);
    for tick in 0..200 {
        if tick == 20 {
            for k in [light, centre] {
                solver.set_external_force(k, Vec3::zeros());
            }
        }
        let report = solver.step(1e-3);
        assert!(!report.diverged, "tick {tick} diverged");
        rolled += report.rollbacks;
        most = most.max(report.substeps);
    }
    println!(
        "centre's fit {:.1}× the cap as built ({:.0} % of Σ|c| through {masters} masters, \
         {heavier} given mass), {:.2}× with the masses now; light point ×{:.1}; \
         sub-steps {uncut} → {most}, {rolled} rollbacks",
        built / cap,
        100.0 * through / (through + own),
        now / cap,
        solver.mass[light] / solver.base_mass[light],
    );
    assert!(built > 10.0 * cap && through > 0.2 * (through + own));
    assert!(now <= cap * (1.0 + 1e-9), "{:.2}× the cap", now / cap);
    assert_eq!(rolled, 0, "rolled back");
    assert!(f64::from(most) <= (f64::from(uncut) * 2f64.sqrt()).ceil());
}

/// Mass scaling to whole sub-steps: a cube whose eight corners hold a tenth of a cell's
/// volume (the slivers an organ's surface clips) has its step set by them. Ticks just
/// over two sub-steps' worth take three; the mass floor on the corners takes them to
/// two, within the budget, with every other mass, and the stiffness, untouched — and a
/// pushed body rings down at two with no rollback. A budget too small changes nothing.
#[test]
fn a_mass_floor_on_clipped_corners_saves_a_sub_step_within_the_budget() {
    let s = 0.003;
    let n = 6;
    let cube = LatticeCube::new(n, s);
    let rest = cube.rest.clone();
    let neighbours = cube.neighbours(&rest, 0);
    let last = n - 1;
    let corners: Vec<usize> = (0..8)
        .map(|c| cube.id(last * (c & 1), last * ((c >> 1) & 1), last * (c >> 2)))
        .collect();
    let mut volume = vec![s * s * s; rest.len()];
    corners.iter().for_each(|&c| volume[c] *= 0.1);
    let mass: Vec<f64> = volume.iter().map(|v| v * 1060.0).collect();
    let solver_with = |budget: f64| {
        let mut solver = cube.soft_solver(&rest, &volume, &mass, &neighbours);
        solver.config.mass_scaling_budget = budget;
        solver
    };
    let mut plain = solver_with(0.0);
    // A tick 1.1 × two sub-steps' worth.
    let dt = 2.0 * plain.config.safety * plain.dt_crit() * 1.1;
    plain.prepare(dt);
    assert_eq!(plain.substeps(), 3);
    let mut scaled = solver_with(0.01);
    scaled.prepare(dt);
    let w = scaled.whole_step_mass().expect("scaled");
    println!(
        "dt_crit {:.3} → {:.3} ms: floor {:.3} cell, {} points, {:.3} % of the body",
        plain.dt_crit() * 1e3,
        scaled.dt_crit() * 1e3,
        w.floor_of_cell,
        w.points,
        w.fraction * 100.0
    );
    assert_eq!((w.substeps_before, w.substeps_after), (3, 2));
    assert_eq!(scaled.substeps(), 2);
    assert!(w.fraction <= 0.01 && w.points == 8, "{w:?}");
    assert!(scaled.dt_crit() >= whole_substeps::HEADROOM * dt / (2.0 * scaled.config.safety));
    for i in 0..rest.len() {
        if corners.contains(&i) {
            assert!(scaled.masses()[i] > mass[i]);
        } else {
            assert_eq!(scaled.masses()[i], mass[i], "point {i}");
        }
    }
    // Same stiffness; and the pushed body rings down at two sub-steps.
    test_support::assert_same_stiffness(&mut plain, &mut scaled, &rest);
    test_support::assert_rings_down_at(&mut scaled, &rest, cube.centre(), dt, 2);
    // A budget under what the corners need: nothing changes.
    let mut tight = solver_with(1e-5);
    tight.prepare(dt);
    assert!(tight.whole_step_mass().is_none());
    assert_eq!(tight.substeps(), 3);
    assert_eq!(tight.masses(), &mass[..]);
}

/// The projective mode holds a surface layer's residual tension as the other modes do: a
/// cube clamped at its base, its outer shell tensioned (1 % prestrain), comes to rest in
/// stiff mode where the static solve (Newton on StVK's energy) puts it, within the two laws'
/// own difference (0.8 % here, 3.9 % at 5 % prestrain: it grows with the strain; the same
/// cube pushed sideways by a body load as large is 0.8 % apart too).
#[test]
fn a_tensioned_layer_settles_alike_in_stiff_mode_and_at_any_stiffness() {
    let s = 0.003;
    let cube = LatticeCube::new(6, s);
    let rest: Vec<Vec3> = cube.rest.iter().map(|x| x - Vec3::repeat(7.5e-3)).collect();
    let n = rest.len();
    let surface = crate::geometry::organs::box_mesh(Vec3::repeat(0.018), [3, 3, 3]);
    let sigma = Prestress::tension_pa(5e3, 0.45, 0.01);
    let layer = || Prestress::surface_layer(&rest, &surface, 3.5e-3, sigma);
    assert!(!layer().is_empty());
    let (volume, mass) = (vec![s * s * s; n], vec![s * s * s * 1060.0; n]);
    let neighbours = cube.neighbours(&rest, 0);
    let solver = |mode| {
        let mut solver = cube.soft_solver(&rest, &volume, &mass, &neighbours);
        solver.config.mode = mode;
        solver.set_prestress(layer());
        for i in 0..n {
            if cube.rest[i].z == 0.0 {
                solver.fix(i, [true; 3]);
            }
        }
        solver
    };
    let mut statics = solver(SolverMode::Explicit);
    assert!(statics.solve_static().converged);
    let mut stiff = solver(SolverMode::Projective);
    for _ in 0..3000 {
        stiff.step(1e-3);
    }
    let moved = |p: &[Vec3]| {
        p.iter()
            .zip(&rest)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max)
    };
    let most = moved(statics.positions());
    let off = moved(
        &(0..n)
            .map(|i| stiff.positions()[i] - statics.positions()[i] + rest[i])
            .collect::<Vec<_>>(),
    );
    println!(
        "the layer pulls the cube in by up to {:.4} mm; stiff mode {:.2e} mm off",
        most * 1e3,
        off * 1e3
    );
    assert!(most > 0.1e-3, "{most}");
    assert!(off < 0.02 * most, "{off} of {most}");
    // A change of E (a stiffness fault) scales the tension with it: the shape the layer
    // pulls the body into is then the same at any stiffness (it took half the strain at 2 E
    // when σ stayed).
    let mut stiffer = solver(SolverMode::Explicit);
    stiffer.set_youngs_modulus(1e4);
    assert!(stiffer.solve_static().converged);
    let apart = moved(
        &(0..n)
            .map(|i| stiffer.positions()[i] - statics.positions()[i] + rest[i])
            .collect::<Vec<_>>(),
    );
    assert!(apart < 1e-6 * most, "{apart} of {most}");
}
