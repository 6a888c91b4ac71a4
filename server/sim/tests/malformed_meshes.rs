//! Every kind of malformed mesh gets its own typed error (or, where a repair is safe, is
//! accepted with a warning), and no input makes the importer panic.

use scalpel_sim::geometry::{
    ImportLimits, LengthUnit, MeshFormat, MeshImportError, MeshValidationError, MeshWarning,
    ValidatedMesh, ValidationOptions, import_mesh, validate,
};

/// What loading a file gave: an import error, a validation error, or an accepted mesh.
#[derive(Debug)]
enum Outcome {
    Import(MeshImportError),
    Invalid(MeshValidationError),
    Accepted(Box<ValidatedMesh>),
}

fn load(name: &str, bytes: &[u8]) -> Outcome {
    load_with(name, bytes, &ImportLimits::default())
}

fn load_with(name: &str, bytes: &[u8], limits: &ImportLimits) -> Outcome {
    let format = match MeshFormat::from_file_name(name) {
        Ok(f) => f,
        Err(e) => return Outcome::Import(e),
    };
    match import_mesh(bytes, format, name, LengthUnit::Mm, limits) {
        Err(e) => Outcome::Import(e),
        Ok(mesh) => match validate(mesh, name, &ValidationOptions::default()) {
            Err(e) => Outcome::Invalid(e),
            Ok(v) => Outcome::Accepted(Box::new(v)),
        },
    }
}

const TETRA_VERTICES: &str = "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\n";
const TETRA_FACES: &str = "f 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n";

fn tetra_obj() -> String {
    format!("{TETRA_VERTICES}{TETRA_FACES}")
}

