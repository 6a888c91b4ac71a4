//! The blade's contact: which face holds, momentum balance, retries, slack.
use super::*;

fn upright() -> Slab {
    Slab {
        tip: Vec3::zeros(),
        edge: Vec3::z(),
        back: -Vec3::x(),
        length: 0.025,
        width: 0.008,
        thickness: 0.0004,
    }
}

/// A point pressed from below the tip is held by the tip's end, one coming in from the
/// side by the flat it came through, one ahead of the edge by the edge.
#[test]
fn a_sample_is_held_by_the_face_it_came_in_through() {
    let b = upright();
    let inside = Vec3::new(-0.003, 0.0001, 0.0005);
    let l = b.local(&inside);
    assert!(b.inside(&l));
    let below = b.local(&Vec3::new(-0.003, 0.0001, -0.001));
    assert_eq!(b.entry_face(&l, &below), Face::Tip);
    let beside = b.local(&Vec3::new(-0.003, 0.001, 0.0005));
    let side = b.side();
    let expected = if side.y > 0.0 {
        Face::FlatPlus
    } else {
        Face::FlatMinus
    };
    assert_eq!(b.entry_face(&l, &beside), expected);
    let ahead = b.local(&Vec3::new(0.001, 0.0001, 0.0005));
    assert_eq!(b.entry_face(&l, &ahead), Face::Edge);
    let (gap, n) = b.gap(&l, Face::Tip);
    assert!((gap + 0.0005).abs() < 1e-15 && n == -Vec3::x());
}

/// A free-floating block (no supports, no gravity, no damping) with the blade pressed
/// into its top tick after tick: the momentum the block gains each tick is exactly
/// the impulse of the force the blade reports, reversed (to 1e-9 of it).
#[test]
fn the_blade_gets_what_the_tissue_gets_reversed() {
    momentum_balance(crate::solver::SolverConfig::default());
}

/// The same in stiff mode, the faces in the projective global solve: the momentum the
/// block gains is the contacts' pushes over the step, normal (Σ n λ) and friction.
#[test]
fn the_blade_gets_what_the_tissue_gets_reversed_in_stiff_mode() {
    momentum_balance(crate::solver::SolverConfig {
        mode: crate::solver::SolverMode::Projective,
        ..Default::default()
    });
}

/// A free-floating 20 mm block of undamped liver (no supports, no gravity, no damping).
fn free_block(config: crate::solver::SolverConfig) -> crate::validate::BoxBody {
    let undamped = crate::scene::Material {
        damping_per_s: 0.0,
        ..crate::scene::Material::LIVER
    };
    let size = Vec3::new(0.02, 0.02, 0.02);
    crate::validate::box_body(size, 5, &undamped, 2.0, config)
}

/// The first-order row of the field at rest place `x` in `body`, into `row`.
fn row_at(body: &crate::validate::BoxBody, x: &Vec3, row: &mut Vec<(u32, f64)>) {
    use crate::model::SurfaceEmbedding;
    let model = &body.model;
    let zero = SurfaceEmbedding::sample_row(x, &model.points.rest, &model.grid, &model.kernel);
    body.solver
        .operator()
        .linear_row(&zero, x, body.solver.rest(), row);
}

/// Moves the blade from `start` by `step` a tick for `ticks` ticks of 1 ms; each tick the
/// block's momentum gain must be the blade's impulse reversed to 1e-9 of it. Returns how
/// many ticks the blade pushed.
fn moved_with_momentum_balanced(
    body: &mut crate::validate::BoxBody,
    start: Slab,
    step: Vec3,
    ticks: u32,
) -> usize {
    moved_with_momentum_within(body, start, step, ticks, 1e-9)
}

