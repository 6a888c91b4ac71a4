//! Geometric predicates in double precision with consistent tie-breaking.
//!
//! These are not exact-arithmetic predicates. They are made *consistent* instead: the same
//! edge evaluated from either adjacent triangle gives exactly negated values, so ray and
//! segment queries against a closed mesh never count a shared edge twice or not at all.

use crate::math::Vec3;

/// Orientation of `d` relative to the plane through `a, b, c`: positive when `d` is on the
/// side the normal `(b−a)×(c−a)` points to.
#[inline]
pub fn orient3d(a: &Vec3, b: &Vec3, c: &Vec3, d: &Vec3) -> f64 {
    (b - a).cross(&(c - a)).dot(&(d - a))
}

/// True when the open segment `(p, q)` crosses the interior of triangle `tri` transversally.
///
/// Touching (an endpoint on the triangle's plane, or the segment passing through an edge or
/// vertex) is not a crossing, and neither is a coplanar overlap. Self-intersection checks
/// and visibility tests use it where only proper crossings matter.
pub fn segment_crosses_triangle(p: &Vec3, q: &Vec3, tri: &[Vec3; 3]) -> bool {
    let [a, b, c] = tri;
    let sp = orient3d(a, b, c, p);
    let sq = orient3d(a, b, c, q);
    if sp == 0.0 || sq == 0.0 || (sp > 0.0) == (sq > 0.0) {
        return false;
    }
    // The line pq pierces the plane; it passes through the interior when it sees the three
    // edges with the same strict orientation.
    let e0 = orient3d(p, q, a, b);
    let e1 = orient3d(p, q, b, c);
    let e2 = orient3d(p, q, c, a);
    (e0 > 0.0 && e1 > 0.0 && e2 > 0.0) || (e0 < 0.0 && e1 < 0.0 && e2 < 0.0)
}

/// True when two triangles that share no vertex intersect transversally.
pub fn disjoint_triangles_intersect(t: &[Vec3; 3], u: &[Vec3; 3]) -> bool {
    (0..3).any(|k| segment_crosses_triangle(&t[k], &t[(k + 1) % 3], u))
        || (0..3).any(|k| segment_crosses_triangle(&u[k], &u[(k + 1) % 3], t))
}

/// Twice the signed area of the 2D triangle `(a, b, p)`, computed so that swapping `a` and
/// `b` gives exactly the negated value (the endpoints are ordered before evaluation).
#[inline]
pub fn edge_function(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    let swapped = (b[0], b[1]) < (a[0], a[1]);
    let (a, b) = if swapped { (b, a) } else { (a, b) };
    let v = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    if swapped { -v } else { v }
}

/// Whether a point lying exactly on the directed edge `a → b` of a counter-clockwise
/// triangle belongs to that triangle ("top-left" rule, as in rasterizers). Of the two
/// triangles sharing the edge, exactly one claims such a point.
#[inline]
fn owns_boundary(a: [f64; 2], b: [f64; 2]) -> bool {
    let dx = b[0] - a[0];
    let dy = b[1] - a[1];
    dy < 0.0 || (dy == 0.0 && dx > 0.0)
}

/// Point-in-triangle test in 2D with the top-left tie rule. Returns `None` when `p` is
/// outside or the triangle is degenerate, else `Some(orientation)` with +1 for a
/// counter-clockwise triangle and −1 for clockwise.
pub fn point_in_triangle_2d(tri: [[f64; 2]; 3], p: [f64; 2]) -> Option<i8> {
    let [a, b, c] = tri;
    let area = edge_function(a, b, c);
    if area == 0.0 {
        return None;
    }
    // Work on the counter-clockwise ordering so that the tie rule is orientation-free.
    let (sign, [a, b, c]) = if area > 0.0 {
        (1, [a, b, c])
    } else {
        (-1, [a, c, b])
    };
    for (u, v) in [(a, b), (b, c), (c, a)] {
        let e = edge_function(u, v, p);
        if e < 0.0 || (e == 0.0 && !owns_boundary(u, v)) {
            return None;
        }
    }
    Some(sign)
}

