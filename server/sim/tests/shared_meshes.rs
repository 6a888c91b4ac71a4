//! The real organ meshes in ../shared/meshes import, validate and build into models.
//! They are data outside the project, so these tests are ignored by default; `.ci/run` runs
//! them with `cargo test -- --ignored shared_`. These check the import as it is
//! (`remesh = "off"`); what the default remeshing makes of them is checked in
//! `geometry::remesh`.

use std::path::PathBuf;

use scalpel_sim::geometry::{LengthUnit, MeshWarning};
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{RemeshRule, build_scene, for_mesh_file};

fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/meshes")
        .join(name)
}

fn check(
    name: &str,
    units: LengthUnit,
    triangles: usize,
    vertices: usize,
    bbox_mm: [f64; 3],
) -> Vec<MeshWarning> {
    let path = shared(name);
    let bytes = std::fs::read(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (is ../shared beside the project?)", path.display()));
    let mut spec = for_mesh_file(path, units);
    spec.mesh.remesh = RemeshRule::Off;
    let scene =
        build_scene(&spec, Some(&bytes), &mut Silent).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(scene.mesh_stats.triangles, triangles, "{name}");
    assert_eq!(scene.mesh_stats.vertices, vertices, "{name}");
    assert_eq!(scene.mesh_stats.components, 1);
    let size = scene.mesh_stats.bbox.size() * 1e3;
    for a in 0..3 {
        assert!((size[a] - bbox_mm[a]).abs() < 0.15, "{name}: {size:?}");
    }
    let summary = scene.model.summary();
    assert!(
        summary.volume_error.abs() < 1e-9,
        "{name}: {}",
        summary.volume_error
    );
    // A mesh file's default sampling: 2000 points where a 1 ms tick of the whole body
    // affords them, fewer where not (scene::real_time) — only the 12 mm tumour.
    let plan = scene
        .sampling_plan
        .expect("a mesh file's default sampling is planned");
    assert!(plan.first.points.abs_diff(2000) < 60, "{name}: {plan:?}");
    assert!(plan.fits(), "{name}: {plan:?}");
    assert_eq!(plan.resampled(), name.contains("Tumor"), "{name}: {plan:?}");
    assert_eq!(summary.points, plan.kept.points, "{name}");
    scene.mesh_warnings
}

#[test]
#[ignore = "reads ../shared/meshes"]
fn shared_pig_liver_tet_mesh_reduces_to_its_boundary() {
    let warnings = check(
        "pig_liver_lobe0_992tet.vtk",
        LengthUnit::M,
        500,
        252,
        [184.4, 120.0, 45.4],
    );
    // The tetrahedral mesh's interior nodes are not on the surface.
    assert_eq!(
        warnings,
        vec![MeshWarning::DroppedUnusedVertices { count: 63 }]
    );
}

#[test]
#[ignore = "reads ../shared/meshes"]
fn shared_pig_liver_surface() {
    assert!(
        check(
            "pig_liver_lobe0_surface500.obj",
            LengthUnit::M,
            500,
            252,
            [184.4, 120.0, 45.4]
        )
        .is_empty()
    );
}

#[test]
#[ignore = "reads ../shared/meshes"]
fn shared_deltoid_with_quads_is_triangulated() {
    assert!(
        check(
            "deltoid.obj",
            LengthUnit::Mm,
            2672,
            1338,
            [153.1, 182.1, 180.5]
        )
        .is_empty()
    );
    assert!(
        check(
            "deltoid_tri.obj",
            LengthUnit::Mm,
            2672,
            1338,
            [153.1, 182.1, 180.5]
        )
        .is_empty()
    );
}

#[test]
#[ignore = "reads ../shared/meshes"]
fn shared_tumour_in_centimetres() {
    assert!(
        check(
            "liver_tumour_PPP_Tumor.obj",
            LengthUnit::Cm,
            592,
            298,
            [11.2, 12.0, 11.4]
        )
        .is_empty()
    );
}

#[test]
#[ignore = "reads ../shared/meshes"]
fn shared_sphere_with_two_objects() {
    assert!(
        check(
            "sofa_sphere_05.obj",
            LengthUnit::Mm,
            500,
            252,
            [99.5, 99.4, 100.0]
        )
        .is_empty()
    );
}