/// [`moved_with_momentum_balanced`] to `tolerance` (relative).
fn moved_with_momentum_within(
    body: &mut crate::validate::BoxBody,
    start: Slab,
    step: Vec3,
    ticks: u32,
    tolerance: f64,
) -> usize {
    let dt = 1e-3;
    let momentum = |s: &crate::solver::Solver| -> Vec3 {
        s.masses()
            .iter()
            .zip(s.velocities())
            .map(|(m, v)| v * *m)
            .sum()
    };
    let mut pushed = 0;
    for k in 1..=ticks {
        let slab = Slab {
            tip: start.tip + step * f64::from(k),
            ..start
        };
        body.solver.blade_mut().unwrap().move_to(slab);
        let before = momentum(&body.solver);
        let report = body.solver.step(dt);
        assert!(!report.diverged && report.rollbacks == 0, "{report:?}");
        let gained = momentum(&body.solver) - before;
        let impulse = body.solver.blade().unwrap().force_on_blade() * dt;
        if impulse.norm() > 0.0 {
            pushed += 1;
            assert!(
                (gained + impulse).norm() <= tolerance * impulse.norm(),
                "tick {k}: gained {gained}, blade impulse {impulse}"
            );
        }
    }
    pushed
}

fn momentum_balance(config: crate::solver::SolverConfig) {
    let mut body = free_block(config);
    let start = Slab {
        tip: Vec3::new(0.0045, 0.0, 0.01),
        ..upright()
    };
    let n = body.solver.rest().len();
    let mut blade = BladeBody::with_room(n, 128, 128 * 512, start);
    let mut row = Vec::new();
    for i in -6..=4 {
        for j in -2..=2 {
            let x = Vec3::new(i as f64 * 1e-3, j as f64 * 1e-3, 0.01);
            row_at(&body, &x, &mut row);
            blade.push(&row, x, body.solver.rest());
        }
    }
    blade.finish(body.solver.positions(), 0.0, 0);
    body.solver.set_blade(Some(blade));
    let pressed = moved_with_momentum_balanced(&mut body, start, -Vec3::z() * 1e-4, 30);
    assert!(pressed > 20, "{pressed} ticks pressed");
    let blade = body.solver.blade().unwrap();
    assert!(blade.force_on_blade().z > 0.0 && blade.touching() > 0);
}

/// The lips pushed by a flat: the blade, in a free-floating block (no supports, no
/// gravity, no damping), is pushed 1 mm sideways across its flats, into the lip samples on
/// one side of its plane. The lips push back against the push (a lateral force, bounded by
/// every lip pressed the whole way in), and the momentum the block gains each tick is the
/// impulse the blade reports, reversed (to 1e-9 of it).
#[test]
fn the_lips_push_back_on_a_flat_pushed_into_them() {
    lips_push_back(Default::default());
}

/// The same in stiff mode: the lips' push is an applied load of the projective step.
#[test]
fn the_lips_push_back_on_a_flat_pushed_into_them_in_stiff_mode() {
    lips_push_back(crate::solver::SolverConfig {
        mode: crate::solver::SolverMode::Projective,
        ..Default::default()
    });
}

fn lips_push_back(config: crate::solver::SolverConfig) {
    let mut body = free_block(config);
    let start = Slab {
        tip: Vec3::new(0.0045, 0.0, 0.0),
        ..upright()
    };
    let n = body.solver.rest().len();
    let mut blade = BladeBody::with_room(n, 128, 128 * 512, start);
    let mut row = Vec::new();
    let (depth, pitch, stiffness) = (1e-5, 0.002, 40.0);
    for x in [0.003, 0.001, -0.001, -0.003] {
        for z in [0.002, 0.005, 0.008] {
            for y in [depth, -depth] {
                let at = Vec3::new(x, y, z);
                row_at(&body, &at, &mut row);
                // The flats' normal is −y: a sample at +y is on the −side flat's lip.
                let side = -y.signum();
                blade.push_lip(&row, at, body.solver.rest(), side, depth, stiffness, pitch);
            }
        }
    }
    blade.finish(body.solver.positions(), 0.0, 0);
    assert_eq!(blade.lips(), 24);
    body.solver.set_blade(Some(blade));
    let pushed = moved_with_momentum_balanced(&mut body, start, Vec3::y() * 1e-4, 10);
    assert!(pushed >= 9, "{pushed} ticks pushed");
    let f = body.solver.blade().unwrap().force_on_blade();
    // Back against the push, and no more than every held lip pressed the whole way in.
    let most = 12.0 * stiffness * (1e-3 + 0.5 * start.thickness);
    assert!(f.y < 0.0 && -f.y <= most, "{f}");
    assert!(f.y.abs() > 5.0 * f.x.abs().max(f.z.abs()), "{f}");
}

