//! Property tests of the cell-clipped lattice volumes: for random boxes and ellipsoids at
//! random spacings, every fraction lies in [0, 1] and the volumes add up to the enclosed
//! volume of the surface.

use proptest::prelude::*;
use scalpel_sim::geometry::TriMesh;
use scalpel_sim::geometry::organs::box_mesh;
use scalpel_sim::math::Vec3;
use scalpel_sim::model::cell_volume::clipped_cell_fractions;
use scalpel_sim::model::lattice::{place_lattice, sample};

/// A latitude–longitude ellipsoid, rotated and shifted, wound outward.
fn ellipsoid(radii: Vec3, rings: usize, segments: usize, angles: [f64; 3], shift: Vec3) -> TriMesh {
    let rotation = nalgebra::Rotation3::from_euler_angles(angles[0], angles[1], angles[2]);
    let mut positions = vec![Vec3::new(0.0, 0.0, radii.z)];
    for r in 1..rings {
        let theta = std::f64::consts::PI * r as f64 / rings as f64;
        for s in 0..segments {
            let phi = 2.0 * std::f64::consts::PI * s as f64 / segments as f64;
            positions.push(Vec3::new(
                radii.x * theta.sin() * phi.cos(),
                radii.y * theta.sin() * phi.sin(),
                radii.z * theta.cos(),
            ));
        }
    }
    positions.push(Vec3::new(0.0, 0.0, -radii.z));
    let south = positions.len() as u32 - 1;
    let ring = |r: usize, s: usize| (1 + (r - 1) * segments + s % segments) as u32;
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, ring(1, s), ring(1, s + 1)]);
        triangles.push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            triangles.push([ring(r, s), ring(r + 1, s), ring(r + 1, s + 1)]);
            triangles.push([ring(r, s), ring(r + 1, s + 1), ring(r, s + 1)]);
        }
    }
    let mut mesh = TriMesh::new(positions, triangles);
    mesh.map_positions(|p| rotation * p + shift);
    mesh
}

fn check_totals(mesh: &TriMesh, spacing: f64) -> Result<(), TestCaseError> {
    let lattice = place_lattice(&mesh.bbox(), spacing);
    let fractions = clipped_cell_fractions(mesh, &lattice);
    for f in &fractions {
        prop_assert!((0.0..=1.0).contains(f));
    }
    let total = fractions.iter().sum::<f64>() * spacing.powi(3);
    let volume = mesh.signed_volume();
    prop_assert!(volume > 0.0);
    prop_assert!(
        (total / volume - 1.0).abs() < 1e-7,
        "Σ = {total}, volume = {volume}"
    );
    // The kept points carry the same total after slivers are merged.
    let points = sample(mesh, spacing, 0.1);
    let kept: f64 = points.volumes.iter().sum();
    prop_assert!((kept / volume - 1.0).abs() < 1e-7);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn box_volumes_add_up(
        size in (0.005f64..0.08, 0.005f64..0.08, 0.005f64..0.08),
        divisions in (1usize..6, 1usize..6, 1usize..6),
        points_across in 3.0f64..14.0,
        shift in (-0.01f64..0.01, -0.01f64..0.01, -0.01f64..0.01),
    ) {
        let mut mesh = box_mesh(Vec3::new(size.0, size.1, size.2), [divisions.0, divisions.1, divisions.2]);
        mesh.map_positions(|p| p + Vec3::new(shift.0, shift.1, shift.2));
        let spacing = size.0.min(size.1).min(size.2) / points_across;
        check_totals(&mesh, spacing)?;
    }

    #[test]
    fn ellipsoid_volumes_add_up(
        radii in (0.004f64..0.05, 0.004f64..0.05, 0.004f64..0.05),
        angles in (0.0f64..6.3, 0.0f64..6.3, 0.0f64..6.3),
        rings in 4usize..16,
        segments in 6usize..24,
        points_across in 3.0f64..16.0,
    ) {
        let radii = Vec3::new(radii.0, radii.1, radii.2);
        let mesh = ellipsoid(radii, rings, segments, [angles.0, angles.1, angles.2], Vec3::new(0.003, -0.001, 0.002));
        check_totals(&mesh, 2.0 * radii.min() / points_across)?;
    }
}