fn binary_stl(triangles: &[[[f32; 3]; 3]], announced: u32) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&announced.to_le_bytes());
    for t in triangles {
        b.extend_from_slice(&[0u8; 12]);
        for v in t {
            for c in v {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        b.extend_from_slice(&[0u8; 2]);
    }
    b
}

fn tetra_triangles() -> Vec<[[f32; 3]; 3]> {
    let v = [
        [0.0, 0.0, 0.0],
        [10.0, 0.0, 0.0],
        [0.0, 10.0, 0.0],
        [0.0, 0.0, 10.0],
    ];
    [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]
        .iter()
        .map(|t| [v[t[0]], v[t[1]], v[t[2]]])
        .collect()
}

#[test]
fn well_formed_tetrahedron_is_accepted_in_every_format() {
    let obj = load("tetra.obj", tetra_obj().as_bytes());
    let stl = load("tetra.stl", &binary_stl(&tetra_triangles(), 4));
    let ascii_stl = {
        let mut s = String::from("solid t\n");
        for t in tetra_triangles() {
            s += "facet normal 0 0 0\nouter loop\n";
            for v in t {
                s += &format!("vertex {} {} {}\n", v[0], v[1], v[2]);
            }
            s += "endloop\nendfacet\n";
        }
        s += "endsolid t\n";
        load("tetra.stl", s.as_bytes())
    };
    let ply = load(
        "tetra.ply",
        b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n10 0 0\n0 10 0\n0 0 10\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n",
    );
    let vtk = load(
        "tetra.vtk",
        b"# vtk DataFile Version 3.0\ntetra\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0 10 0 0 0 10 0 0 0 10\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n",
    );
    for (name, outcome) in [
        ("obj", obj),
        ("binary stl", stl),
        ("ascii stl", ascii_stl),
        ("ply", ply),
        ("vtk", vtk),
    ] {
        match outcome {
            Outcome::Accepted(v) => {
                assert_eq!(v.stats.triangles, 4, "{name}");
                assert!(
                    (v.stats.volume_m3 - 1e-6 / 6.0).abs() < 1e-15,
                    "{name}: {}",
                    v.stats.volume_m3
                );
            }
            other => panic!("{name}: {other:?}"),
        }
    }
}

#[test]
fn open_mesh_is_rejected_with_the_boundary_edge() {
    let text = format!("{TETRA_VERTICES}f 1 3 2\nf 1 2 4\nf 2 3 4\n");
    match load("open.obj", text.as_bytes()) {
        Outcome::Invalid(MeshValidationError::OpenBoundary { count, file, .. }) => {
            assert_eq!(count, 3);
            assert_eq!(file, "open.obj");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn non_manifold_edge_is_rejected() {
    // A fin: a fifth triangle on the tetrahedron's edge 1–2.
    let text = format!("{}v 5 -10 5\nf 1 2 5\n", tetra_obj());
    match load("fin.obj", text.as_bytes()) {
        Outcome::Invalid(MeshValidationError::NonManifoldEdge { triangles, .. }) => {
            assert_eq!(triangles, 3)
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn non_manifold_vertex_is_rejected() {
    // Two tetrahedra touching at one vertex.
    let text = format!(
        "{TETRA_VERTICES}v -10 0 0\nv 0 -10 0\nv 0 0 -10\n{TETRA_FACES}f 1 6 5\nf 1 7 6\nf 1 5 7\nf 5 6 7\n"
    );
    match load("hourglass.obj", text.as_bytes()) {
        Outcome::Invalid(MeshValidationError::NonManifoldVertex { vertex, .. }) => {
            assert_eq!(vertex, 0)
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn inverted_mesh_is_flipped_with_a_warning() {
    let text = format!("{TETRA_VERTICES}f 1 2 3\nf 1 4 2\nf 2 4 3\nf 1 3 4\n");
    match load("inverted.obj", text.as_bytes()) {
        Outcome::Accepted(v) => {
            assert!(v.stats.volume_m3 > 0.0);
            assert!(
                v.warnings.iter().any(|w| matches!(
                    w,
                    MeshWarning::FlippedInvertedComponent { triangles: 4, .. }
                )),
                "{:?}",
                v.warnings
            );
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn one_backwards_triangle_is_reoriented_with_a_warning() {
    let text = format!("{TETRA_VERTICES}f 1 3 2\nf 1 2 4\nf 2 4 3\nf 1 4 3\n");
    match load("patchy.obj", text.as_bytes()) {
        Outcome::Accepted(v) => assert!(
            v.warnings
                .contains(&MeshWarning::ReorientedTriangles { count: 1 }),
            "{:?}",
            v.warnings
        ),
        other => panic!("{other:?}"),
    }
}

#[test]
fn nan_vertex_is_rejected_with_its_line() {
    let text = "v 0 0 0\nv nan 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n";
    match load("nan.obj", text.as_bytes()) {
        Outcome::Import(MeshImportError::NonFiniteCoordinate { line, vertex, .. }) => {
            assert_eq!(line, Some(2));
            assert_eq!(vertex, 1);
        }
        other => panic!("{other:?}"),
    }
    // Binary formats have no lines; the vertex is still named.
    let mut t = tetra_triangles();
    t[2][1][0] = f32::INFINITY;
    assert!(matches!(
        load("inf.stl", &binary_stl(&t, 4)),
        Outcome::Import(MeshImportError::NonFiniteCoordinate { .. })
    ));
}

#[test]
fn zero_area_triangle_is_repaired_with_a_warning() {
    // Vertex 5 sits on the middle of edge 1–2; triangle (1, 2, 5) has zero area and closes
    // the surface. Flipping edge 1–2 removes it.
    let text = "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nv 5 0 0\n\
                f 1 3 5\nf 5 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\nf 1 5 2\n";
    match load("sliver.obj", text.as_bytes()) {
        Outcome::Accepted(v) => {
            assert!(
                v.warnings
                    .contains(&MeshWarning::RepairedZeroAreaTriangles { count: 1 }),
                "{:?}",
                v.warnings
            );
            assert!(v.stats.min_angle_deg > 1.0);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn duplicate_vertices_are_merged_and_collapsed_triangles_removed() {
    // Every triangle has its own three vertices (as in STL), plus one collapsed triangle.
    let mut text = String::new();
    let v = ["0 0 0", "10 0 0", "0 10 0", "0 0 10"];
    let mut k = 0;
    for f in [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2], [0, 0, 1]] {
        for i in f {
            text += &format!("v {}\n", v[i]);
        }
        text += &format!("f {} {} {}\n", k + 1, k + 2, k + 3);
        k += 3;
    }
    match load("soup.obj", text.as_bytes()) {
        Outcome::Accepted(v) => {
            assert_eq!(v.stats.vertices, 4);
            assert!(
                v.warnings
                    .contains(&MeshWarning::MergedDuplicateVertices { count: 11 })
            );
            assert!(
                v.warnings
                    .contains(&MeshWarning::RemovedCollapsedTriangles { count: 1 })
            );
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn self_intersecting_mesh_is_rejected() {
    // Two tetrahedra pushed through each other.
    let text = format!(
        "{}v 3 3 3\nv 13 3 3\nv 3 13 3\nv 3 3 13\nf 5 7 6\nf 5 6 8\nf 6 7 8\nf 5 8 7\n",
        tetra_obj()
    );
    match load("overlap.obj", text.as_bytes()) {
        Outcome::Invalid(MeshValidationError::SelfIntersection { count, .. }) => assert!(count > 0),
        other => panic!("{other:?}"),
    }
}

#[test]
fn empty_files_are_rejected() {
    for name in ["empty.obj", "empty.stl", "empty.ply", "empty.vtk"] {
        assert!(
            matches!(
                load(name, b""),
                Outcome::Import(MeshImportError::EmptyFile { .. })
            ),
            "{name}"
        );
        assert!(
            matches!(
                load(name, b"  \n\t\n"),
                Outcome::Import(MeshImportError::EmptyFile { .. })
            ),
            "{name}"
        );
    }
    // Vertices but no faces: nothing to simulate.
    assert!(matches!(
        load("points.obj", TETRA_VERTICES.as_bytes()),
        Outcome::Import(MeshImportError::Unsupported { .. })
    ));
}

#[test]
fn truncated_binary_stl_is_rejected_with_sizes() {
    let mut bytes = binary_stl(&tetra_triangles(), 4);
    bytes.truncate(bytes.len() - 17);
    match load("cut.stl", &bytes) {
        Outcome::Import(MeshImportError::Truncated {
            expected, actual, ..
        }) => {
            assert_eq!(expected, 84 + 200);
            assert_eq!(actual, 84 + 200 - 17);
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        load("tiny.stl", &[1u8; 40]),
        Outcome::Import(MeshImportError::Truncated { .. })
    ));
}

#[test]
fn absurd_counts_are_rejected_before_allocating() {
    // Binary STL announcing four billion triangles.
    assert!(matches!(
        load("huge.stl", &binary_stl(&tetra_triangles(), 4_000_000_000)),
        Outcome::Import(MeshImportError::TooManyElements { .. })
    ));
    // PLY announcing 10^11 vertices.
    let ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 100000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    assert!(matches!(
        load("huge.ply", ply),
        Outcome::Import(MeshImportError::TooManyElements { .. })
    ));
    // PLY whose counts are under the cap but cannot fit in the file.
    let ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    assert!(matches!(
        load("short.ply", ply),
        Outcome::Import(MeshImportError::Truncated { .. })
    ));
    // Legacy VTK announcing 10^12 points.
    let vtk = b"# vtk DataFile Version 2.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 999999999999 float\n0 0 0\n";
    assert!(matches!(
        load("huge.vtk", vtk),
        Outcome::Import(MeshImportError::TooManyElements { .. })
    ));
    let vtk =
        b"# vtk DataFile Version 2.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 3000000 float\n0 0 0\n";
    assert!(matches!(
        load("short.vtk", vtk),
        Outcome::Import(MeshImportError::Truncated { .. })
    ));
    // A configured cap smaller than the mesh.
    let limits = ImportLimits {
        max_triangles: 3,
        ..ImportLimits::default()
    };
    assert!(matches!(
        load_with("tetra.obj", tetra_obj().as_bytes(), &limits),
        Outcome::Import(MeshImportError::TooManyElements { .. })
    ));
    let limits = ImportLimits {
        max_file_bytes: 10,
        ..ImportLimits::default()
    };
    assert!(matches!(
        load_with("tetra.obj", tetra_obj().as_bytes(), &limits),
        Outcome::Import(MeshImportError::FileTooLarge { .. })
    ));
}

#[test]
fn wrong_extension_is_rejected() {
    for name in ["organ.txt", "organ", "organ.stp", "organ.vtu"] {
        match load(name, tetra_obj().as_bytes()) {
            Outcome::Import(e @ MeshImportError::UnsupportedExtension { .. }) => {
                assert!(e.to_string().contains(".obj, .stl, .ply or .vtk"), "{e}");
            }
            other => panic!("{name}: {other:?}"),
        }
    }
    // Content that does not match its extension fails to parse, with the format named.
    match load("actually_obj.ply", tetra_obj().as_bytes()) {
        Outcome::Import(MeshImportError::Parse { format: "PLY", .. }) => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn face_index_out_of_range_names_the_line() {
    let text = format!("{TETRA_VERTICES}f 1 3 2\nf 1 2 9\n");
    match load("bad_index.obj", text.as_bytes()) {
        Outcome::Import(MeshImportError::IndexOutOfRange {
            line,
            index,
            vertices,
            ..
        }) => {
            assert_eq!((line, index, vertices), (Some(6), 9, 4));
        }
        other => panic!("{other:?}"),
    }
    let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    assert!(matches!(
        load("bad.ply", ply),
        Outcome::Import(MeshImportError::IndexOutOfRange { face: 0, .. })
    ));
}

#[test]
fn garbage_numbers_name_the_line() {
    let text = "v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n";
    match load("garbage.obj", text.as_bytes()) {
        Outcome::Import(MeshImportError::Parse { line: Some(2), .. }) => {}
        other => panic!("{other:?}"),
    }
    let vtk = b"# vtk DataFile Version 2.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n0 0 0\n1 0 oops\n0 1 0\nPOLYGONS 1 4\n3 0 1 2\n";
    match load("garbage.vtk", vtk) {
        Outcome::Import(MeshImportError::Parse { line: Some(7), .. }) => {}
        other => panic!("{other:?}"),
    }
    let vtk =
        b"# vtk DataFile Version 2.0\nx\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 2 2\n";
    assert!(matches!(
        load("image.vtk", vtk),
        Outcome::Import(MeshImportError::Unsupported { .. })
    ));
}

#[test]
fn errors_say_where_and_what_to_do() {
    let text = format!("{TETRA_VERTICES}f 1 3 2\nf 1 2 4\nf 2 3 4\n");
    let Outcome::Invalid(e) = load("open.obj", text.as_bytes()) else {
        panic!("expected a validation error")
    };
    let msg = e.to_string();
    assert!(msg.starts_with("open.obj: "), "{msg}");
    assert!(msg.contains("mm") && msg.contains("triangle"), "{msg}");
    assert!(msg.contains("fill the holes"), "{msg}");
}

mod never_panics {
    use super::*;
    use proptest::prelude::*;

    fn corpus() -> Vec<(&'static str, Vec<u8>)> {
        vec![
            ("a.obj", tetra_obj().into_bytes()),
            ("a.stl", binary_stl(&tetra_triangles(), 4)),
            (
                "a.ply",
                b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n10 0 0\n0 10 0\n0 0 10\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n".to_vec(),
            ),
            (
                "a.vtk",
                b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0 10 0 0 0 10 0 0 0 10\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n".to_vec(),
            ),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

        /// Truncations and byte flips of valid files give Ok or a typed error, never a panic.
        #[test]
        fn mutated_files_do_not_panic(which in 0usize..4, cut in 0.0f64..1.0, flips in proptest::collection::vec((0.0f64..1.0, any::<u8>()), 0..6)) {
            let (name, mut bytes) = corpus().swap_remove(which);
            let len = ((bytes.len() as f64) * cut) as usize;
            if !flips.is_empty() {
                for (at, b) in flips {
                    let i = ((bytes.len() as f64) * at) as usize % bytes.len();
                    bytes[i] = b;
                }
            } else {
                bytes.truncate(len.max(1));
            }
            let _ = load(name, &bytes);
        }

        /// Random bytes under every extension never panic.
        #[test]
        fn random_bytes_do_not_panic(which in 0usize..4, bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
            let name = ["r.obj", "r.stl", "r.ply", "r.vtk"][which];
            let _ = load(name, &bytes);
        }
    }
}

mod binary_and_cell_formats {
    use super::*;

    fn cube_corners() -> [[f32; 3]; 8] {
        [
            [0.0, 0.0, 0.0],
            [10.0, 0.0, 0.0],
            [10.0, 10.0, 0.0],
            [0.0, 10.0, 0.0],
            [0.0, 0.0, 10.0],
            [10.0, 0.0, 10.0],
            [10.0, 10.0, 10.0],
            [0.0, 10.0, 10.0],
        ]
    }

    /// Outward quads of the cube above.
    const CUBE_QUADS: [[u32; 4]; 6] = [
        [0, 3, 2, 1],
        [4, 5, 6, 7],
        [0, 1, 5, 4],
        [1, 2, 6, 5],
        [2, 3, 7, 6],
        [3, 0, 4, 7],
    ];

    fn accepted_cube(name: &str, bytes: &[u8]) {
        match load(name, bytes) {
            Outcome::Accepted(v) => {
                assert_eq!(v.stats.triangles, 12, "{name}");
                assert_eq!(v.stats.vertices, 8, "{name}");
                assert!(
                    (v.stats.volume_m3 - 1e-6).abs() < 1e-15,
                    "{name}: {}",
                    v.stats.volume_m3
                );
            }
            other => panic!("{name}: {other:?}"),
        }
    }

    fn binary_ply(big_endian: bool) -> Vec<u8> {
        let enc = if big_endian {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        };
        let mut b = format!(
            "ply\nformat {enc} 1.0\ncomment scalpel test\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n"
        )
        .into_bytes();
        for v in cube_corners() {
            for c in v {
                b.extend_from_slice(&if big_endian {
                    c.to_be_bytes()
                } else {
                    c.to_le_bytes()
                });
            }
        }
        for q in CUBE_QUADS {
            b.push(4);
            for i in q {
                let i = i as i32;
                b.extend_from_slice(&if big_endian {
                    i.to_be_bytes()
                } else {
                    i.to_le_bytes()
                });
            }
        }
        b
    }

    #[test]
    fn binary_ply_in_both_byte_orders() {
        accepted_cube("cube_le.ply", &binary_ply(false));
        accepted_cube("cube_be.ply", &binary_ply(true));
        // Cut mid-payload: a parse error, not a panic or a partial mesh.
        let mut cut = binary_ply(false);
        cut.truncate(cut.len() - 9);
        assert!(matches!(
            load("cut.ply", &cut),
            Outcome::Import(MeshImportError::Parse { .. } | MeshImportError::Truncated { .. })
        ));
    }

    #[test]
    fn binary_legacy_vtk_polydata() {
        let mut b = b"# vtk DataFile Version 3.0\ncube\nBINARY\nDATASET POLYDATA\nPOINTS 8 float\n"
            .to_vec();
        for v in cube_corners() {
            for c in v {
                b.extend_from_slice(&c.to_be_bytes());
            }
        }
        b.extend_from_slice(b"\nPOLYGONS 6 30\n");
        for q in CUBE_QUADS {
            b.extend_from_slice(&4i32.to_be_bytes());
            for i in q {
                b.extend_from_slice(&(i as i32).to_be_bytes());
            }
        }
        b.extend_from_slice(b"\nPOINT_DATA 8\nSCALARS x float 1\nLOOKUP_TABLE default\n");
        accepted_cube("cube_bin.vtk", &b);
    }

    #[test]
    fn vtk5_offsets_and_connectivity() {
        let mut t = String::from(
            "# vtk DataFile Version 5.1\ncube\nASCII\nDATASET POLYDATA\nPOINTS 8 float\n",
        );
        for v in cube_corners() {
            t += &format!("{} {} {}\n", v[0], v[1], v[2]);
        }
        t += "POLYGONS 7 24\nOFFSETS vtktypeint64\n0 4 8 12 16 20 24\nCONNECTIVITY vtktypeint64\n";
        for q in CUBE_QUADS {
            t += &format!("{} {} {} {}\n", q[0], q[1], q[2], q[3]);
        }
        accepted_cube("cube5.vtk", t.as_bytes());
    }

    #[test]
    fn hexahedron_and_tetrahedra_reduce_to_their_boundary() {
        let mut t = String::from(
            "# vtk DataFile Version 2.0\nhex\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 8 float\n",
        );
        for v in cube_corners() {
            t += &format!("{} {} {}\n", v[0], v[1], v[2]);
        }
        t += "CELLS 1 9\n8 0 1 2 3 4 5 6 7\nCELL_TYPES 1\n12\n";
        accepted_cube("hex.vtk", t.as_bytes());

        // The same cube as five tetrahedra: the shared inner faces disappear.
        let mut t = String::from(
            "# vtk DataFile Version 2.0\ntets\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 8 float\n",
        );
        for v in cube_corners() {
            t += &format!("{} {} {}\n", v[0], v[1], v[2]);
        }
        t += "CELLS 5 25\n4 0 1 3 4\n4 1 2 3 6\n4 1 4 5 6\n4 3 4 6 7\n4 1 3 4 6\nCELL_TYPES 5\n10\n10\n10\n10\n10\n";
        accepted_cube("tets.vtk", t.as_bytes());
    }

    #[test]
    fn obj_quads_and_negative_indices_are_triangulated() {
        let mut t = String::new();
        for v in cube_corners() {
            t += &format!("v {} {} {}\n", v[0], v[1], v[2]);
        }
        // Relative (negative) indices count back from the last vertex.
        for q in CUBE_QUADS {
            t += &format!(
                "f {} {} {} {}\n",
                q[0] as i64 - 8,
                q[1] as i64 - 8,
                q[2] as i64 - 8,
                q[3] as i64 - 8
            );
        }
        accepted_cube("cube.obj", t.as_bytes());
    }
}