/// A blade backed into uncut tissue (a free block, as above) meets it with its spine: the
/// spine samples past it are pushed by their compliant contact, the blade gets the force
/// back against its motion, and the block's momentum gain each tick is the blade's impulse
/// reversed (to 1e-9 of it) in the explicit and projective modes — to 1e-3 in the implicit
/// mode, whose CG solve conserves the block's own momentum only to its tolerance (1e-4 of
/// the spine's impulse here; the spine's push itself is applied after it, exactly).
#[test]
fn the_spine_pushes_what_lies_past_it_and_is_pushed_back() {
    use crate::solver::SolverMode;
    for (mode, tolerance) in [
        (SolverMode::Explicit, 1e-9),
        (SolverMode::Projective, 1e-9),
        (SolverMode::Implicit, 1e-3),
    ] {
        let mut body = free_block(crate::solver::SolverConfig {
            mode,
            ..Default::default()
        });
        let start = Slab {
            tip: Vec3::new(0.0045, 0.0, 0.0),
            ..upright()
        };
        let n = body.solver.rest().len();
        let mut blade = BladeBody::with_room(n, 16, 16 * 512, start);
        let mut row = Vec::new();
        let (capture, stiffness, pitch) = (0.001, 40.0, 0.002);
        // 0.1 mm past the spine (at x = 4.5 − 8 mm), three up the spine.
        for z in [0.002, 0.005, 0.008] {
            let at = Vec3::new(start.tip.x - start.width - 1e-4, 0.0, z);
            row_at(&body, &at, &mut row);
            blade.push_spine(&row, at, body.solver.rest(), capture, stiffness, pitch);
        }
        blade.finish(body.solver.positions(), 0.0, 0);
        body.solver.set_blade(Some(blade));
        let back = -Vec3::x() * 1e-4;
        let pushed = moved_with_momentum_within(&mut body, start, back, 10, tolerance);
        assert!(pushed >= 8, "{mode:?}: {pushed} ticks pushed");
        let blade = body.solver.blade().unwrap();
        let f = blade.force_on_blade();
        // Back against the motion, no more than every sample pressed the whole way in.
        assert!(f.x > 0.0 && f.x <= 3.0 * stiffness * 1e-3, "{mode:?}: {f}");
        assert!(f.x > 5.0 * f.y.abs().max(f.z.abs()), "{mode:?}: {f}");
        assert!(blade.spine_indentation() > 0.0 && blade.spine_indentation() < 1e-3);
    }
}

/// A spine sample the tip passes (the blade lifted out) is let go over its patch, as a lip
/// is, not at once: pressed as deep, it pushes fully well above the tip, three
/// quarters as hard a quarter patch above it, a quarter as hard a quarter patch below it,
/// and not at all half a patch below.
#[test]
fn the_tip_lets_a_spine_sample_go_over_its_patch() {
    // (Less deep than a sample met where the steel already was, which is caught up.)
    let (stiffness, pitch, inside) = (10.0, 0.002, 1e-5);
    let push_at = |height: f64| {
        // Inside the spine (at x = −8 mm for the upright blade) by `inside`.
        let at = Vec3::new(-0.008 + inside, 0.0, height);
        let mut blade = BladeBody::with_room(1, 4, 4, upright());
        blade.push_spine(&[(0, 1.0)], at, &[at], 0.001, stiffness, pitch);
        blade.finish(&[at], 0.0, 0);
        blade.begin_substep(0.0, 1.0, &[at], f64::INFINITY);
        let mut out = [Vec3::zeros()];
        blade.lip_forces(&[at], &[1e-3], &mut out, 1e-4, Field::Explicit);
        -out[0].x
    };
    let full = stiffness * inside;
    assert!(
        (push_at(0.005) - full).abs() < 1e-9 * full,
        "{}",
        push_at(0.005)
    );
    assert!((push_at(0.25 * pitch) - 0.75 * full).abs() < 1e-9 * full);
    assert!((push_at(-0.25 * pitch) - 0.25 * full).abs() < 1e-9 * full);
    assert_eq!(push_at(-0.5 * pitch - 1e-6), 0.0);
}

