//! Tests of `file`.

use super::*;

fn parse(text: &str) -> Result<SceneSpec, SceneError> {
    SceneSpec::from_toml(text, Path::new("scenes/test.toml"))
}

#[test]
fn extends_keeps_the_builtin_and_overrides_keys() {
    let s = parse("extends = \"liver\"\n[material]\nyoungs_modulus_kpa = 8\n").unwrap();
    assert_eq!(s.material.youngs_modulus_pa, 8000.0);
    assert_eq!(s.sampling.spacing, SpacingRule::TargetPoints(1526));
    assert_eq!(s.mesh.source, MeshSource::Builtin(BuiltinMesh::Liver));
    assert_eq!(s.name, "test");
}

#[test]
fn a_scene_that_swaps_the_organ_does_not_keep_its_description() {
    let s = parse("extends = \"liver\"\n[mesh]\nbuiltin = \"block\"\n").unwrap();
    assert_eq!(s.description, "scene file scenes/test.toml");
    let s = parse("extends = \"liver\"\n[material]\nyoungs_modulus_kpa = 8\n").unwrap();
    assert_eq!(s.description, builtin("liver").unwrap().description);
}

#[test]
fn cutting_off_takes_what_only_cutting_uses_unless_asked_for() {
    let s = parse("extends = \"liver\"\n[features]\ncutting = false\n").unwrap();
    let f = &s.features;
    assert!(!f.cutting && !f.virtual_points && !f.ripple);
    assert!(f.haptics && f.frames, "the rest is the liver's");
    let e = parse("extends = \"liver\"\n[features]\ncutting = false\nripple = true\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("features.ripple") && e.contains("cutting"),
        "{e}"
    );
}

#[test]
fn mass_scaling_is_given_in_per_cent_of_the_body() {
    let budget = |text: &str| parse(text).unwrap().solver.mass_scaling_budget;
    assert_eq!(budget("extends = \"liver\"\n"), 0.01);
    assert_eq!(
        budget("extends = \"liver\"\n[solver]\nmass_scaling_percent = 0\n"),
        0.0
    );
    assert_eq!(
        budget("extends = \"liver\"\n[solver]\nmass_scaling_percent = 2.5\n"),
        0.025
    );
}

#[test]
fn the_integrator_is_chosen_by_name() {
    let integrator = |text: &str| parse(text).unwrap().solver.integrator;
    assert_eq!(integrator("extends = \"liver\"\n"), Integrator::Explicit);
    let implicit = "extends = \"liver\"\n[solver]\nintegrator = \"implicit\"\n";
    assert_eq!(integrator(implicit), Integrator::Implicit);
    assert!(!parse(implicit).unwrap().is_explicit());
}

#[test]
fn prestrain_is_range_checked() {
    let s = parse("extends = \"liver\"\n[material]\nprestrain = 0.1\nprestrain_depth_mm = 4\n")
        .unwrap();
    assert_eq!(s.material.prestrain, 0.1);
    assert_eq!(s.material.prestrain_depth_m, Some(0.004));
    let e = parse("extends = \"liver\"\n[material]\nprestrain = 0.5\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("material.prestrain") && e.contains("0.3"), "{e}");
    let e = parse("extends = \"liver\"\n[material]\nprestrain_depth_mm = 0\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("material.prestrain_depth_mm"), "{e}");
    // The stiff mode holds the layer too (`solver::projective`'s local step).
    let stiff = "extends = \"liver\"\n[material]\nprestrain = 0.1\n[features]\nstiff_mode = true\n";
    assert_eq!(parse(stiff).unwrap().material.prestrain, 0.1);
}

#[test]
fn file_paths_are_relative_to_the_scene() {
    let s = parse("[mesh]\nfile = \"organ.stl\"\nunits = \"mm\"\n[sampling]\nspacing_mm = 2.5\n")
        .unwrap();
    assert_eq!(s.mesh.source, MeshSource::File("scenes/organ.stl".into()));
    assert_eq!(s.mesh.units, LengthUnit::Mm);
    assert_eq!(s.sampling.spacing, SpacingRule::Spacing(0.0025));
}

#[test]
fn unknown_keys_are_rejected_with_their_line() {
    let e = parse("extends = \"liver\"\n[material]\nyoung = 3\n").unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, SceneError::Parse { .. }));
    assert!(msg.contains("young") && msg.contains("line 3"), "{msg}");
}