/// Whether the segment `[p, q]` meets the closed triangle (boundary included). Hits on an
/// edge shared by two triangles of Σ are reported by both, so no pair slips through a seam.
/// An endpoint exactly on the triangle's plane counts as on its positive side.
pub fn segment_meets_triangle(p: &Vec3, q: &Vec3, tri: &[Vec3; 3]) -> bool {
    let [a, b, c] = tri;
    let n = (b - a).cross(&(c - a));
    let sp = n.dot(&(p - a));
    let sq = n.dot(&(q - a));
    let side = |s: f64| s >= 0.0;
    if side(sp) == side(sq) {
        return false;
    }
    let t = sp / (sp - sq);
    let x = p + (q - p) * t;
    // Barycentric coordinates of x, with a tolerance relative to the triangle's size.
    let nn = n.norm_squared();
    if nn == 0.0 {
        return false;
    }
    let u = n.dot(&(b - x).cross(&(c - x))) / nn;
    let v = n.dot(&(c - x).cross(&(a - x))) / nn;
    let w = 1.0 - u - v;
    let tol = -1e-12;
    u >= tol && v >= tol && w >= tol
}

/// Where on the segment `[a, b]` the point nearest `x` is, as a fraction from `a` (0 for a
/// degenerate segment).
pub fn nearest_on_segment(x: &Vec3, a: &Vec3, b: &Vec3) -> f64 {
    let ab = b - a;
    let len2 = ab.norm_squared();
    if len2 > 0.0 {
        ((x - a).dot(&ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Squared distance from `x` to the segment `[a, b]`.
pub fn distance_sq_to_segment(x: &Vec3, a: &Vec3, b: &Vec3) -> f64 {
    (a + (b - a) * nearest_on_segment(x, a, b) - x).norm_squared()
}

/// Where the line `origin + t·dir` meets a triangle (Möller–Trumbore): the parameter t
/// (any sign, in units of `dir`) and the barycentric coordinates, or `None` if it misses
/// (boundary included) or runs parallel to it.
pub fn line_triangle(origin: &Vec3, dir: &Vec3, tri: &[Vec3; 3]) -> Option<(f64, [f64; 3])> {
    let e1 = tri[1] - tri[0];
    let e2 = tri[2] - tri[0];
    let h = dir.cross(&e2);
    let det = e1.dot(&h);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - tri[0];
    let u = s.dot(&h) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = dir.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some((e2.dot(&q) * inv, [1.0 - u - v, u, v]))
}

/// The point of the closed triangle nearest to `x` (Ericson, Real-Time Collision Detection
/// §5.1.5: Voronoi regions of the vertices, edges and face).
pub fn closest_point_on_triangle(x: &Vec3, tri: &[Vec3; 3]) -> Vec3 {
    let [a, b, c] = tri;
    let ab = b - a;
    let ac = c - a;
    let ap = x - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = x - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = x - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    if denom == 0.0 {
        // Degenerate triangle: the nearest of its vertices.
        return [*a, *b, *c]
            .into_iter()
            .min_by(|p, q| (p - x).norm_squared().total_cmp(&(q - x).norm_squared()))
            .unwrap_or(*a);
    }
    a + ab * (vb / denom) + ac * (vc / denom)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_meets_a_triangle_with_its_parameter_and_barycentrics() {
        let tri = [
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(2.0, 0.0, 1.0),
            Vec3::new(0.0, 2.0, 1.0),
        ];
        let (t, b) =
            line_triangle(&Vec3::new(0.5, 0.5, -1.0), &Vec3::new(0.0, 0.0, 4.0), &tri).unwrap();
        assert!((t - 0.5).abs() < 1e-15);
        assert!((b[0] - 0.5).abs() < 1e-15 && (b[1] - 0.25).abs() < 1e-15);
        // Behind the origin: a negative parameter, still a hit of the line.
        let (t, _) = line_triangle(&Vec3::new(0.5, 0.5, 3.0), &Vec3::z(), &tri).unwrap();
        assert!((t + 2.0).abs() < 1e-15);
        // Outside, and parallel.
        assert!(line_triangle(&Vec3::new(3.0, 3.0, 0.0), &Vec3::z(), &tri).is_none());
        assert!(line_triangle(&Vec3::zeros(), &Vec3::x(), &tri).is_none());
    }

    fn v(x: f64, y: f64, z: f64) -> Vec3 {
        Vec3::new(x, y, z)
    }

    #[test]
    fn segment_through_triangle_interior() {
        let tri = [v(0., 0., 0.), v(1., 0., 0.), v(0., 1., 0.)];
        assert!(segment_crosses_triangle(
            &v(0.2, 0.2, -1.),
            &v(0.2, 0.2, 1.),
            &tri
        ));
        assert!(!segment_crosses_triangle(
            &v(0.8, 0.8, -1.),
            &v(0.8, 0.8, 1.),
            &tri
        ));
        // Ends on the plane: touching, not crossing.
        assert!(!segment_crosses_triangle(
            &v(0.2, 0.2, 0.),
            &v(0.2, 0.2, 1.),
            &tri
        ));
    }

    #[test]
    fn shared_edge_point_is_claimed_exactly_once() {
        // Two triangles sharing the diagonal of the unit square, both counter-clockwise.
        let t1 = [[0., 0.], [1., 0.], [1., 1.]];
        let t2 = [[0., 0.], [1., 1.], [0., 1.]];
        for p in [[0.5, 0.5], [0.25, 0.25], [0.0, 0.0], [1.0, 1.0]] {
            let n = [t1, t2]
                .iter()
                .filter(|t| point_in_triangle_2d(**t, p).is_some())
                .count();
            assert!(n <= 1, "point {p:?} claimed {n} times");
        }
        assert_eq!(
            [t1, t2]
                .iter()
                .filter(|t| point_in_triangle_2d(**t, [0.5, 0.5]).is_some())
                .count(),
            1
        );
    }

    #[test]
    fn shared_vertex_of_a_fan_is_claimed_once() {
        // Six triangles around the origin, alternating orientation must not matter.
        let ring: Vec<[f64; 2]> = (0..6)
            .map(|k| {
                let a = k as f64 * std::f64::consts::PI / 3.0;
                [a.cos(), a.sin()]
            })
            .collect();
        let n = (0..6)
            .filter(|&k| {
                let mut tri = [[0.0, 0.0], ring[k], ring[(k + 1) % 6]];
                if k % 2 == 1 {
                    tri.swap(1, 2);
                }
                point_in_triangle_2d(tri, [0.0, 0.0]).is_some()
            })
            .count();
        assert_eq!(n, 1);
    }

    #[test]
    fn closest_points_in_every_region() {
        let tri = [v(0., 0., 0.), v(1., 0., 0.), v(0., 1., 0.)];
        let cases = [
            (v(0.2, 0.2, 1.0), v(0.2, 0.2, 0.0)),
            (v(-1.0, -1.0, 0.5), v(0.0, 0.0, 0.0)),
            (v(2.0, -0.5, 0.0), v(1.0, 0.0, 0.0)),
            (v(0.5, -1.0, 0.0), v(0.5, 0.0, 0.0)),
            (v(1.0, 1.0, 0.0), v(0.5, 0.5, 0.0)),
            (v(-1.0, 0.5, 0.0), v(0.0, 0.5, 0.0)),
            (v(-0.1, 3.0, 0.0), v(0.0, 1.0, 0.0)),
        ];
        for (x, want) in cases {
            assert!(
                (closest_point_on_triangle(&x, &tri) - want).norm() < 1e-12,
                "{x}"
            );
        }
        assert!(
            (distance_sq_to_segment(&v(0.5, 1.0, 0.0), &v(0., 0., 0.), &v(1., 0., 0.)) - 1.0).abs()
                < 1e-15
        );
        assert!(
            (distance_sq_to_segment(&v(3.0, 0.0, 0.0), &v(0., 0., 0.), &v(1., 0., 0.)) - 4.0).abs()
                < 1e-15
        );
    }
}