/// A lip sample on a sliver's light point (a quarter of a milligram, as on the tumour
/// scan, where points weigh a gram) is pushed no harder than a sub-step resolves: it
/// moves at most half its depth in the flat in one; on a gram the full stiffness pushes.
#[test]
fn a_lip_on_a_light_point_is_pushed_no_harder_than_its_step_resolves() {
    let (h, stiffness, inside) = (1.25e-4, 14.0, 1e-5);
    for mass in [1e-3, 2.4e-7] {
        let rest = Vec3::new(-0.003, 1e-5, 0.005);
        let mut blade = BladeBody::with_room(1, 4, 4, upright());
        // At +y: the −side flat's lip, that flat at y = +0.2 mm.
        blade.push_lip(&[(0, 1.0)], rest, &[rest], -1.0, 1e-5, stiffness, 0.002);
        let p = [Vec3::new(-0.003, 0.0002 - inside, 0.005)];
        blade.finish(&p, 0.0, 0);
        let mut out = [Vec3::zeros()];
        blade.lip_forces(&p, &[mass], &mut out, h, Field::Explicit);
        // The lip's face is `lip_depth` beyond its sample: pressed that much deeper.
        let deep = inside + 1e-5;
        let expected = (stiffness * deep).min(LIP_STABLE_SHARE * mass / (h * h) * deep);
        assert!(
            (out[0].y - expected).abs() <= 1e-9 * expected,
            "{mass}: {}",
            out[0]
        );
        assert!(out[0].x.abs() + out[0].z.abs() < 1e-12, "{}", out[0]);
        assert!(out[0].y * h * h / mass <= LIP_STABLE_SHARE * deep * (1.0 + 1e-9));
    }
}

/// A blade holding lip samples (rows `rows`, each at its rest `rests[s]`, the points at
/// rest at `rest_points`, each sample's spring `stiffness`), the points at `p`: the −side
/// flat's lip at +y, as above.
fn lip_blade(
    rows: &[Vec<(u32, f64)>],
    rests: &[Vec3],
    rest_points: &[Vec3],
    p: &[Vec3],
    stiffness: f64,
) -> BladeBody {
    let mut blade = BladeBody::with_room(p.len(), rows.len(), 64, upright());
    for (row, rest) in rows.iter().zip(rests) {
        blade.push_lip(row, *rest, rest_points, -1.0, 1e-5, stiffness, 0.002);
    }
    blade.finish(p, 0.0, 0);
    blade
}

/// The lips' push on the points at `p` for a sub-step of `h`, from a copy of `blade`.
fn lip_push(blade: &BladeBody, p: &[Vec3], mass: &[f64], h: f64) -> Vec<Vec3> {
    let mut blade = blade.clone();
    let mut out = vec![Vec3::zeros(); p.len()];
    blade.lip_forces(p, mass, &mut out, h, Field::Explicit);
    out
}

