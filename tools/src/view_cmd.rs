//! `scalpel view --station S [--snapshot out.png [--after N]]`: attaches to a station's
//! render frames over shared memory and draws the live surface — wound walls in their own
//! colour, the blade, and the force on it as an arrow — with the CPU renderer of
//! `scalpel cut`: in a window (minifb; arrow keys turn the camera, +/- zoom, Esc quits), or
//! headless into a PNG.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use scalpel_client::frame_reader::{Frame, FrameReader};
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
    let image = draw(&frame, &Orbit::default(), &RenderOptions::default())?;
    crate::export::save_png(&image, out)?;
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

/// Where the camera is, around the surface's centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Orbit {
    /// Degrees about +z.
    pub azimuth_deg: f64,
    /// Degrees above the horizontal.
    pub elevation_deg: f64,
    /// Distance as a multiple of the fitted one.
    pub zoom: f64,
}

impl Default for Orbit {
    fn default() -> Self {
        Self {
            azimuth_deg: -60.0,
            elevation_deg: 35.0,
            zoom: 1.0,
        }
    }
}

/// Live view in a window until it is closed (or Esc), or until `exit_after` frames are
/// drawn.
pub fn window(station: &str, exit_after: Option<u64>) -> anyhow::Result<()> {
    use minifb::{Key, KeyRepeat, Window, WindowOptions};
    scalpel_proto::shm::quiet_logging();
    let mut reader = FrameReader::open(station)?;
    let options = RenderOptions {
        width: 960,
        height: 720,
        supersample: 1,
        ..RenderOptions::default()
    };
    let (w, h) = (options.width as usize, options.height as usize);
    let mut window = Window::new(
        &format!("scalpel · station {station}"),
        w,
        h,
        WindowOptions::default(),
    )
    .map_err(|e| {
        anyhow::anyhow!(
            "cannot open a window ({e}); with no display, render headless with --snapshot out.png"
        )
    })?;
    window.set_target_fps(60);
    let mut pixels = vec![0u32; w * h];
    let mut orbit = Orbit::default();
    let mut last: Option<Frame> = None;
    let mut drawn = 0u64;
    let started = Instant::now();
    let mut last_frame_at = Instant::now();
    let mut offline_shown = false;
    let mut last_check = Instant::now();
    while window.is_open()
        && !window.is_key_down(Key::Escape)
        && exit_after.is_none_or(|n| drawn < n)
    {
        let mut moved = false;
        for key in window.get_keys_pressed(KeyRepeat::Yes) {
            moved = true;
            match key {
                Key::Left => orbit.azimuth_deg -= 5.0,
                Key::Right => orbit.azimuth_deg += 5.0,
                Key::Up => orbit.elevation_deg = (orbit.elevation_deg + 5.0).min(89.0),
                Key::Down => orbit.elevation_deg = (orbit.elevation_deg - 5.0).max(-89.0),
                Key::Equal | Key::NumPadPlus => orbit.zoom = (orbit.zoom / 1.1).max(0.05),
                Key::Minus | Key::NumPadMinus => orbit.zoom = (orbit.zoom * 1.1).min(20.0),
                _ => moved = false,
            }
        }
        if let Some(frame) = reader.wait(Duration::from_millis(10))? {
            last = Some(frame);
            last_frame_at = Instant::now();
            offline_shown = false;
            moved = true;
        }
        // A server that stopped (or was killed) sends nothing: after 0.1 s of silence look
        // whether its frame publisher is alive (iceoryx2 node liveness), say so, keep the
        // last picture, and pick up the frames of a restarted server on the station.
        let silent = last_frame_at.elapsed();
        if silent > Duration::from_millis(100)
            && !offline_shown
            && last_check.elapsed() > Duration::from_millis(100)
        {
            last_check = Instant::now();
            let publisher = format!("scalpel-server.frames.{station}");
            let alive = scalpel_proto::shm::station_nodes(station)
                .map(|nodes| nodes.iter().any(|n| n.alive && n.name == publisher))
                .unwrap_or(false);
            if !alive || silent > Duration::from_secs(1) {
                window.set_title(&format!(
                    "scalpel · station {station} · {}",
                    if alive {
                        "no frames: frames off or the simulation stalled"
                    } else {
                        "server offline"
                    }
                ));
                offline_shown = true;
            }
        }
        if moved && let Some(frame) = &last {
            let image = draw(frame, &orbit, &options)?;
            drawn += 1;
            for (p, c) in pixels.iter_mut().zip(image.rgba.chunks_exact(4)) {
                *p = u32::from(c[0]) << 16 | u32::from(c[1]) << 8 | u32::from(c[2]);
            }
            window.set_title(&format!(
                "scalpel · station {station} · frame {} · {:.2} N · cut {:.1} mm",
                frame.header.frame,
                norm(frame.header.force_n.map(f64::from)),
                frame.header.cut_length_mm
            ));
        }
        window.update_with_buffer(&pixels, w, h)?;
    }
    let seconds = started.elapsed().as_secs_f64();
    println!(
        "drew {drawn} frames in {seconds:.1} s ({:.1} per second), last frame {}",
        drawn as f64 / seconds.max(1e-9),
        last.map_or(0, |f| f.header.frame)
    );
    Ok(())
}

/// The frame's surface with the blade and the force arrow added as extra triangles.
pub fn draw(
    frame: &Frame,
    orbit: &Orbit,
    options: &RenderOptions,
) -> anyhow::Result<scalpel_client::render::Image> {
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
    let distance = orbit.zoom * 0.65 * extent / (0.5 * f64::to_radians(fov)).tan();
    let camera = Camera::orbit(
        centre,
        distance,
        orbit.elevation_deg,
        orbit.azimuth_deg,
        fov,
    );
    Ok(render(
        &SurfaceView {
            positions: &positions,
            triangles: &triangles,
            materials: &materials,
        },
        &PALETTE,
        &camera,
        options,
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
