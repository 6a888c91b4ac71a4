//! A headless CPU renderer for tissue surfaces (euc rasterizer, PNG output).
//!
//! The same code draws offline renders (`scalpel cut`, `scalpel render`) and, later, the
//! local viewer's frames: no GPU, no window system, so it runs in CI. Surfaces come in as
//! plain arrays (positions, triangles, a material per triangle), the way frames arrive from
//! shared memory.
//!
//! Shading: Gouraud with normals smoothed within each material and kept sharp across
//! materials (the wound wall meets the skin at a crease), a key light, a fill light and
//! ambient; 2×2 supersampling against jagged edges.

use std::io::Write;

use euc::Pipeline;
use euc::buffer::Buffer2d;
use euc::rasterizer::{BackfaceCullingDisabled, Triangles};
use thiserror::Error;

/// Why a render failed.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum RenderError {
    /// A triangle names a vertex that does not exist, or a material without a colour.
    #[error("triangle {triangle}: {message}")]
    BadSurface {
        /// Triangle index.
        triangle: usize,
        /// What is wrong.
        message: String,
    },
    /// Width or height out of range.
    #[error("image size {width}×{height} must be between 1×1 and 8192×8192")]
    BadSize {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
    },
    /// The camera looks nowhere (eye at the target, or up along the view).
    #[error("degenerate camera: {0}")]
    BadCamera(String),
    /// Writing the PNG failed.
    #[error("PNG encoding failed: {0}")]
    Png(String),
}

/// A surface to draw.
#[derive(Debug, Clone, Copy)]
pub struct SurfaceView<'a> {
    /// Vertex positions (any unit; the camera uses the same).
    pub positions: &'a [[f64; 3]],
    /// Triangles, counter-clockwise seen from outside.
    pub triangles: &'a [[u32; 3]],
    /// Material of each triangle: an index into the palette.
    pub materials: &'a [u8],
}

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: [f64; 3],
    /// Point looked at.
    pub target: [f64; 3],
    /// Up direction (need not be orthogonal to the view).
    pub up: [f64; 3],
    /// Vertical field of view (degrees).
    pub fov_y_deg: f64,
}

impl Camera {
    /// A camera looking at `target` from `distance` away, raised `elevation_deg` above the
    /// horizontal (xy) plane and turned `azimuth_deg` about +z from the +x axis; z is up.
    pub fn orbit(
        target: [f64; 3],
        distance: f64,
        elevation_deg: f64,
        azimuth_deg: f64,
        fov_y_deg: f64,
    ) -> Self {
        let (el, az) = (elevation_deg.to_radians(), azimuth_deg.to_radians());
        let dir = [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()];
        Self {
            eye: [
                target[0] + distance * dir[0],
                target[1] + distance * dir[1],
                target[2] + distance * dir[2],
            ],
            target,
            // Looking straight down, "up" on the image is the azimuth's opposite.
            up: if elevation_deg.abs() > 89.0 {
                [-az.cos(), -az.sin(), 0.0]
            } else {
                [0.0, 0.0, 1.0]
            },
            fov_y_deg,
        }
    }
}

/// Image size, background and quality.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// Samples per pixel along each axis (1 = none, 2 = 2×2).
    pub supersample: u32,
    /// Background colour (linear 0–1 RGB).
    pub background: [f32; 3],
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            width: 960,
            height: 720,
            supersample: 2,
            background: [0.12, 0.13, 0.15],
        }
    }
}

/// An RGBA8 image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// Row-major RGBA bytes.
    pub rgba: Vec<u8>,
}

impl Image {
    /// The pixel at (x, y) as RGBA.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = 4 * (y as usize * self.width as usize + x as usize);
        [
            self.rgba[i],
            self.rgba[i + 1],
            self.rgba[i + 2],
            self.rgba[i + 3],
        ]
    }

    /// Encodes the image as PNG.
    pub fn write_png(&self, out: impl Write) -> Result<(), RenderError> {
        let mut encoder = png::Encoder::new(out, self.width, self.height);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder
            .write_header()
            .map_err(|e| RenderError::Png(e.to_string()))?;
        writer
            .write_image_data(&self.rgba)
            .map_err(|e| RenderError::Png(e.to_string()))
    }
}

type V3 = [f64; 3];

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(a: V3) -> Option<V3> {
    let n = dot(a, a).sqrt();
    (n > 1e-300 && n.is_finite()).then(|| [a[0] / n, a[1] / n, a[2] / n])
}

/// One corner of a triangle after the vertex stage: clip position and lit colour.
#[derive(Debug, Clone, Copy)]
struct Corner {
    clip: [f32; 4],
    colour: (f32, f32, f32),
}

struct Shaded;