/// Several lip samples on one light point share its bound: together they push it no
/// harder than one may (each alone could take it all, and ω·h grew as √(N/2)).
#[test]
fn lip_samples_sharing_a_light_point_share_its_bound() {
    let (h, mass, shift) = (1.25e-4, 2.4e-7, 0.00019);
    let rest_points = [Vec3::new(-0.003, 0.0, 0.005)];
    let rows: Vec<_> = (0..6).map(|_| vec![(0u32, 1.0)]).collect();
    let rests: Vec<_> = (0..6)
        .map(|i| Vec3::new(-0.003 + 1e-4 * i as f64, 1e-5, 0.005))
        .collect();
    let p = [rest_points[0] + Vec3::y() * shift];
    let blade = lip_blade(&rows, &rests, &rest_points, &p, 14.0);
    let out = lip_push(&blade, &p, &[mass], h);
    // Each sample sits on the flat (y = 1e-5 + shift = 0.2 mm), its lip's face the lip
    // depth (1e-5) inside it.
    let deep = 1e-5;
    let whole = LIP_STABLE_SHARE * mass / (h * h) * deep;
    assert!(
        (out[0].y - whole).abs() <= 1e-9 * whole,
        "{} vs {whole}",
        out[0]
    );
}

/// Lip samples over light and heavy points with mixed rows, each spring stiff enough that
/// a bound of its own row's mass binds it (so that only a bound over the samples together
/// keeps the sum): the stiffness the lips give the points — by finite differences along
/// all three axes, the flats' push and the friction's stick — keeps ω² = λ_max(M⁻¹K)
/// within LIP_STABLE_SHARE/h², and the bound does not take the push away.
#[test]
fn the_lips_springs_together_stay_within_the_step() {
    let (h, shift, dx) = (1.25e-4, 0.00019, 1e-9);
    let mass = [2.4e-7, 1e-3, 5e-4, 3e-6];
    let rest_points: Vec<_> = (0..4)
        .map(|k| Vec3::new(-0.003 + 4e-4 * k as f64, 0.0, 0.005))
        .collect();
    let rows: Vec<Vec<(u32, f64)>> = vec![
        vec![(0, 0.7), (1, 0.3)],
        vec![(0, 0.5), (2, 0.6), (3, -0.1)],
        vec![(0, 0.2), (1, 0.4), (2, 0.4)],
        vec![(3, 0.9), (1, 0.1)],
        vec![(0, 0.05), (2, 0.95)],
    ];
    let rests: Vec<_> = (0..rows.len())
        .map(|i| Vec3::new(-0.0025 + 3e-4 * i as f64, 1e-5, 0.005 + 1e-4 * i as f64))
        .collect();
    let p: Vec<_> = rest_points.iter().map(|r| r + Vec3::y() * shift).collect();
    let mut blade = lip_blade(&rows, &rests, &rest_points, &p, 1e4);
    // The samples take their flats and stick where they are: friction holds from here.
    let mut out = vec![Vec3::zeros(); p.len()];
    blade.lip_forces(&p, &mass, &mut out, h, Field::Explicit);
    let base = lip_push(&blade, &p, &mass, h);
    assert!(base.iter().all(|f| f.y >= 0.0) && base.iter().any(|f| f.y > 0.0));
    // K column by column, scaled by M^{-1/2} on both sides.
    let n = mass.len();
    let mut k = nalgebra::DMatrix::<f64>::zeros(3 * n, 3 * n);
    for j in 0..n {
        for a in 0..3 {
            let mut q = p.clone();
            q[j][a] += dx;
            let moved = lip_push(&blade, &q, &mass, h);
            for i in 0..n {
                for b in 0..3 {
                    k[(3 * i + b, 3 * j + a)] =
                        -(moved[i][b] - base[i][b]) / dx / (mass[i] * mass[j]).sqrt();
                }
            }
        }
    }
    let k = (&k + k.transpose()) * 0.5;
    let omega_sq = k.symmetric_eigenvalues().max();
    assert!(
        omega_sq * h * h <= LIP_STABLE_SHARE * (1.0 + 1e-4),
        "ω²h² = {}",
        omega_sq * h * h
    );
    // The light points bind it: it is not a bound far below what it must be.
    assert!(
        omega_sq * h * h > 0.1 * LIP_STABLE_SHARE,
        "{}",
        omega_sq * h * h
    );
}

