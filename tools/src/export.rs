//! Writing a scene's surface and interior points for inspection in other tools.
//!
//! The formats are simple enough to write directly: legacy VTK POLYDATA (triangles, points as
//! VERTICES, and per-point `kind` and `volume` arrays, which ParaView shows), ASCII PLY and
//! OBJ (interior points as unreferenced vertices / `p` elements). Coordinates are in metres,
//! the unit the importer assumes by default, so an export reads back unchanged.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, bail};
use scalpel_sim::cut::FaceKind;
use scalpel_sim::geometry::TriMesh;
use scalpel_sim::scene::BuiltScene;

/// The export formats, by file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Vtk,
    Ply,
    Obj,
}

fn format_of(out: &Path) -> anyhow::Result<Format> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    Ok(match ext.as_str() {
        "vtk" => Format::Vtk,
        "ply" => Format::Ply,
        "obj" => Format::Obj,
        _ => bail!(
            "{}: unsupported export format '.{ext}'; use .vtk, .ply or .obj",
            out.display()
        ),
    })
}

/// Writes `scene` to `out`; the format follows the extension.
pub fn write(scene: &BuiltScene, out: &Path) -> anyhow::Result<()> {
    let text = match format_of(out)? {
        Format::Vtk => vtk(scene),
        Format::Ply => ply(scene),
        Format::Obj => obj(scene),
    };
    std::fs::write(out, text).with_context(|| format!("cannot write {}", out.display()))
}

/// Writes a cut surface (skin and wound walls, current positions, m) to `out`; the format
/// follows the extension. The kind of each triangle is kept: a `kind` cell array in VTK
/// (0 skin, 1 wound wall), a face property in PLY, groups in OBJ.
pub fn write_cut_surface(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    title: &str,
    out: &Path,
) -> anyhow::Result<()> {
    let code = |k: &FaceKind| u8::from(*k == FaceKind::Wall);
    let mut s = String::new();
    match format_of(out)? {
        Format::Vtk => {
            let _ = writeln!(s, "# vtk DataFile Version 3.0\n{title}, units m");
            let _ = writeln!(
                s,
                "ASCII\nDATASET POLYDATA\nPOINTS {} double",
                mesh.positions.len()
            );
            for p in &mesh.positions {
                let _ = writeln!(s, "{} {} {}", p.x, p.y, p.z);
            }
            let n = mesh.triangles.len();
            let _ = writeln!(s, "POLYGONS {n} {}", 4 * n);
            for t in &mesh.triangles {
                let _ = writeln!(s, "3 {} {} {}", t[0], t[1], t[2]);
            }
            let _ = writeln!(s, "CELL_DATA {n}\nSCALARS kind int 1\nLOOKUP_TABLE default");
            for k in kinds {
                let _ = writeln!(s, "{}", code(k));
            }
        }
        Format::Ply => {
            let _ = writeln!(
                s,
                "ply\nformat ascii 1.0\ncomment {title}, units m, kind 1 = wound wall"
            );
            let _ = writeln!(s, "element vertex {}", mesh.positions.len());
            let _ = writeln!(s, "property double x\nproperty double y\nproperty double z");
            let _ = writeln!(s, "element face {}", mesh.triangles.len());
            let _ = writeln!(
                s,
                "property list uchar int vertex_indices\nproperty uchar kind\nend_header"
            );
            for p in &mesh.positions {
                let _ = writeln!(s, "{} {} {}", p.x, p.y, p.z);
            }
            for (t, k) in mesh.triangles.iter().zip(kinds) {
                let _ = writeln!(s, "3 {} {} {} {}", t[0], t[1], t[2], code(k));
            }
        }
        Format::Obj => {
            let _ = writeln!(s, "# {title}, units m");
            for p in &mesh.positions {
                let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
            }
            for (group, kind) in [("skin", FaceKind::Skin), ("wound_wall", FaceKind::Wall)] {
                let _ = writeln!(s, "g {group}");
                for (t, _) in mesh
                    .triangles
                    .iter()
                    .zip(kinds)
                    .filter(|(_, k)| **k == kind)
                {
                    let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
                }
            }
        }
    }
    std::fs::write(out, s).with_context(|| format!("cannot write {}", out.display()))
}

