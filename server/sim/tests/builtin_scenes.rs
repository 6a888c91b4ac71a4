//! The built-in scenes: the paper's Table 1 counts (within 3 %), sizes, mesh quality, exact
//! volume totals, and what the validation scenes need (points on the faces of the beam).

use scalpel_sim::geometry::{MeshWarning, ValidationOptions, validate};
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{BUILTIN_SCENES, BuiltScene, RemeshRule, build_scene, builtin};

fn build(name: &str) -> BuiltScene {
    build_scene(&builtin(name).expect("built-in"), None, &mut Silent)
        .expect("built-in scenes build")
}

fn within(actual: usize, target: usize, fraction: f64) -> bool {
    (actual as f64 - target as f64).abs() <= fraction * target as f64
}

#[test]
fn table1_counts_are_within_three_percent() {
    // Paper Table 1: surface triangles and interior points.
    for (name, triangles, points) in [
        ("liver", 508, 1526),
        ("shoulder", 1842, 4812),
        ("cerebroma", 2601, 7086),
    ] {
        let s = build(name);
        assert!(
            within(s.mesh_stats.triangles, triangles, 0.03),
            "{name}: {} triangles",
            s.mesh_stats.triangles
        );
        assert!(
            within(s.model.points.len(), points, 0.03),
            "{name}: {} points",
            s.model.points.len()
        );
    }
}

#[test]
fn organ_sizes_match_the_paper() {
    for (name, dims) in [
        ("liver", [250.0, 150.0, 50.0]),
        ("cerebroma", [50.0, 40.0, 30.0]),
        ("beam", [40.0, 10.0, 10.0]),
    ] {
        let size = build(name).mesh_stats.bbox.size() * 1e3;
        for a in 0..3 {
            assert!((size[a] - dims[a]).abs() < 1e-6, "{name}: {size:?} mm");
        }
    }
}

#[test]
fn every_builtin_is_closed_smooth_and_volume_exact() {
    for name in BUILTIN_SCENES {
        let s = build(name);
        // (No repairs, and not remeshed: `remesh = "auto"` leaves good triangles alone.)
        assert!(s.mesh_warnings.is_empty(), "{name}: {:?}", s.mesh_warnings);
        assert!(
            s.mesh_stats.min_angle_deg >= 20.0,
            "{name}: min angle {}",
            s.mesh_stats.min_angle_deg
        );
        assert_eq!(s.mesh_stats.components, 1);
        let summary = s.model.summary();
        // Σ V_i is the enclosed volume (the issue asks for 1 %; the clipping is exact).
        assert!(
            summary.volume_error.abs() < 1e-9,
            "{name}: {}",
            summary.volume_error
        );
        let mass: f64 = s.model.points.mass_kg.iter().sum();
        assert!(
            (mass / (s.spec.material.density_kg_m3 * s.mesh_stats.volume_m3) - 1.0).abs() < 1e-9
        );
        assert_eq!(summary.weak_points, 0, "{name}");
        assert_eq!(summary.embedding.widened, 0, "{name}");
        // Re-validating the generated surface finds nothing to repair.
        let again = validate(s.model.surface.clone(), name, &ValidationOptions::default()).unwrap();
        assert!(again.warnings.is_empty());
    }
}

#[test]
fn beam_points_sit_on_faces_with_trapezoid_volumes() {
    let s = build("beam");
    let lattice = s.model.lattice;
    assert_eq!(lattice.dims, [17, 5, 5]);
    assert_eq!(s.model.points.len(), 17 * 5 * 5);
    let cell = lattice.spacing.powi(3);
    for (i, c) in s.model.points.lattice_coords.iter().enumerate() {
        let boundary = [(c[0], 16), (c[1], 4), (c[2], 4)]
            .iter()
            .filter(|(v, n)| *v == 0 || *v == *n)
            .count();
        let expected = cell * 0.5f64.powi(boundary as i32);
        assert!((s.model.points.volume_m3[i] / expected - 1.0).abs() < 1e-6);
    }
}

#[test]
fn neighbourhoods_are_symmetric_and_within_support() {
    let s = build("liver");
    let m = &s.model;
    let h = m.kernel.support_m;
    for i in 0..m.points.len() {
        for &j in m.neighbours.of(i) {
            let d = (m.points.rest[i] - m.points.rest[j as usize]).norm();
            assert!(d < h && d > 0.0);
            assert!(m.neighbours.of(j as usize).contains(&(i as u32)));
        }
    }
    // h = 2s on a lattice: at most 26 neighbours (6 + 12 + 8).
    assert!(m.summary().max_neighbours <= 26);
}

#[test]
fn surface_embedding_reproduces_rest_and_rigid_motion() {
    let s = build("cerebroma");
    let m = &s.model;
    let rotation = *nalgebra::Rotation3::from_euler_angles(0.3, -0.7, 1.1).matrix();
    let shift = scalpel_sim::math::Vec3::new(0.01, -0.02, 0.005);
    let moved: Vec<_> = m.points.rest.iter().map(|p| rotation * p + shift).collect();
    for v in 0..m.surface.positions.len() {
        let (_, w) = m.embedding.of(v);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let x = m.surface.positions[v];
        let at_rest = m
            .embedding
            .vertex_position(v, &x, &m.points.rest, &m.points.rest, |_| {
                scalpel_sim::math::Mat3::identity()
            });
        assert!((at_rest - x).norm() < 1e-12);
        // With the points rotated rigidly and F = R, the vertex moves rigidly too.
        let rigid = m
            .embedding
            .vertex_position(v, &x, &m.points.rest, &moved, |_| rotation);
        assert!((rigid - (rotation * x + shift)).norm() < 1e-12);
    }
}

#[test]
fn builds_are_deterministic() {
    let a = build("shoulder");
    let b = build("shoulder");
    assert_eq!(a.model.surface, b.model.surface);
    assert_eq!(a.model.points, b.model.points);
    assert_eq!(a.model.neighbours, b.model.neighbours);
    assert_eq!(a.model.embedding, b.model.embedding);
}

#[test]
fn an_asked_for_remesh_is_made_and_one_too_fine_is_refused() {
    let mut spec = builtin("liver").unwrap();
    spec.mesh.remesh = RemeshRule::EdgeM(0.012);
    let s = build_scene(&spec, None, &mut Silent).unwrap();
    let [MeshWarning::Remeshed(r)] = &s.mesh_warnings[..] else {
        panic!("{:?}", s.mesh_warnings)
    };
    assert_eq!(
        (r.triangles_before, r.triangles_after),
        (508, s.mesh_stats.triangles)
    );
    assert!(r.triangles_after > 700, "{r:?}");
    // A thousand times finer would be about 10⁹ triangles: refused before any work, and
    // the surface kept as it is.
    spec.mesh.remesh = RemeshRule::EdgeM(1.2e-5);
    let s = build_scene(&spec, None, &mut Silent).unwrap();
    let [MeshWarning::RemeshRefused { reason, .. }] = &s.mesh_warnings[..] else {
        panic!("{:?}", s.mesh_warnings)
    };
    assert!(reason.contains("mesh.max_triangles"), "{reason}");
    assert_eq!(s.mesh_stats.triangles, 508);
}