/// A sample that came in while the blade lets go is the crack's for the rest of the
/// attempt, but a retried tick starts from what the tick started with.
#[test]
fn a_retried_tick_starts_from_the_samples_it_started_with() {
    let b = upright();
    let mut blade = BladeBody::with_room(1, 4, 4, b);
    let rest = [Vec3::new(-0.003, 0.0001, 0.0005)];
    blade.push(&[(0, 1.0)], rest[0], &rest);
    blade.finish(&[Vec3::new(-0.003, 0.0001, -0.001)], 0.0, 0);
    assert_eq!(blade.release(0.5), 0.5);
    blade.begin_tick();
    blade.begin_attempt();
    let mut p = [Vec3::new(-0.003, 0.0001, -0.001)];
    blade.begin_substep(0.0, 1.0, &p, f64::INFINITY);
    p[0] = rest[0];
    let mut v = [Vec3::zeros()];
    blade.project(&mut p, &mut v, &[1e-3], 1e-3, |_| 1e3);
    assert!(blade.cut[0], "came in while letting go");
    blade.begin_attempt();
    assert!(!blade.cut[0], "restored for the retry");
}

/// A blade holding one crack-front sample built at `at` (its row: point 0 alone, at `at`)
/// with a capture band of `pitch`, its tick begun.
fn one_front_sample(b: Slab, at: Vec3, pitch: f64) -> BladeBody {
    let mut blade = BladeBody::with_room(1, 4, 4, b);
    blade.push_front(&[(0, 1.0)], at, &[at], pitch);
    blade.finish(&[at], 0.0, 0);
    blade.begin_tick();
    blade.begin_attempt();
    blade
}

/// A crack-front sample the edge first meets half a millimetre behind it is taken up
/// at FRONT_CATCH_UP_M_PER_S, not put out in one pass (which would launch its points
/// as far again in the next sub-step); one just ahead of the edge is not moved.
#[test]
fn a_front_met_behind_the_edge_is_caught_up_not_launched() {
    let b = upright();
    let h = 1e-4;
    for (behind, most_per_substep) in [(5e-4, FRONT_CATCH_UP_M_PER_S * h), (-1e-6, 0.0)] {
        let x = Vec3::new(-behind, 0.0, 0.005);
        let mut blade = one_front_sample(b, x, 0.001);
        let mut p = [x];
        let mut v = [Vec3::zeros()];
        let mut last = -behind;
        for _ in 0..20 {
            // The sub-step's inertial move, then the blade.
            blade.begin_substep(0.0, 1.0, &p, f64::INFINITY);
            p[0] += v[0] * h;
            blade.project(&mut p, &mut v, &[1e-3], h, |_| 1e3);
            let moved = p[0].x - last;
            assert!(moved <= most_per_substep + 1e-12, "{behind}: {moved}");
            last = p[0].x;
        }
        if behind > 0.0 {
            // Taken up steadily: 20 sub-steps of 5 µm.
            assert!((p[0].x + behind - 20.0 * most_per_substep).abs() < 1e-9);
            assert!((v[0].x - FRONT_CATCH_UP_M_PER_S).abs() < 1e-9, "{}", v[0].x);
        } else {
            assert_eq!(p[0].x, -behind);
        }
    }
}

