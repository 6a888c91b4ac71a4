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

use std::collections::HashMap;
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
    check_surface(surface, palette)?;
    let view = View::new(camera, surface.positions, w as f64 / h as f64)?;
    let normals = smoothed_normals(surface);
    let corners = shade_corners(surface, palette, &view, &normals);
    let s = options.supersample.clamp(1, 4) as usize;
    let colour = rasterize(&corners, w as usize * s, h as usize * s, options.background);
    Ok(Image {
        width: w,
        height: h,
        rgba: downsample(colour.as_ref(), w as usize, h as usize, s),
    })
}

/// Refuses a triangle naming a missing vertex or a material without a palette colour.
fn check_surface(surface: &SurfaceView<'_>, palette: &[[f32; 3]]) -> Result<(), RenderError> {
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
    Ok(())
}

/// The camera's view basis, projection (near and far planes around the surface) and lights.
struct View {
    eye: V3,
    forward: V3,
    right: V3,
    up: V3,
    aspect: f64,
    /// Focal length: cot(fov_y / 2).
    f: f64,
    near: f64,
    far: f64,
    key: V3,
    fill: V3,
}

impl View {
    /// The view of `positions` through `camera` on an image `aspect` wide per unit high.
    fn new(camera: &Camera, positions: &[[f64; 3]], aspect: f64) -> Result<Self, RenderError> {
        let forward = normalize(sub(camera.target, camera.eye))
            .ok_or_else(|| RenderError::BadCamera("the eye is at the target".into()))?;
        let right = normalize(cross(forward, camera.up))
            .ok_or_else(|| RenderError::BadCamera("up is along the view direction".into()))?;
        let up = cross(right, forward);
        let f = 1.0 / (0.5 * camera.fov_y_deg.to_radians()).tan();
        // Near and far planes around the surface.
        let depths: Vec<f64> = positions
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
        Ok(Self {
            eye: camera.eye,
            forward,
            right,
            up,
            aspect,
            f,
            near,
            far,
            key,
            fill,
        })
    }

    /// The clip-space position of `p`; its w is the depth along the view.
    fn clip_of(&self, p: V3) -> [f32; 4] {
        let (near, far, f, aspect) = (self.near, self.far, self.f, self.aspect);
        let d = sub(p, self.eye);
        let (x, y, z) = (dot(d, self.right), dot(d, self.up), dot(d, self.forward));
        // OpenGL-style projection with depth mapped to [-1, 1].
        let zc = (far + near) / (far - near) * z - 2.0 * far * near / (far - near);
        [(f / aspect * x) as f32, (f * y) as f32, zc as f32, z as f32]
    }

    /// `base` lit by the key light, the fill light and ambient at normal `n`.
    fn shade(&self, n: V3, base: [f32; 3]) -> (f32, f32, f32) {
        // Two-sided: a normal facing away from the eye is flipped.
        let n = if dot(n, self.forward) > 0.0 {
            [-n[0], -n[1], -n[2]]
        } else {
            n
        };
        let light = 0.22 + 0.68 * dot(n, self.key).max(0.0) + 0.18 * dot(n, self.fill).max(0.0);
        let light = light as f32;
        (base[0] * light, base[1] * light, base[2] * light)
    }
}

/// Triangle `t`'s normal, scaled by twice its area.
fn face_normal(surface: &SurfaceView<'_>, t: usize) -> V3 {
    let [a, b, c] = surface.triangles[t].map(|v| surface.positions[v as usize]);
    cross(sub(b, a), sub(c, a))
}

/// Vertex normals smoothed within each material (unnormalised), by (vertex, material).
fn smoothed_normals(surface: &SurfaceView<'_>) -> HashMap<(u32, u8), V3> {
    let mut groups: HashMap<(u32, u8), V3> = HashMap::new();
    for (t, tri) in surface.triangles.iter().enumerate() {
        let n = face_normal(surface, t);
        let m = surface.materials.get(t).copied().unwrap_or(0);
        for &v in tri {
            let e = groups.entry((v, m)).or_insert([0.0; 3]);
            *e = [e[0] + n[0], e[1] + n[1], e[2] + n[2]];
        }
    }
    groups
}

/// The lit corners of every triangle wholly in front of the near plane, three per triangle.
fn shade_corners(
    surface: &SurfaceView<'_>,
    palette: &[[f32; 3]],
    view: &View,
    normals: &HashMap<(u32, u8), V3>,
) -> Vec<Corner> {
    let mut corners = Vec::with_capacity(3 * surface.triangles.len());
    for (t, tri) in surface.triangles.iter().enumerate() {
        let clip = tri.map(|v| view.clip_of(surface.positions[v as usize]));
        if clip
            .iter()
            .any(|c| (c[3] as f64) < view.near || !c.iter().all(|x| x.is_finite()))
        {
            continue;
        }
        let m = surface.materials.get(t).copied().unwrap_or(0);
        let base = palette[m as usize];
        for (k, &v) in tri.iter().enumerate() {
            let n = normals
                .get(&(v, m))
                .and_then(|n| normalize(*n))
                .or_else(|| normalize(face_normal(surface, t)))
                .unwrap_or(view.forward);
            corners.push(Corner {
                clip: clip[k],
                colour: view.shade(n, base),
            });
        }
    }
    corners
}

/// Rasterizes `corners` with a depth test into a `sw`×`sh` linear colour buffer.
fn rasterize(corners: &[Corner], sw: usize, sh: usize, background: [f32; 3]) -> Buffer2d<[f32; 3]> {
    let mut colour = Buffer2d::new([sw, sh], background);
    let mut depth = Buffer2d::new([sw, sh], 1.0f32);
    Shaded.draw::<Triangles<Buffer2d<f32>, BackfaceCullingDisabled>, _>(
        corners,
        &mut colour,
        Some(&mut depth),
    );
    colour
}

/// Box-filters `s`×`s` supersamples down to `w`×`h` and gamma-encodes them as RGBA8.
fn downsample(samples: &[[f32; 3]], w: usize, h: usize, s: usize) -> Vec<u8> {
    let sw = w * s;
    let mut rgba = Vec::with_capacity(4 * w * h);
    for y in 0..h {
        for x in 0..w {
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
    rgba
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