impl Pipeline for Shaded {
    type Vertex = Corner;
    type VsOut = (f32, f32, f32);
    type Pixel = [f32; 3];

    fn vert(&self, c: &Corner) -> ([f32; 4], Self::VsOut) {
        (c.clip, c.colour)
    }

    fn frag(&self, c: &Self::VsOut) -> Self::Pixel {
        [c.0, c.1, c.2]
    }
}

/// Draws `surface` with `palette` colours (linear 0–1 RGB) through `camera`.
pub fn render(
    surface: &SurfaceView<'_>,
    palette: &[[f32; 3]],
    camera: &Camera,
    options: &RenderOptions,
) -> Result<Image, RenderError> {
    let (w, h) = (options.width, options.height);
    if !(1..=8192).contains(&w) || !(1..=8192).contains(&h) {
        return Err(RenderError::BadSize {
            width: w,
            height: h,
        });
    }
    let nv = surface.positions.len();
    for (t, tri) in surface.triangles.iter().enumerate() {
        if let Some(v) = tri.iter().find(|&&v| v as usize >= nv) {
            return Err(RenderError::BadSurface {
                triangle: t,
                message: format!("vertex {v} of {nv}"),
            });
        }
        let m = surface.materials.get(t).copied().unwrap_or(0) as usize;
        if m >= palette.len() {
            return Err(RenderError::BadSurface {
                triangle: t,
                message: format!(
                    "material {m} has no colour ({} in the palette)",
                    palette.len()
                ),
            });
        }
    }
    // View basis.
    let forward = normalize(sub(camera.target, camera.eye))
        .ok_or_else(|| RenderError::BadCamera("the eye is at the target".into()))?;
    let right = normalize(cross(forward, camera.up))
        .ok_or_else(|| RenderError::BadCamera("up is along the view direction".into()))?;
    let up = cross(right, forward);
    let aspect = w as f64 / h as f64;
    let f = 1.0 / (0.5 * camera.fov_y_deg.to_radians()).tan();
    // Near and far planes around the surface.
    let depths: Vec<f64> = surface
        .positions
        .iter()
        .map(|p| dot(sub(*p, camera.eye), forward))
        .collect();
    let far = depths.iter().copied().fold(0.0, f64::max) * 1.05 + 1e-9;
    let near = (far * 1e-3).max(
        depths
            .iter()
            .copied()
            .filter(|d| *d > 0.0)
            .fold(f64::INFINITY, f64::min)
            * 0.5,
    );
    let clip_of = |p: V3| -> [f32; 4] {
        let d = sub(p, camera.eye);
        let (x, y, z) = (dot(d, right), dot(d, up), dot(d, forward));
        // OpenGL-style projection with depth mapped to [-1, 1].
        let zc = (far + near) / (far - near) * z - 2.0 * far * near / (far - near);
        [(f / aspect * x) as f32, (f * y) as f32, zc as f32, z as f32]
    };
    // Normals smoothed within each material.
    let face_normal = |t: usize| {
        let [a, b, c] = surface.triangles[t].map(|v| surface.positions[v as usize]);
        cross(sub(b, a), sub(c, a))
    };
    let mut groups: std::collections::HashMap<(u32, u8), V3> = std::collections::HashMap::new();
    for (t, tri) in surface.triangles.iter().enumerate() {
        let n = face_normal(t);
        let m = surface.materials.get(t).copied().unwrap_or(0);
        for &v in tri {
            let e = groups.entry((v, m)).or_insert([0.0; 3]);
            *e = [e[0] + n[0], e[1] + n[1], e[2] + n[2]];
        }
    }
    let key = normalize([
        0.4 * right[0] + 0.7 * up[0] - forward[0],
        0.4 * right[1] + 0.7 * up[1] - forward[1],
        0.4 * right[2] + 0.7 * up[2] - forward[2],
    ])
    .unwrap_or(up);
    let fill = normalize([
        -right[0] - 0.3 * forward[0],
        -right[1] - 0.3 * forward[1],
        -right[2] - 0.3 * forward[2],
    ])
    .unwrap_or(right);
    let shade = |n: V3, base: [f32; 3]| -> (f32, f32, f32) {
        // Two-sided: a normal facing away from the eye is flipped.
        let n = if dot(n, forward) > 0.0 {
            [-n[0], -n[1], -n[2]]
        } else {
            n
        };
        let light = 0.22 + 0.68 * dot(n, key).max(0.0) + 0.18 * dot(n, fill).max(0.0);
        let light = light as f32;
        (base[0] * light, base[1] * light, base[2] * light)
    };
    let mut corners = Vec::with_capacity(3 * surface.triangles.len());
    for (t, tri) in surface.triangles.iter().enumerate() {
        let clip = tri.map(|v| clip_of(surface.positions[v as usize]));
        if clip
            .iter()
            .any(|c| (c[3] as f64) < near || !c.iter().all(|x| x.is_finite()))
        {
            continue;
        }
        let m = surface.materials.get(t).copied().unwrap_or(0);
        let base = palette[m as usize];
        for (k, &v) in tri.iter().enumerate() {
            let n = groups
                .get(&(v, m))
                .and_then(|n| normalize(*n))
                .or_else(|| normalize(face_normal(t)))
                .unwrap_or(forward);
            corners.push(Corner {
                clip: clip[k],
                colour: shade(n, base),
            });
        }
    }
    let s = options.supersample.clamp(1, 4) as usize;
    let (sw, sh) = (w as usize * s, h as usize * s);
    let mut colour = Buffer2d::new([sw, sh], options.background);
    let mut depth = Buffer2d::new([sw, sh], 1.0f32);
    Shaded.draw::<Triangles<Buffer2d<f32>, BackfaceCullingDisabled>, _>(
        &corners,
        &mut colour,
        Some(&mut depth),
    );
    // Box filter down to the output size, then gamma-encode.
    let samples: &[[f32; 3]] = colour.as_ref();
    let mut rgba = Vec::with_capacity(4 * w as usize * h as usize);
    for y in 0..h as usize {
        for x in 0..w as usize {
            let mut sum = [0.0f32; 3];
            for dy in 0..s {
                for dx in 0..s {
                    let p = samples[(y * s + dy) * sw + x * s + dx];
                    sum = [sum[0] + p[0], sum[1] + p[1], sum[2] + p[2]];
                }
            }
            let n = (s * s) as f32;
            for c in sum {
                let linear = (c / n).clamp(0.0, 1.0);
                rgba.push((linear.powf(1.0 / 2.2) * 255.0).round() as u8);
            }
            rgba.push(255);
        }
    }
    Ok(Image {
        width: w,
        height: h,
        rgba,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube, skin on five faces and "wall" on the top.
    fn cube() -> (Vec<[f64; 3]>, Vec<[u32; 3]>, Vec<u8>) {
        let p: Vec<[f64; 3]> = (0..8)
            .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let mut t = Vec::new();
        let mut m = Vec::new();
        for (k, q) in quads.iter().enumerate() {
            t.push([q[0], q[1], q[2]]);
            t.push([q[0], q[2], q[3]]);
            let mat = u8::from(k == 1);
            m.extend([mat, mat]);
        }
        (p, t, m)
    }

    #[test]
    fn a_cube_from_above_shows_its_top_in_the_wall_colour() {
        let (p, t, m) = cube();
        let view = SurfaceView {
            positions: &p,
            triangles: &t,
            materials: &m,
        };
        let palette = [[0.8, 0.3, 0.3], [0.2, 0.2, 0.9]];
        let camera = Camera::orbit([0.5, 0.5, 0.5], 4.0, 90.0, 0.0, 40.0);
        let options = RenderOptions {
            width: 64,
            height: 48,
            ..RenderOptions::default()
        };
        let img = render(&view, &palette, &camera, &options).expect("renders");
        let centre = img.pixel(32, 24);
        assert!(centre[2] > centre[0] && centre[2] > 100, "{centre:?}");
        let corner = img.pixel(0, 0);
        assert!(corner[0] < 110 && corner[2] < 110, "background {corner:?}");
        let mut png = Vec::new();
        img.write_png(&mut png).expect("encodes");
        assert_eq!(&png[1..4], b"PNG");
    }

    #[test]
    fn bad_input_is_refused_with_a_message() {
        let (p, t, m) = cube();
        let palette = [[1.0, 1.0, 1.0]];
        let camera = Camera::orbit([0.5; 3], 3.0, 30.0, 0.0, 40.0);
        let view = SurfaceView {
            positions: &p,
            triangles: &t,
            materials: &m,
        };
        let e = render(&view, &palette, &camera, &RenderOptions::default()).unwrap_err();
        assert!(e.to_string().contains("material 1 has no colour"), "{e}");
        let bad = [[0, 1, 99]];
        let view = SurfaceView {
            positions: &p,
            triangles: &bad,
            materials: &[0],
        };
        let e = render(&view, &palette, &camera, &RenderOptions::default()).unwrap_err();
        assert!(e.to_string().starts_with("triangle 0: vertex 99"), "{e}");
        let same = Camera {
            eye: [0.0; 3],
            target: [0.0; 3],
            up: [0.0, 0.0, 1.0],
            fov_y_deg: 40.0,
        };
        assert!(render(&view, &palette, &same, &RenderOptions::default()).is_err());
    }
}