#[test]
fn out_of_range_values_name_their_key() {
    for (text, key) in [
        (
            "extends = \"liver\"\n[material]\npoisson_ratio = 0.5\n",
            "material.poisson_ratio",
        ),
        (
            "extends = \"liver\"\n[material]\nyoungs_modulus_kpa = -1\n",
            "material.youngs_modulus_kpa",
        ),
        (
            "extends = \"liver\"\n[sampling]\nspacing_mm = 2\ntarget_points = 100\n",
            "sampling",
        ),
        (
            "extends = \"liver\"\n[sampling]\ntarget_points = 100\nreal_time_points = 100\n",
            "sampling",
        ),
        (
            "extends = \"liver\"\n[sampling]\nreal_time_points = 4\n",
            "sampling.real_time_points",
        ),
        (
            "extends = \"block\"\n[features]\nripple = true\n",
            "features.ripple",
        ),
        (
            "extends = \"liver\"\n[force]\nmax_force_n = 100\n",
            "force.max_force_n",
        ),
        ("[mesh]\nbuiltin = \"kidney\"\n", "mesh.builtin"),
        ("extends = \"liver\"\nname = \" \"\n", "name"),
        ("name = \"x\"\n", "mesh"),
        ("extends = \"spleen\"\n", "extends"),
        (
            "extends = \"liver\"\n[mesh]\nscale = [1, 0, 1]\n",
            "mesh.scale",
        ),
        (
            "extends = \"liver\"\n[mesh]\nremesh = \"always\"\n",
            "mesh.remesh",
        ),
        ("extends = \"liver\"\n[mesh]\nremesh = 0\n", "mesh.remesh"),
        (
            "extends = \"liver\"\n[mesh]\nremesh = -2.5\n",
            "mesh.remesh",
        ),
        (
            "extends = \"liver\"\n[solver]\nmass_scaling_percent = 12\n",
            "solver.mass_scaling_percent",
        ),
        (
            "extends = \"liver\"\n[solver]\nintegrator = \"verlet\"\n",
            "solver.integrator",
        ),
        (
            "extends = \"liver\"\n[features]\nstiff_mode = true\n[solver]\nintegrator = \"implicit\"\n",
            "solver.integrator",
        ),
    ] {
        match parse(text) {
            Err(SceneError::Invalid { key: k, .. }) => assert_eq!(k, key, "{text}"),
            other => panic!("{text}: expected an Invalid error on {key}, got {other:?}"),
        }
    }
    // A huge or tiny value is said in exponent form, not in three hundred digits.
    let e = parse("extends = \"liver\"\n[sampling]\nspacing_mm = 1e300\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("1e300 mm is out of range"), "{e}");
}

#[test]
fn remesh_takes_a_word_or_an_edge_length_in_mm() {
    let rule = |value: &str| {
        parse(&format!("extends = \"liver\"\n[mesh]\nremesh = {value}\n")).map(|s| s.mesh.remesh)
    };
    assert_eq!(rule("\"off\""), Ok(RemeshRule::Off));
    assert_eq!(rule("\"auto\""), Ok(RemeshRule::Auto));
    assert_eq!(rule("2.5"), Ok(RemeshRule::EdgeM(0.0025)));
    assert_eq!(rule("3"), Ok(RemeshRule::EdgeM(0.003)));
    // Neither a word nor a number: the parser's message, with the line.
    let e = rule("true").unwrap_err().to_string();
    assert!(e.contains("line 3"), "{e}");
}

/// The complete example in docs/SCENES.md lists every key with its real default.
#[test]
fn docs_example_is_complete() {
    let doc = include_str!("../../../../../docs/SCENES.md");
    let start = doc.find("## Complete example").expect("section");
    let block = &doc[start..];
    let open = block.find("```toml\n").expect("toml block") + "```toml\n".len();
    let text = &block[open..open + block[open..].find("```").expect("end of block")];

    // Exhaustive destructuring: a new key fails to compile here until it is documented.
    let raw: RawScene = toml::from_str(text).expect("the example parses");
    let RawScene {
        name,
        description,
        extends,
        mesh,
        material,
        sampling,
        features,
        tool,
        force,
        solver,
        loads,
        supports,
    } = raw;
    assert!(name.is_some() && description.is_some() && extends.is_none());
    let RawMesh {
        builtin,
        file,
        units,
        scale,
        rotate_deg,
        translate_mm,
        max_triangles,
        max_file_mb,
        check_self_intersections,
        remesh,
    } = mesh.expect("[mesh]");
    assert!(builtin.is_none() && file.is_some() && units.is_some() && scale.is_some());
    assert!(rotate_deg.is_some() && translate_mm.is_some() && max_triangles.is_some());
    assert!(max_file_mb.is_some() && check_self_intersections.is_some() && remesh.is_some());
    let RawMaterial {
        youngs_modulus_kpa,
        poisson_ratio,
        density_kg_m3,
        damping_per_s,
        stiffening,
        prestrain,
        prestrain_depth_mm,
    } = material.expect("[material]");
    assert!(youngs_modulus_kpa.is_some() && poisson_ratio.is_some());
    assert!(density_kg_m3.is_some() && damping_per_s.is_some() && stiffening.is_some());
    // The layer's depth defaults to the lattice's spacing, which no number in the
    // example can show; the table documents it.
    assert!(prestrain.is_some() && prestrain_depth_mm.is_none());
    let RawSampling {
        spacing_mm,
        target_points,
        real_time_points,
        support_ratio,
        min_cell_fraction,
        neighbour_headroom,
    } = sampling.expect("[sampling]");
    // One of the three sampling rules: the example shows the default.
    assert!(spacing_mm.is_none() && target_points.is_none() && real_time_points.is_some());
    assert!(support_ratio.is_some());
    assert!(min_cell_fraction.is_some() && neighbour_headroom.is_some());
    let RawFeatures {
        cutting,
        haptics,
        virtual_points,
        ripple,
        volume_term,
        stiff_mode,
        frames,
        observers,
    } = features.expect("[features]");
    for f in [
        cutting,
        haptics,
        virtual_points,
        ripple,
        volume_term,
        stiff_mode,
        frames,
        observers,
    ] {
        assert!(f.is_some());
    }
    let RawTool {
        blade_length_mm,
        blade_width_mm,
        blade_thickness_mm,
    } = tool.expect("[tool]");
    assert!(blade_length_mm.is_some() && blade_width_mm.is_some() && blade_thickness_mm.is_some());
    let RawForce {
        rupture_force_n,
        rupture_displacement_mm,
        toughness_n_per_mm,
        fracture_by_energy,
        crack_tip_stiffening,
        friction_n,
        friction_depth_mm,
        ripple_amplitude,
        ripple_wavelength_mm,
        ripple_decay_s,
        crack_transparency,
        motion_deadband_mm,
        max_force_n,
    } = force.expect("[force]");
    assert!(fracture_by_energy.is_some());
    for f in [
        rupture_force_n,
        rupture_displacement_mm,
        toughness_n_per_mm,
        crack_tip_stiffening,
        friction_n,
        friction_depth_mm,
        ripple_amplitude,
        ripple_wavelength_mm,
        ripple_decay_s,
        crack_transparency,
        motion_deadband_mm,
        max_force_n,
    ] {
        assert!(f.is_some());
    }
    let RawSolver {
        mass_scaling_percent,
        integrator,
    } = solver.expect("[solver]");
    assert!(mass_scaling_percent.is_some() && integrator.is_some());
    let supports::RawLoads { gravity_m_s2 } = loads.expect("[loads]");
    assert!(gravity_m_s2.is_some());
    let supports::RawSupports {
        fixed,
        attachments,
        tray,
    } = supports.expect("[supports]");
    assert!(fixed.is_some() && attachments.is_some() && tray.is_some());

    // The values shown are the defaults of a mesh-file scene.
    let parsed = SceneSpec::from_toml(text, Path::new("docs/organ.toml")).expect("valid");
    let mut expected = for_mesh_file("docs/organ.stl".into(), LengthUnit::Mm);
    expected.name = "organ".into();
    expected.description = "a scanned organ".into();
    let (a, b) = (
        toml::Value::try_from(&parsed).unwrap(),
        toml::Value::try_from(&expected).unwrap(),
    );
    assert!(
        same_values(&a, &b),
        "documented defaults differ:\n{a}\nvs\n{b}"
    );
}

/// Structural equality with a relative tolerance on floats (mm → m conversions round).
fn same_values(a: &toml::Value, b: &toml::Value) -> bool {
    use toml::Value as V;
    match (a, b) {
        (V::Float(x), V::Float(y)) => (x - y).abs() <= 1e-12 * x.abs().max(y.abs()),
        (V::Table(x), V::Table(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| same_values(v, w)))
        }
        (V::Array(x), V::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(v, w)| same_values(v, w))
        }
        _ => a == b,
    }
}
