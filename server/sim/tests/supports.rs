//! Supports and gravity (cutting-physics.md §1) on a built organ: the liver comes to rest
//! on its tray and its ligament, a fixed region holds, an unsupported body is refused.

use std::path::Path;

use scalpel_sim::pipeline::Simulation;
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{SceneSpec, build_scene};

fn scene(text: &str) -> SceneSpec {
    SceneSpec::from_toml(text, Path::new("test.toml")).expect("a valid scene")
}

/// Why the scene file `text` is refused.
fn refused(text: &str) -> String {
    SceneSpec::from_toml(text, Path::new("test.toml"))
        .unwrap_err()
        .to_string()
}

/// Standard gravity, as a scene file's table.
const GRAVITY: &str = "[loads]\ngravity_m_s2 = [0.0, 0.0, -9.81]\n";

/// The liver under standard gravity, with `more` of a scene file after it.
fn liver_under_gravity(more: &str) -> SceneSpec {
    scene(&format!("extends = \"liver\"\n{GRAVITY}{more}"))
}

/// Under gravity the liver settles on its tray before the first tick: it sags, comes to
/// rest, rests on the tray, and its ligament side stays close to where it was.
#[test]
fn the_liver_settles_on_its_tray_under_gravity() {
    let spec = liver_under_gravity("");
    let built = build_scene(&spec, None, &mut Silent).expect("builds");
    let sim = Simulation::new(&built);
    let r = *sim.settled().expect("settled under gravity");
    println!("{r:?}");
    assert!(r.settled, "in equilibrium: {r:?}");
    assert!(r.sag_mm > 0.1 && r.max_displacement_mm < 50.0, "{r:?}");
    assert!(r.on_tray > 0, "resting on the tray: {r:?}");
    assert!(r.residual_n < 1e-3, "{r:?}");
    let p = sim.solver().positions();
    assert!(p.iter().all(|x| x.iter().all(|c| c.is_finite())));
}

/// Without gravity and without residual tension nothing settles and nothing moves; with a
/// tensioned surface layer and no gravity the body settles into it (its layer shortened,
/// its core compressed) and rests there.
#[test]
fn without_gravity_the_body_starts_at_rest() {
    let weightless = |prestrain: f64| {
        let text = format!(
            "extends = \"liver\"\n[loads]\ngravity_m_s2 = [0.0, 0.0, 0.0]\n\
             [material]\nprestrain = {prestrain}\n"
        );
        build_scene(&scene(&text), None, &mut Silent).expect("builds")
    };
    let sim = Simulation::new(&weightless(0.0));
    assert!(sim.settled().is_none());
    assert_eq!(sim.solver().positions(), sim.solver().rest());
    let sim = Simulation::new(&weightless(0.05));
    let r = sim.settled().expect("settled into its tension");
    assert!(r.settled && r.residual_n < 1e-3, "{r:?}");
    assert!(r.max_displacement_mm > 0.1, "{r:?}");
}

/// A fixed region's points do not move under gravity; the rest of a cube hangs from them.
#[test]
fn a_fixed_face_holds_a_hanging_block() {
    let spec = scene(
        "extends = \"block\"\n[loads]\ngravity_m_s2 = [0.0, 0.0, -9.81]\n\
         [supports]\nfixed = [ { box_fraction = { min = [0.0, 0.0, 0.95], max = [1.0, 1.0, 1.0] } } ]\n",
    );
    let built = build_scene(&spec, None, &mut Silent).expect("builds");
    let sim = Simulation::new(&built);
    let r = *sim.settled().expect("settled");
    assert!(r.settled && r.sag_mm > 0.0, "{r:?}");
    let (p, rest) = (sim.solver().positions(), sim.solver().rest());
    let top = rest.iter().map(|x| x.z).fold(f64::MIN, f64::max);
    for (x, x0) in p.iter().zip(rest) {
        if x0.z >= top - 1e-9 {
            assert_eq!(x, x0, "a fixed point moved");
        }
    }
    let lowest = p
        .iter()
        .zip(rest)
        .map(|(x, x0)| x.z - x0.z)
        .fold(0.0, f64::min);
    assert!(lowest < 0.0, "the bottom hangs down");
}

/// Gravity with nothing to hold the body, or a region that holds nothing, is refused with
/// a message that says which.
#[test]
fn an_unsupported_body_is_refused() {
    let e = refused("extends = \"block\"\n[loads]\ngravity_m_s2 = [0.0, 0.0, -9.81]\n");
    assert!(e.contains("supports") && e.contains("nothing holds"), "{e}");
    let spec = scene(
        "extends = \"block\"\n[supports]\n\
         fixed = [ { box_mm = { min = [500.0, 0.0, 0.0], max = [600.0, 1.0, 1.0] } } ]\n",
    );
    let e = build_scene(&spec, None, &mut Silent)
        .unwrap_err()
        .to_string();
    assert!(e.contains("supports.fixed[0] holds no point"), "{e}");
    let e = refused("extends = \"liver\"\n[supports]\ntray = { normal = [0.0, 0.0, 0.0] }\n");
    assert!(e.contains("supports.tray.normal"), "{e}");
    let e = refused(
        "extends = \"liver\"\n[supports]\nfixed = [ { box_fraction = { min = [0.5, 0.0, 0.0], max = [0.2, 1.0, 1.0] } } ]\n",
    );
    assert!(
        e.contains("supports.fixed[0].box_fraction") && e.contains("above"),
        "{e}"
    );
}

