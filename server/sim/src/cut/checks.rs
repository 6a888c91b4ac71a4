//! Checks of incised surfaces, shared by the incision and wound tests.

use crate::geometry::TriMesh;
use crate::geometry::topology::check_surface;
use crate::math::Vec3;
use crate::pipeline::script::vertical_extent;

use super::incision::Incised;
use super::{FaceKind, PathSample};

/// A straight path across the top of `mesh` from (x0, y0) to (x1, y1), `depth` deep.
pub fn top_path(mesh: &TriMesh, from: [f64; 2], to: [f64; 2], depth: f64) -> Vec<PathSample> {
    let n = 24;
    (0..=n)
        .map(|k| {
            let f = k as f64 / n as f64;
            let x = from[0] + f * (to[0] - from[0]);
            let y = from[1] + f * (to[1] - from[1]);
            let (top, _) = vertical_extent(mesh, x, y).expect("surface above");
            let surface = Vec3::new(x, y, top);
            PathSample {
                surface,
                bottom: surface - Vec3::z() * depth,
            }
        })
        .collect()
}

/// The incised surface is closed, edge-manifold and oriented (drawn and envelope), its new
/// triangles have angles ≥ 15°, and every vertex is used.
pub fn check(out: &Incised, name: &str) {
    check_topology(out, name);
    let worst = out
        .created
        .iter()
        .filter(|&&t| out.kinds[t as usize] != FaceKind::Lid)
        .map(|&t| {
            let a = out
                .mesh
                .angles_deg(t as usize)
                .into_iter()
                .fold(180.0, f64::min);
            (
                a,
                out.kinds[t as usize],
                out.mesh.corners(t as usize).map(|c| {
                    [
                        (c.x * 1e4).round() / 10.0,
                        (c.y * 1e4).round() / 10.0,
                        (c.z * 1e4).round() / 10.0,
                    ]
                }),
            )
        })
        .min_by(|a, b| a.0.total_cmp(&b.0));
    assert!(
        out.min_angle_deg >= 15.0,
        "{name}: min angle {} {worst:?} depth {} w {} L {}",
        out.min_angle_deg,
        out.depth_m,
        out.opening_m,
        out.length_m
    );
}

/// The incised surface is closed, edge-manifold and oriented (drawn and envelope), and
/// every vertex is used.
pub fn check_topology(out: &Incised, name: &str) {
    let all_but = |left_out: FaceKind| -> Vec<[u32; 3]> {
        out.mesh
            .triangles
            .iter()
            .zip(&out.kinds)
            .filter(|(_, k)| **k != left_out)
            .map(|(t, _)| *t)
            .collect()
    };
    let (drawn, envelope) = (all_but(FaceKind::Lid), all_but(FaceKind::Wall));
    let nv = out.mesh.positions.len();
    let c = check_surface(&drawn, nv);
    assert!(
        c.closed && c.manifold && c.oriented,
        "{name}: drawn surface {c:?}"
    );
    let c = check_surface(&envelope, nv);
    assert!(
        c.closed && c.manifold && c.oriented,
        "{name}: envelope {c:?}"
    );
    let mut used = vec![false; nv];
    out.mesh
        .triangles
        .iter()
        .flatten()
        .for_each(|&v| used[v as usize] = true);
    assert!(used.iter().all(|&u| u), "{name}: unused vertices");
}

/// A repeatable stream of numbers in [0, 1) from `seed` (xorshift64), for randomized tests.
pub fn uniform(seed: u64) -> impl FnMut() -> f64 {
    let mut rng = seed;
    move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    }
}
