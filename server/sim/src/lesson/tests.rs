use super::*;
use crate::math::Vec3;
use crate::scene::BuiltinMesh;

fn parse(text: &str) -> Result<LessonSpec, LessonError> {
    LessonSpec::from_toml(text, "test.toml")
}

const MINIMAL: &str = r#"
name = "t"
scene = "liver"
[[incision]]
points_mm = [[-30.0, 0.0, 25.0], [30.0, 0.0, 25.0]]
depth_mm = 10.0
"#;

#[test]
fn every_built_in_lesson_lays_on_its_organ() {
    for (name, _) in BUILTIN {
        let spec = builtin_lesson(name).unwrap();
        let mesh = BuiltinMesh::from_name(&spec.scene).unwrap().generate();
        let plan = Plan::new(spec, &mesh, name).unwrap_or_else(|e| panic!("{name}: {e}"));
        for inc in &plan.incisions {
            assert!(inc.length_m > 0.03, "{name}: {} m", inc.length_m);
            for w in inc.samples.windows(2) {
                let gap = (w[1].at - w[0].at).norm();
                assert!(gap < 2.0 * SAMPLE_M, "{name}: samples {gap} m apart");
            }
            // The normal points out of the organ: a step along it leaves the surface.
            for s in &inc.samples {
                assert!(
                    (s.out.norm() - 1.0).abs() < 1e-9 && s.out.z > 0.3,
                    "{name}: {s:?}"
                );
                assert!(s.tangent.dot(&s.out).abs() < 1e-9);
            }
        }
        // Every no-go structure lies below the path, clear of a careful cut's depth.
        for g in &plan.spec.no_go {
            for inc in &plan.incisions {
                for s in &inc.samples {
                    let reach = s.at - s.out * inc.depth_m;
                    assert!(
                        g.shape.segment_distance(&s.at, &reach) > g.contact_margin_m,
                        "{name}: {} within reach of the planned cut",
                        g.name
                    );
                }
            }
        }
    }
}

#[test]
fn the_liver_lesson_runs_60_mm_on_the_top() {
    let spec = builtin_lesson("liver-straight").unwrap();
    let plan = Plan::new(spec, &BuiltinMesh::Liver.generate(), "liver").unwrap();
    let inc = &plan.incisions[0];
    assert!((inc.length_m - 0.060).abs() < 0.004, "{}", inc.length_m);
    assert!(inc.samples.iter().all(|s| s.at.z > 0.015));
    let on = plan.nearest(&(inc.samples[40].at + Vec3::new(0.0, 0.002, 0.0)));
    let on = on.unwrap();
    assert_eq!((on.incision, on.sample), (0, 40));
    assert!((on.distance_m - 0.002).abs() < 2e-4, "{}", on.distance_m);
}

#[test]
fn a_bezier_path_is_sampled_along_its_curve() {
    let spec = builtin_lesson("shoulder-curved").unwrap();
    let plan = Plan::new(spec, &BuiltinMesh::Shoulder.generate(), "shoulder").unwrap();
    let inc = &plan.incisions[0];
    // The control polygon's chord is 40 mm; the curve bows 12.75 mm: longer than its chord.
    let chord = (inc.samples.last().unwrap().at - inc.samples[0].at).norm();
    assert!(inc.length_m > chord + 0.005, "{} vs {chord}", inc.length_m);
}

#[test]
fn unknown_keys_are_refused_with_their_place() {
    let e = parse(&format!("{MINIMAL}colour = 3\n")).unwrap_err();
    assert!(e.to_string().contains("colour"), "{e}");
    let e = parse(&MINIMAL.replace("depth_mm", "deep_mm")).unwrap_err();
    assert!(e.to_string().contains("deep_mm"), "{e}");
}

#[test]
fn out_of_range_values_name_their_key() {
    let cases = [
        (MINIMAL.replace("10.0\n", "-1.0\n"), "incision[0].depth_mm"),
        (
            format!("{MINIMAL}depth_tolerance_mm = 12.0\n"),
            "incision[0].depth_tolerance_mm",
        ),
        (
            format!("{MINIMAL}[force]\nwarning_n = 5.0\ncritical_n = 4.0\n"),
            "force.critical_n",
        ),
        (format!("time_limit_s = 0.0\n{MINIMAL}"), "time_limit_s"),
        (
            MINIMAL.replace("[[-30.0, 0.0, 25.0], ", "["),
            "incision[0].points_mm",
        ),
        (
            format!("{MINIMAL}bezier_mm = [[0.0, 0.0, 0.0]]\n"),
            "incision[0]",
        ),
        (
            format!(
                "{MINIMAL}[[no_go]]\nname = \"v\"\nsphere_mm = {{ centre = [0.0, 0.0, 0.0], radius = -2.0 }}\n"
            ),
            "no_go[0].sphere_mm.radius",
        ),
        (
            format!(
                "{MINIMAL}[[no_go]]\nname = \"v\"\ntube_mm = {{ from = [0.0, 0.0, 0.0], to = [0.0, 0.0, 0.0], radius = 2.0 }}\n"
            ),
            "no_go[0].tube_mm",
        ),
        (
            format!("{MINIMAL}[pass]\nmin_completed_percent = 120.0\n"),
            "pass.min_completed_percent",
        ),
        (
            MINIMAL.replace("25.0]]", "NaN]]").replace("NaN", "nan"),
            "incision[0].points_mm[1]",
        ),
    ];
    for (text, key) in cases {
        match parse(&text) {
            Err(LessonError::Invalid { key: k, .. }) => assert_eq!(k, key, "{text}"),
            other => panic!("{key}: {other:?}"),
        }
    }
}