/// Every region form reads in the scene's millimetres; two forms at once are refused.
#[test]
fn region_forms_read_in_millimetres_and_one_at_a_time() {
    use scalpel_sim::scene::Region;
    let spec = scene(
        "extends = \"block\"\n[supports]\nfixed = [\n\
         { box_mm = { min = [-1.0, -2.0, -3.0], max = [1.0, 2.0, 3.0] } },\n\
         { beyond_plane_mm = { point = [0.0, 0.0, 14.0], normal = [0.0, 0.0, 2.0] } },\n\
         { inside_cylinder_mm = { point = [0.0, 0.0, 0.0], axis = [0.0, 3.0, 0.0], radius = 4.0 } },\n]\n",
    );
    assert_eq!(
        spec.supports.fixed,
        vec![
            Region::Box {
                min: [-1e-3, -2e-3, -3e-3],
                max: [1e-3, 2e-3, 3e-3],
            },
            Region::BeyondPlane {
                point: [0.0, 0.0, 0.014],
                normal: [0.0, 0.0, 1.0],
            },
            Region::InsideCylinder {
                point: [0.0, 0.0, 0.0],
                axis: [0.0, 1.0, 0.0],
                radius: 0.004,
            },
        ]
    );
    let e = refused(
        "extends = \"block\"\n[supports]\nfixed = [ { box_mm = { min = [0.0, 0.0, 0.0], max = [1.0, 1.0, 1.0] }, \
         box_fraction = { min = [0.0, 0.0, 0.0], max = [1.0, 1.0, 1.0] } } ]\n",
    );
    assert!(
        e.contains("supports.fixed[0]") && e.contains("exactly one"),
        "{e}"
    );
}

/// The probe's force is the tissue's: on the liver resting on its supports under gravity,
/// a 5 mm punch pressed 3 mm pushes back in proportion to E (within 5 % from 5 to
/// 20 kPa: the gravity's pre-strain, ∝ 1/E, is what breaks exact proportion), with
/// every static solve converged and no point inverted.
#[test]
fn the_probe_force_scales_with_the_tissue_stiffness() {
    use scalpel_sim::pipeline::probe::{ProbeSpec, probe};
    let per_kpa: Vec<f64> = [5.0, 10.0, 20.0]
        .iter()
        .map(|&kpa| {
            let spec = liver_under_gravity(&format!("[material]\nyoungs_modulus_kpa = {kpa}\n"));
            let built = build_scene(&spec, None, &mut Silent).expect("builds");
            let r = probe(&built, &ProbeSpec::default()).expect("over the liver");
            println!("{kpa} kPa: {:.4} N, {r:?}", r.force_n);
            assert!(r.converged && r.max_det_f_loss < 0.5, "{r:?}");
            assert!(r.force_n > 0.0 && r.contact_points > 0, "{r:?}");
            r.force_n / kpa
        })
        .collect();
    let mean = per_kpa.iter().sum::<f64>() / per_kpa.len() as f64;
    for f in &per_kpa {
        assert!((f / mean - 1.0).abs() < 0.05, "{per_kpa:?} N/kPa");
    }
}

/// The blade pressed 5 mm edge first into the liver on its supports (ν = 0.45) pushes
/// back and loses no volume under it: min det F ≥ 0.85 (the dent it replaces, a patch of
/// points carried on the blade, left det F ≈ 0.3).
#[test]
fn the_blade_pressed_5_mm_keeps_the_volume_under_it() {
    use scalpel_sim::pipeline::probe::{ProbeSpec, probe};
    use scalpel_sim::solver::contact::ToolShape;
    let spec = liver_under_gravity("");
    let built = build_scene(&spec, None, &mut Silent).expect("builds");
    let tool = &built.spec.tool;
    let r = probe(
        &built,
        &ProbeSpec {
            depth_m: 0.005,
            steps: 5,
            blade: Some(ToolShape::Blade {
                length: tool.blade_length_m,
                width: tool.blade_width_m,
                thickness: tool.blade_thickness_m,
            }),
            ..ProbeSpec::default()
        },
    )
    .expect("over the liver");
    println!("{r:?}");
    assert!(
        r.converged && r.force_n > 0.05 && r.contact_points > 0,
        "{r:?}"
    );
    assert!(1.0 - r.max_det_f_loss >= 0.85, "{r:?}");
}
