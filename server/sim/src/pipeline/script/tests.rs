//! Tests of `script`.

use super::*;
use crate::scene::BuiltinMesh;

/// A ring (80 mm across, a 20 mm tube) has nothing above its centre: the default stroke
/// goes onto the top of the ring near it, as long as the top there goes on smoothly,
/// and no deeper than half the tube.
#[test]
fn a_shape_with_nothing_above_its_centre_is_cut_on_its_top_nearby() {
    let (big, small, n) = (0.04, 0.01, 48);
    let at = |i: usize, j: usize| {
        let (u, v) = (
            std::f64::consts::TAU * (i % n) as f64 / n as f64,
            std::f64::consts::TAU * (j % n) as f64 / n as f64,
        );
        Vec3::new(
            (big + small * v.cos()) * u.cos(),
            (big + small * v.cos()) * u.sin(),
            small * v.sin(),
        )
    };
    let positions: Vec<Vec3> = (0..n * n).map(|k| at(k / n, k % n)).collect();
    let id = |i: usize, j: usize| ((i % n) * n + j % n) as u32;
    let mut triangles = Vec::new();
    for i in 0..n {
        for j in 0..n {
            triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    let ring = TriMesh::new(positions, triangles);
    assert!(vertical_extent(&ring, 0.0, 0.0).is_none());
    let s = CutScript::default_for(&ring).expect("a stroke");
    // Along the cut (between going down and coming up), the tip is under the ring's top
    // all the way, and as deep below it as at the start.
    let cut = &s.keyframes[1..s.keyframes.len() - 1];
    let depth_at = |k: &Keyframe| {
        let (top, bottom) =
            vertical_extent(&ring, k.pose.tip_m.x, k.pose.tip_m.y).expect("over the ring");
        (top - k.pose.tip_m.z, top - bottom)
    };
    let (depth, thickness) = depth_at(&cut[0]);
    assert!(depth > 0.001 && depth <= 0.5 * thickness + 1e-9, "{depth}");
    for k in cut {
        assert!((depth_at(k).0 - depth).abs() < 1e-9, "{}", s.description);
    }
    let travel = (cut[cut.len() - 1].pose.tip_m - cut[0].pose.tip_m).norm();
    assert!(travel > 0.015, "{}", s.description);
}

/// The block's and the beam's centres are grid vertices of their meshes: a vertical line
/// there meets six triangles at each face, once.
#[test]
fn a_stroke_through_a_shared_vertex_is_as_deep_as_the_rule_says() {
    for (organ, depth_mm) in [(BuiltinMesh::Block, 9.0), (BuiltinMesh::Beam, 3.0)] {
        let s = CutScript::default_for(&organ.generate()).expect("a stroke");
        assert!(
            s.description.contains(&format!("{depth_mm:.1} mm deep")),
            "{}",
            s.description
        );
    }
}

#[test]
fn default_liver_cut_is_the_papers_stroke() {
    let liver = BuiltinMesh::Liver.generate();
    let s = CutScript::default_for(&liver).expect("a stroke");
    // 15 mm down at 5 mm/s, 60 mm along, 15 mm up: about 18 s.
    assert!((s.duration_s() - 18.0).abs() < 0.5, "{}", s.duration_s());
    let mid = s.pose_at(9.0);
    let (top, _) = vertical_extent(&liver, mid.tip_m.x, mid.tip_m.y).unwrap();
    assert!((top - mid.tip_m.z - DEFAULT_DEPTH_M).abs() < 1e-3);
    assert_eq!(s.pose_at(-1.0), s.keyframes[0].pose);
    assert_eq!(s.pose_at(1e9), s.keyframes.last().unwrap().pose);
}

/// Issue 45: `-1e308` was said as a 309-character number.
#[test]
fn a_huge_time_is_said_in_a_few_characters() {
    let csv =
        "t_s,tip_x_mm,tip_y_mm,tip_z_mm,edge_x,edge_y,edge_z\n0,0,0,10,0,0,1\n-1e308,0,0,0,,,\n";
    let e = CutScript::from_csv(csv, "s.csv").unwrap_err().to_string();
    assert!(e.contains("t_s = -1e308 must be within"), "{e}");
    assert!(e.len() < 200, "{e}");
}

#[test]
fn csv_scripts_read_like_toml_ones() {
    let toml = "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 10]\nedge = [0, 0, 1]\n\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n";
    let csv = format!("{CSV_HEADER}\n0,0,0,10,0,0,1\n1,0,0,0,,,\n");
    let a = CutScript::from_toml(toml, "a.toml").unwrap();
    let b = CutScript::from_csv(&csv, "a.csv").unwrap();
    assert_eq!(a.keyframes, b.keyframes);
    let facing = toml.replace("edge = [0, 0, 1]", "edge = [0, 0, 1]\nfacing = [0, 1, 0]");
    let csv = format!("{CSV_HEADER},{CSV_FACING_COLUMNS}\n0,0,0,10,0,0,1,0,1,0\n1,0,0,0,,,,,,\n");
    let a = CutScript::from_toml(&facing, "a.toml").unwrap();
    let b = CutScript::from_csv(&csv, "a.csv").unwrap();
    assert_eq!(a.keyframes, b.keyframes);
    for (text, expected) in [
        ("t,x\n".to_string(), "line 1: the header"),
        (format!("{CSV_HEADER}\n0,0,0\n"), "line 2: 7 columns"),
        (format!("{CSV_HEADER}\n0,0,0,x,0,0,1\n"), "line 2: column 4"),
        (format!("{CSV_HEADER}\n0,0,0,0,0,0,1\n"), "at least 2"),
        (
            format!("{CSV_HEADER}\n0,0,0,0,,,\n1,0,0,0,,,\n"),
            "keyframe 1: the first keyframe needs an edge",
        ),
    ] {
        let e = CutScript::from_csv(&text, "s.csv").unwrap_err().to_string();
        assert!(e.contains("s.csv") && e.contains(expected), "{e}");
    }
}

#[test]
fn script_files_are_checked() {
    let good = "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 10]\nedge = [0, 0, 1]\n\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n";
    let s = CutScript::from_toml(good, "a.toml").expect("valid");
    assert!((s.pose_at(0.5).tip_m.z - 0.005).abs() < 1e-12);
    // A blade turned to face +y keeps facing it (its back toward -y).
    let turned = good.replace("edge = [0, 0, 1]", "edge = [0, 0, 1]\nfacing = [0, 3, 0]");
    let s = CutScript::from_toml(&turned, "a.toml").expect("valid");
    let blade = crate::cut::Blade::at(&s.pose_at(0.5), &crate::scene::ToolSpec::default());
    assert!((blade.toward_back + Vec3::y()).norm() < 1e-12, "{blade:?}");
    let cases = [
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [0, 0, 1]\n",
            "at least 2",
        ),
        (
            "[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\nedge = [0, 0, 1]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n",
            "keyframe 2: t_s = 1 must be after",
        ),
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n",
            "keyframe 1: the first keyframe needs an edge",
        ),
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [0, 0, 0]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n",
            "non-zero direction",
        ),
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, nan, 0]\nedge = [0, 0, 1]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n",
            "must be finite",
        ),
        ("[[keyframe]]\nt_s = 0\ntip = [0, 0, 0]\n", "unknown field"),
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [0, 0, 1]\nfacing = [0, 0, -2]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n",
            "keyframe 1: facing = [0.0, 0.0, -2.0] must be a direction across the edge",
        ),
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [0, 0, 1]\nfacing = [1, 0, 0]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\nedge = [2, 0, 0]\n",
            "keyframe 2: facing = [1.0, 0.0, 0.0] must be a direction across the edge [2.0, 0.0, 0.0]",
        ),
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [1, nan, 2]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n",
            "keyframe 1: edge = [1.0, NaN, 2.0] must be a finite, non-zero direction",
        ),
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [0, 0, 1]\nfacing = [nan, 1, 0]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n",
            "keyframe 1: facing = [NaN, 1.0, 0.0] must be a finite, non-zero direction",
        ),
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [0, 0, 1]\nfacing = [0, 0, 0]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n",
            "keyframe 1: facing = [0.0, 0.0, 0.0] must be a finite, non-zero direction",
        ),
        // A teleport: 100 mm in a millisecond.
        (
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [0, 0, 1]\n[[keyframe]]\nt_s = 0.001\ntip_mm = [100, 0, 0]\n",
            "keyframe 2: the tip moves 100.0 mm in 0.001 s",
        ),
    ];
    for (text, want) in cases {
        let e = CutScript::from_toml(text, "s.toml")
            .expect_err(text)
            .to_string();
        assert!(e.contains(want) && e.starts_with("s.toml"), "{e}");
    }
    // Directions of any finite size are directions (1e200 overflowed the norm and the
    // blade turned upright; 1e-200 was called zero).
    for size in ["1e200", "1e-200"] {
        let text = format!(
            "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\nedge = [{size}, 0, 0]\n[[keyframe]]\nt_s = 1\ntip_mm = [0, 0, 0]\n"
        );
        let s = CutScript::from_toml(&text, "s.toml").expect("valid");
        let edge = s.pose_at(0.5).orientation * Vec3::z();
        assert!((edge - Vec3::x()).norm() < 1e-12, "{size}: {edge:?}");
    }
}