/// A surface sample the steel meets half a millimetre deep while it hardly moves was
/// re-sampled inside it: caught up like a front sample. One the steel runs into (as
/// deep as the steel moved) is put out at once.
#[test]
fn a_surface_sample_met_deep_is_caught_up_one_run_into_is_put_out() {
    let b = upright();
    let h = 1e-4;
    for (deep, most) in [(5e-4, FRONT_CATCH_UP_M_PER_S * h), (1e-6, 1e-6)] {
        let mut blade = BladeBody::with_room(1, 4, 4, b);
        // Inside the steel, ahead of the edge, met through the edge.
        let x = Vec3::new(-deep, 0.0, 0.005);
        let before = Vec3::new(0.001, 0.0, 0.005);
        blade.push(&[(0, 1.0)], x, &[x]);
        let mut p = [before];
        blade.finish(&p, 0.0, 0);
        blade.begin_tick();
        blade.begin_attempt();
        blade.begin_substep(0.0, 1.0, &p, f64::INFINITY);
        p[0] = x;
        let mut v = [Vec3::zeros()];
        blade.project(&mut p, &mut v, &[1e-3], h, |_| 1e3);
        let moved = p[0].x - x.x;
        assert!(
            moved <= most + 1e-12 && moved >= 0.0,
            "{deep}: moved {moved}"
        );
        if deep < 1e-5 {
            assert!((p[0].x).abs() < 1e-12, "put out: {}", p[0].x);
        }
    }
}

/// The projective step's constraint keeps the same slack: a front sample met half a
/// millimetre behind the edge asks for no push at first, then for what a step's
/// catch-up takes up.
#[test]
fn the_projective_constraint_keeps_a_front_samples_slack() {
    let b = upright();
    let behind = 5e-4;
    let dt = 1e-3;
    let x = Vec3::new(-behind, 0.0, 0.005);
    let mut blade = one_front_sample(b, x, 0.001);
    let p = [x];
    blade.begin_substep(0.0, 1.0, &p, f64::INFINITY);
    let gap = |blade: &mut BladeBody| {
        let (n, offset) = blade.constraint(0, &p, |_| true).expect("held");
        n.dot(&p[0]) - offset
    };
    assert!(gap(&mut blade).abs() < 1e-15, "met: no push");
    blade.take_up_slack(dt);
    let asked = -gap(&mut blade);
    assert!(
        (asked - FRONT_CATCH_UP_M_PER_S * dt).abs() < 1e-12,
        "{asked}"
    );
    // Retried from the tick's start: the slack as it was.
    blade.begin_attempt();
    assert!(gap(&mut blade).abs() < 1e-15);
}

/// The edge's last half pitch before the tip is bevelled for crack-front samples: a
/// sample the tip passes is let go as the bevel reaches it, its push falling to nothing
/// over that travel instead of from its whole depth at once. Surface samples keep the
/// square tip.
#[test]
fn the_tip_lets_a_front_sample_go_over_half_a_pitch() {
    let b = upright();
    let pitch = 0.001;
    let mut blade = BladeBody::with_room(2, 4, 4, b);
    let x = Vec3::new(-2e-4, 0.0, 0.005);
    blade.push_front(&[(0, 1.0)], x, &[x], pitch);
    blade.push(&[(0, 1.0)], x, &[x]);
    // 0.2 mm behind the edge line (local y), at heights above the tip (local x).
    let depth = 2e-4;
    // What the projection pushes it out by: its gap to the edge, bevel included.
    let push_at = |along: f64| {
        let l = Vec3::new(along, depth, 0.0);
        blade
            .contains(&b, 0, &l)
            .then(|| -blade.gap_to(&b, 0, &l, Face::Edge).0)
    };
    assert_eq!(
        push_at(2e-3),
        Some(depth),
        "above the bevel: the whole depth"
    );
    assert_eq!(push_at(0.5 * pitch), Some(depth));
    let mut last = depth;
    for k in 1..=20 {
        let along = 0.5 * pitch - 0.2 * pitch * k as f64 / 20.0;
        let push = push_at(along).unwrap_or(0.0);
        assert!(
            push <= last + 1e-15 && last - push <= depth / 20.0 + 1e-12,
            "{along}: {push}"
        );
        last = push;
    }
    assert!(
        last < 1e-12,
        "let go where the bevel reaches its depth: {last}"
    );
    assert_eq!(push_at(0.25 * pitch), None);
    // A surface sample at the same place is inside the square steel, bevel or not.
    let l = Vec3::new(0.25 * pitch, depth, 0.0);
    assert!(blade.contains(&b, 1, &l) && blade.gap_to(&b, 1, &l, Face::Edge).0 == -depth);
}