fn vtk(scene: &BuiltScene) -> String {
    let surface = &scene.model.surface;
    let points = &scene.model.points;
    let nv = surface.positions.len();
    let np = points.len();
    let mut s = String::new();
    let _ = writeln!(s, "# vtk DataFile Version 3.0");
    let _ = writeln!(
        s,
        "scalpel scene {}: surface + interior points, units m",
        scene.spec.name
    );
    let _ = writeln!(s, "ASCII\nDATASET POLYDATA\nPOINTS {} double", nv + np);
    for p in surface.positions.iter().chain(&points.rest) {
        let _ = writeln!(s, "{} {} {}", p.x, p.y, p.z);
    }
    let _ = writeln!(s, "VERTICES {np} {}", 2 * np);
    for i in 0..np {
        let _ = writeln!(s, "1 {}", nv + i);
    }
    let _ = writeln!(
        s,
        "POLYGONS {} {}",
        surface.triangles.len(),
        4 * surface.triangles.len()
    );
    for t in &surface.triangles {
        let _ = writeln!(s, "3 {} {} {}", t[0], t[1], t[2]);
    }
    let _ = writeln!(s, "POINT_DATA {}", nv + np);
    let _ = writeln!(s, "SCALARS kind int 1\nLOOKUP_TABLE default");
    for i in 0..nv + np {
        let _ = writeln!(s, "{}", u8::from(i >= nv));
    }
    let _ = writeln!(s, "SCALARS volume_mm3 double 1\nLOOKUP_TABLE default");
    for i in 0..nv + np {
        let v = if i < nv {
            0.0
        } else {
            points.volume_m3[i - nv] * 1e9
        };
        let _ = writeln!(s, "{v}");
    }
    s
}

fn ply(scene: &BuiltScene) -> String {
    let surface = &scene.model.surface;
    let points = &scene.model.points;
    let nv = surface.positions.len();
    let mut s = String::new();
    let _ = writeln!(s, "ply\nformat ascii 1.0");
    let _ = writeln!(
        s,
        "comment scalpel scene {}: surface + interior points (kind 1), units m",
        scene.spec.name
    );
    let _ = writeln!(s, "element vertex {}", nv + points.len());
    let _ = writeln!(
        s,
        "property double x\nproperty double y\nproperty double z\nproperty uchar kind"
    );
    let _ = writeln!(s, "element face {}", surface.triangles.len());
    let _ = writeln!(s, "property list uchar int vertex_indices\nend_header");
    for (i, p) in surface.positions.iter().chain(&points.rest).enumerate() {
        let _ = writeln!(s, "{} {} {} {}", p.x, p.y, p.z, u8::from(i >= nv));
    }
    for t in &surface.triangles {
        let _ = writeln!(s, "3 {} {} {}", t[0], t[1], t[2]);
    }
    s
}

fn obj(scene: &BuiltScene) -> String {
    let surface = &scene.model.surface;
    let points = &scene.model.points;
    let nv = surface.positions.len();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# scalpel scene {}: surface + interior points (p elements), units m",
        scene.spec.name
    );
    let _ = writeln!(s, "o surface");
    for p in &surface.positions {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    for t in &surface.triangles {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    let _ = writeln!(s, "o interior_points");
    for p in &points.rest {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    for i in 0..points.len() {
        let _ = writeln!(s, "p {}", nv + i + 1);
    }
    s
}

/// Writes a rendered image to `path` as PNG.
pub fn save_png(image: &scalpel_client::render::Image, path: &Path) -> anyhow::Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    image.write_png(std::io::BufWriter::new(file))?;
    Ok(())
}
