//! `scalpel view --station S --snapshot out.png [--after N]`: attaches to a station's render
//! frames over shared memory and draws the live surface — wound walls in their own colour,
//! the blade, and the force on it as an arrow — with the headless CPU renderer of
//! `scalpel cut`.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use scalpel_client::frames::{Frame, FrameReader};
use scalpel_client::render::{Camera, RenderOptions, SurfaceView, render};
use scalpel_proto::shm::FRAME_TOOL_PRESENT;

/// Skin, wound wall, blade, force arrow (linear RGB).
const PALETTE: [[f32; 3]; 4] = [
    [0.50, 0.14, 0.11],
    [0.93, 0.62, 0.52],
    [0.75, 0.78, 0.82],
    [0.15, 0.55, 0.95],
];
/// Arrow length per newton (m).
const ARROW_M_PER_N: f64 = 0.01;

/// Waits for `after` frames (at most `timeout_s`), then renders the newest to `out`.
pub fn snapshot(station: &str, out: &Path, after: u64, timeout_s: f64) -> anyhow::Result<()> {
    scalpel_proto::shm::quiet_logging();
    let mut reader = FrameReader::open(station)?;
    let started = Instant::now();
    let mut seen = 0;
    let mut newest: Option<Frame> = None;
    while seen < after.max(1) {
        if started.elapsed().as_secs_f64() > timeout_s {
            bail!(
                "station {station}: {seen} frame(s) in {timeout_s} s, waited for {after} (is the server running with frames on?)"
            );
        }
        if let Some(frame) = reader.wait(Duration::from_millis(100))? {
            seen += 1;
            newest = Some(frame);
        }
    }
    let frame = newest.context("no frame")?;
    let image = draw(&frame)?;
    let file =
        std::fs::File::create(out).with_context(|| format!("cannot write {}", out.display()))?;
    image.write_png(std::io::BufWriter::new(file))?;
    println!(
        "frame {} (simulation tick {}): {} vertices, {} triangles ({} wound wall), tool {}, force {:.2} N -> {}",
        frame.header.frame,
        frame.header.sim_tick,
        frame.positions.len(),
        frame.triangles.len(),
        frame.materials.iter().filter(|&&m| m == 1).count(),
        if frame.header.flags & FRAME_TOOL_PRESENT != 0 {
            "present"
        } else {
            "absent"
        },
        norm(frame.header.force_n.map(f64::from)),
        out.display()
    );
    Ok(())
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The frame's surface with the blade and the force arrow added as extra triangles.
fn draw(frame: &Frame) -> anyhow::Result<scalpel_client::render::Image> {
    let mut positions: Vec<[f64; 3]> = frame.positions.iter().map(|p| p.map(f64::from)).collect();
    let mut triangles = frame.triangles.clone();
    let mut materials = frame.materials.clone();
    let (lo, hi) = positions.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
            )
        },
    );
    if positions.is_empty() {
        bail!("frame {} has no surface", frame.header.frame);
    }
    let h = &frame.header;
    if h.flags & FRAME_TOOL_PRESENT != 0 {
        let tip = h.tool_tip_m.map(f64::from);
        let [x, y, z, w] = h.tool_orientation_xyzw.map(f64::from);
        // The blade's edge is the tool's local +z axis; its flat side contains local +x.
        let rotate = |v: [f64; 3]| {
            let q = rotate_by([x, y, z, w], v);
            [tip[0] + q[0], tip[1] + q[1], tip[2] + q[2]]
        };
        let length = f64::from(h.blade_length_m).min(0.06);
        let width = 0.008;
        let base = positions.len() as u32;
        positions.extend([
            tip,
            rotate([0.0, 0.0, length]),
            rotate([width, 0.0, length]),
            rotate([width, 0.0, 0.0]),
        ]);
        triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        materials.extend([2, 2]);
        let f = h.force_n.map(f64::from);
        let magnitude = norm(f);
        if magnitude > 1e-3 {
            let d = f.map(|c| c / magnitude);
            let len = magnitude * ARROW_M_PER_N;
            // Two crossed flat arrows, so it shows from any side.
            let side_a = unit(cross(
                d,
                if d[2].abs() < 0.9 {
                    [0.0, 0.0, 1.0]
                } else {
                    [1.0, 0.0, 0.0]
                },
            ));
            let side_b = cross(d, side_a);
            // From the blade's back end, which is out of the tissue and in view.
            let origin = rotate([0.0, 0.0, length]);
            for s in [side_a, side_b] {
                let at = |along: f64, across: f64| {
                    [0, 1, 2].map(|i| origin[i] + d[i] * along + s[i] * across)
                };
                let base = positions.len() as u32;
                let shaft = 0.0012;
                positions.extend([
                    at(0.0, -shaft),
                    at(0.75 * len, -shaft),
                    at(0.75 * len, shaft),
                    at(0.0, shaft),
                    at(0.75 * len, -3.0 * shaft),
                    at(len, 0.0),
                    at(0.75 * len, 3.0 * shaft),
                ]);
                triangles.extend([
                    [base, base + 1, base + 2],
                    [base, base + 2, base + 3],
                    [base + 4, base + 5, base + 6],
                ]);
                materials.extend([3, 3, 3]);
            }
        }
    }
    let centre = [0, 1, 2].map(|i| 0.5 * (lo[i] + hi[i]));
    let extent = norm([0, 1, 2].map(|i| hi[i] - lo[i])).max(0.02);
    let fov = 40.0;
    let distance = 0.65 * extent / (0.5 * f64::to_radians(fov)).tan();
    let camera = Camera::orbit(centre, distance, 35.0, -60.0, fov);
    Ok(render(
        &SurfaceView {
            positions: &positions,
            triangles: &triangles,
            materials: &materials,
        },
        &PALETTE,
        &camera,
        &RenderOptions::default(),
    )?)
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = norm(v).max(1e-30);
    v.map(|c| c / n)
}

/// Rotates `v` by the unit quaternion (x, y, z, w).
fn rotate_by(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let u = [q[0], q[1], q[2]];
    let w = q[3];
    // v' = v + 2w(u×v) + 2u×(u×v)
    let uv = cross(u, v);
    let uuv = cross(u, uv);
    [0, 1, 2].map(|i| v[i] + 2.0 * (w * uv[i] + uuv[i]))
}