/// Tissue below a withdrawing blade springs back into its track: a crack-front sample
/// that comes in from beyond the tip's end is put out through the tip, a little, not
/// caught up through the edge across the blade's whole width.
#[test]
fn a_front_sample_from_below_the_tip_is_put_out_through_it() {
    let b = upright();
    let h = 1e-4;
    // Below the tip (world z < 0), 2 mm behind the edge line: it then comes up 0.1 mm
    // into the steel.
    let below = Vec3::new(-0.002, 0.0, -1e-4);
    let mut blade = one_front_sample(b, below, 0.001);
    let mut p = [below];
    let mut v = [Vec3::zeros()];
    for k in 0..40 {
        blade.begin_substep(0.0, 1.0, &p, f64::INFINITY);
        if k == 0 {
            p[0].z = 1e-4;
        }
        blade.project(&mut p, &mut v, &[1e-3], h, |_| 1e3);
        assert_eq!(p[0].x, below.x, "never pushed toward the edge");
        if k == 0 {
            assert_eq!(blade.face[0], Some(Face::Tip));
        }
    }
    assert!(
        p[0].z.abs() < 1e-12,
        "out through the tip's end: {}",
        p[0].z
    );
}

/// One sub-step of `h` in which the tissue presses the front sample 20 µm into the edge.
fn pressed_substep(blade: &mut BladeBody, p: &mut [Vec3; 1], v: &mut [Vec3; 1], h: f64) {
    blade.begin_substep(0.0, 1.0, p, f64::INFINITY);
    p[0].x -= 2e-5;
    blade.project(p, v, &[1e-3], h, |_| 1e3);
}

/// A lifting blade lets go of the crack front at a hand's pace: where the edge held a
/// front sample the tissue presses into it, the hold recedes at the pace it is given (not
/// at once as the tip passes), and is taken up again at the catch-up pace once the lift
/// stops.
#[test]
fn a_lifting_blade_lets_the_front_go_at_a_hands_pace() {
    let b = upright();
    let h = 1e-4;
    let x = Vec3::new(1e-5, 0.0, 0.005);
    let mut blade = one_front_sample(b, x, 0.001);
    let (mut p, mut v) = ([x], [Vec3::zeros()]);
    for _ in 0..10 {
        pressed_substep(&mut blade, &mut p, &mut v, h);
    }
    assert!(p[0].x.abs() < 1e-12, "held at the edge: {}", p[0].x);
    blade.let_go_front(FRONT_CATCH_UP_M_PER_S);
    let pace = FRONT_CATCH_UP_M_PER_S * h;
    for k in 1..=20 {
        pressed_substep(&mut blade, &mut p, &mut v, h);
        assert!((p[0].x + k as f64 * pace).abs() < 1e-12, "{k}: {}", p[0].x);
    }
    blade.let_go_front(0.0);
    let catch_up = FRONT_CATCH_UP_M_PER_S * h;
    for k in 1..=5 {
        pressed_substep(&mut blade, &mut p, &mut v, h);
        let held = -20.0 * pace + k as f64 * catch_up;
        assert!((p[0].x - held).abs() < 1e-12, "{k}: {}", p[0].x);
    }
}

/// Halfway between two slabs: halfway along, axes still orthonormal.
#[test]
fn a_slab_between_two_is_orthonormal() {
    let a = upright();
    let b = Slab {
        tip: Vec3::new(0.01, 0.0, 0.0),
        edge: Vec3::new(0.0, 0.6, 0.8),
        ..a
    };
    let m = Slab::between(&a, &b, 0.5);
    assert!((m.tip - Vec3::new(0.005, 0.0, 0.0)).norm() < 1e-15);
    assert!((m.edge.norm() - 1.0).abs() < 1e-12 && m.edge.dot(&m.back).abs() < 1e-12);
}