#[test]
fn a_path_off_the_organ_is_refused_where_it_leaves() {
    let liver = BuiltinMesh::Liver.generate();
    let far = parse(&MINIMAL.replace("[30.0, 0.0, 25.0]", "[30.0, 0.0, 80.0]")).unwrap();
    let e = Plan::new(far, &liver, "test.toml").unwrap_err();
    assert!(
        e.to_string().contains("incision[0].points_mm[1]: is 5")
            && e.to_string().contains("from the organ's surface"),
        "{e}"
    );
    let outside = parse(&format!(
        "{MINIMAL}[[no_go]]\nname = \"moon\"\nsphere_mm = {{ centre = [0.0, 0.0, 900.0], radius = 2.0 }}\n"
    ))
    .unwrap();
    let e = Plan::new(outside, &liver, "test.toml").unwrap_err();
    assert!(
        e.to_string().contains("'moon' lies outside the organ"),
        "{e}"
    );
}

#[test]
fn a_script_written_as_toml_reads_back() {
    let spec = builtin_lesson("liver-straight").unwrap();
    let liver = BuiltinMesh::Liver.generate();
    let plan = Plan::new(spec, &liver, "liver").unwrap();
    for who in Trainee::ALL {
        let script = trainee_script(&plan, &liver, who);
        let back = crate::pipeline::CutScript::from_toml(&script.to_toml(), "t.toml").unwrap();
        assert_eq!(back.keyframes.len(), script.keyframes.len());
        for (a, b) in back.keyframes.iter().zip(&script.keyframes) {
            assert!((a.t_s - b.t_s).abs() < 1e-8);
            assert!((a.pose.tip_m - b.pose.tip_m).norm() < 1e-8);
            assert!(a.pose.orientation.angle_to(&b.pose.orientation) < 1e-6);
        }
    }
}

#[test]
fn a_cut_triangle_reaches_a_structure_by_its_nearest_point() {
    let tri = [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.010, 0.0, 0.0),
        Vec3::new(0.0, 0.010, 0.0),
    ];
    // A tube crossing under the triangle's middle, 1 mm below, radius 1.5 mm: inside by 0.5.
    let tube = NoGoShape::Tube {
        from: Vec3::new(-0.02, 0.003, -0.001),
        to: Vec3::new(0.02, 0.003, -0.001),
        radius: 0.0015,
    };
    assert!((tube.triangle_distance(&tri) + 0.0005).abs() < 1e-12);
    // Its axis through the triangle: the whole radius inside.
    let through = NoGoShape::Tube {
        from: Vec3::new(0.002, 0.002, -0.01),
        to: Vec3::new(0.002, 0.002, 0.01),
        radius: 0.001,
    };
    assert!((through.triangle_distance(&tri) + 0.001).abs() < 1e-12);
    // A ball beside the triangle's long edge, by the edge's distance.
    let ball = NoGoShape::Sphere {
        centre: Vec3::new(0.008, 0.008, 0.0),
        radius: 0.001,
    };
    let edge_distance = (0.016f64 - 0.010) / 2f64.sqrt();
    assert!((ball.triangle_distance(&tri) - (edge_distance - 0.001)).abs() < 1e-12);
    // The vertices alone would have missed the first tube by 1.3 mm.
    assert!(tri.iter().all(|v| tube.distance(v) > 0.001));
}

#[test]
fn a_path_drawn_into_the_organ_instead_of_along_it_is_refused() {
    let liver = BuiltinMesh::Liver.generate();
    // Straight down through the top at the liver's middle: it lands on one point.
    let down = parse(&MINIMAL.replace(
        "[[-30.0, 0.0, 25.0], [30.0, 0.0, 25.0]]",
        "[[0.0, 0.0, 30.0], [0.0, 0.0, 40.0]]",
    ))
    .unwrap();
    let e = Plan::new(down, &liver, "test.toml").unwrap_err();
    assert!(
        e.to_string().contains("incision[0].points_mm")
            && e.to_string().contains("lands on the surface"),
        "{e}"
    );
}
