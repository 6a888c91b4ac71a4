//! `scalpel settle`: a supported organ comes to rest under gravity; its sag, the settled
//! surface (VTK) and a render of it on its supports (PNG).

use std::path::Path;

use anyhow::{Context, bail};
use scalpel_client::render::{Camera, RenderOptions, SurfaceView, render};
use scalpel_sim::math::{Aabb, Vec3};
use scalpel_sim::pipeline::Simulation;
use scalpel_sim::pipeline::supports::SettleReport;
use scalpel_sim::scene::Region;
use scalpel_sim::scene::supports::STANDARD_GRAVITY;
use serde::Serialize;

use crate::{TargetArgs, export, load};

/// Colours of the render: tissue, what holds it (linear RGB).
const PALETTE: [[f32; 3]; 2] = [[0.50, 0.14, 0.11], [0.55, 0.57, 0.60]];

/// What `scalpel settle --json` prints.
#[derive(Serialize)]
struct SettleOutput {
    scene: String,
    gravity_m_s2: [f64; 3],
    /// Whether the scene had gravity off and standard gravity was used.
    gravity_added: bool,
    #[serde(flatten)]
    report: SettleReport,
    fixed_points: usize,
    attached_vertices: usize,
    tray_samples: usize,
}

/// `scalpel settle`.
pub fn run(target: &TargetArgs, out: &Path, json: bool) -> anyhow::Result<()> {
    let mut spec = load::resolve(target)?;
    let gravity_added = spec.loads.gravity == Vec3::zeros();
    if gravity_added {
        spec.loads.gravity = STANDARD_GRAVITY;
    }
    if let Some(why) = spec.supports.unable_to_hold(&spec.loads.gravity) {
        bail!("scene '{}': {why}", spec.name);
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    // Built without gravity and then let fall: the time it takes is part of the report (a
    // scene under gravity starts in its static equilibrium instead).
    let gravity = spec.loads.gravity;
    spec.loads.gravity = Vec3::zeros();
    let timed = load::build_with_progress(&spec)?;
    let mut sim = Simulation::new(&timed.scene);
    let report = sim.settle_under(gravity);
    spec.loads.gravity = gravity;
    let counts = sim.supports();
    let (drawn, kinds) = sim.current_surface().drawn();
    let mesh_path = out.join("settled.vtk");
    export::write_cut_surface(
        &drawn,
        &kinds,
        &format!("scalpel settle {}: the surface at rest", spec.name),
        &mesh_path,
    )?;
    let png_path = out.join("settled.png");
    render_settled(&sim, &png_path)?;
    let output = SettleOutput {
        scene: spec.name.clone(),
        gravity_m_s2: spec.loads.gravity.into(),
        gravity_added,
        report,
        fixed_points: counts.fixed_points,
        attached_vertices: counts.attached_vertices,
        tray_samples: counts.tray_samples,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&output)?);
        return Ok(());
    }
    let g = spec.loads.gravity;
    println!(
        "settle {}: gravity [{:.2}, {:.2}, {:.2}] m/s²{}",
        spec.name,
        g.x,
        g.y,
        g.z,
        if gravity_added {
            " (the scene has none: standard gravity)"
        } else {
            ""
        }
    );
    println!(
        "  held by {} fixed points, {} attached vertices, {} surface samples over the tray",
        counts.fixed_points, counts.attached_vertices, counts.tray_samples
    );
    println!(
        "  {} in {:.2} s: sag {:.2} mm (mean along gravity), largest displacement {:.2} mm, {} tray samples on the tray, residual {:.2e} N",
        if report.settled {
            "at rest"
        } else {
            "NOT at rest"
        },
        report.settle_s,
        report.sag_mm,
        report.max_displacement_mm,
        report.on_tray,
        report.residual_n
    );
    println!("wrote {}, {}", mesh_path.display(), png_path.display());
    Ok(())
}

/// The settled surface from the side and above, on its tray when it has one.
fn render_settled(sim: &Simulation, path: &Path) -> anyhow::Result<()> {
    let (drawn, _) = sim.current_surface().drawn();
    let mut positions: Vec<[f64; 3]> = drawn.positions.iter().map(|p| (*p).into()).collect();
    let mut triangles = drawn.triangles.clone();
    let mut materials = vec![0u8; triangles.len()];
    let bounds = Aabb::around(&drawn.positions);
    let (lo, hi) = (bounds.min_v(), bounds.max_v());
    let centre = (lo + hi) * 0.5;
    let extent = (hi - lo).norm().max(0.01);
    if let Some(tray) = sim.solver().held().and_then(|h| h.tray()) {
        // A square of the tray's plane, 1.4 times the body across, under it.
        let n = tray.normal;
        let on_plane = centre - n * tray.gap(&centre);
        let u = n.cross(&Vec3::x()).try_normalize(1e-9).unwrap_or(Vec3::y());
        let v = n.cross(&u);
        let half = 0.7 * extent;
        let base = positions.len() as u32;
        for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            positions.push((on_plane + u * (a * half) + v * (b * half)).into());
        }
        triangles.push([base, base + 1, base + 2]);
        triangles.push([base, base + 2, base + 3]);
        materials.extend([1, 1]);
    }
    // The bones the fixed regions stand for, a little inside the tissue.
    for region in &sim.spec().supports.fixed {
        if let Region::InsideCylinder {
            point,
            axis,
            radius,
        } = *region
        {
            add_cylinder(
                &mut positions,
                &mut triangles,
                &mut materials,
                (Vec3::from(point), Vec3::from(axis)),
                0.9 * radius,
                (lo, hi),
            );
        }
    }
    let fov = 40.0;
    let distance = 0.75 * extent / (0.5 * f64::to_radians(fov)).tan();
    let camera = Camera::orbit(centre.into(), distance, 25.0, -60.0, fov);
    let image = render(
        &SurfaceView {
            positions: &positions,
            triangles: &triangles,
            materials: &materials,
        },
        &PALETTE,
        &camera,
        &RenderOptions::default(),
    )?;
    export::save_png(&image, path)
}

/// A closed-ended cylinder of `radius` round `axis` (a point and a unit direction), as long
/// as the body's box `bounds` along it, in material 1.
fn add_cylinder(
    positions: &mut Vec<[f64; 3]>,
    triangles: &mut Vec<[u32; 3]>,
    materials: &mut Vec<u8>,
    (point, axis): (Vec3, Vec3),
    radius: f64,
    (lo, hi): (Vec3, Vec3),
) {
    const SEGMENTS: u32 = 48;
    let centre = (lo + hi) * 0.5;
    let half = 0.5 * (hi - lo).dot(&axis.abs());
    let mid = point + axis * (centre - point).dot(&axis);
    let u = axis
        .cross(&Vec3::x())
        .try_normalize(1e-9)
        .unwrap_or(Vec3::z());
    let v = axis.cross(&u);
    let base = positions.len() as u32;
    for end in [-1.0, 1.0] {
        for k in 0..SEGMENTS {
            let t = std::f64::consts::TAU * f64::from(k) / f64::from(SEGMENTS);
            let p = mid + axis * (end * half) + (u * t.cos() + v * t.sin()) * radius;
            positions.push(p.into());
        }
    }
    for k in 0..SEGMENTS {
        let (a, b) = (base + k, base + (k + 1) % SEGMENTS);
        triangles.push([a, b, b + SEGMENTS]);
        triangles.push([a, b + SEGMENTS, a + SEGMENTS]);
        materials.extend([1, 1]);
    }
}
