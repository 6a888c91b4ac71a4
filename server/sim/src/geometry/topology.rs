//! Edge adjacency of a triangle mesh, built by sorting (deterministic, no hashing).

/// One use of an undirected edge by a triangle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EdgeUse {
    /// The triangle using the edge.
    pub triangle: u32,
    /// True when the triangle traverses the edge from its lower to its higher vertex index.
    pub ascending: bool,
}

/// All undirected edges of a mesh with the triangles that use them.
#[derive(Debug, Clone)]
pub struct EdgeTable {
    /// `(low, high)` vertex pair of each edge, sorted.
    pub edges: Vec<[u32; 2]>,
    /// `uses[start[e]..start[e + 1]]` are the uses of edge `e`.
    pub start: Vec<u32>,
    /// Edge uses grouped by edge.
    pub uses: Vec<EdgeUse>,
}

impl EdgeTable {
    /// Builds the table for `triangles`.
    pub fn build(triangles: &[[u32; 3]]) -> Self {
        let mut all: Vec<([u32; 2], EdgeUse)> = Vec::with_capacity(triangles.len() * 3);
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                all.push((
                    [a.min(b), a.max(b)],
                    EdgeUse {
                        triangle: t as u32,
                        ascending: a < b,
                    },
                ));
            }
        }
        all.sort_unstable_by_key(|(e, u)| (*e, u.triangle));
        let mut edges = Vec::new();
        let mut start = Vec::new();
        let mut uses = Vec::with_capacity(all.len());
        for (i, (e, u)) in all.iter().enumerate() {
            if i == 0 || all[i - 1].0 != *e {
                edges.push(*e);
                start.push(uses.len() as u32);
            }
            uses.push(*u);
        }
        start.push(uses.len() as u32);
        Self { edges, start, uses }
    }

    /// The triangles using edge `e`.
    pub fn uses_of(&self, e: usize) -> &[EdgeUse] {
        &self.uses[self.start[e] as usize..self.start[e + 1] as usize]
    }

    /// Index of the edge `{a, b}`, if present.
    pub fn find(&self, a: u32, b: u32) -> Option<usize> {
        self.edges.binary_search(&[a.min(b), a.max(b)]).ok()
    }

    /// Number of edges.
    pub fn len(&self) -> usize {
        self.edges.len()
    }

    /// True when there are no edges.
    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }
}

/// For every triangle, the three neighbouring triangles across its edges `(v0,v1)`,
/// `(v1,v2)`, `(v2,v0)`. Only valid for closed, edge-manifold meshes.
pub fn triangle_neighbours(triangles: &[[u32; 3]], table: &EdgeTable) -> Vec<[u32; 3]> {
    let mut nb = vec![[u32::MAX; 3]; triangles.len()];
    for e in 0..table.len() {
        if let [u, w] = table.uses_of(e) {
            let [lo, hi] = table.edges[e];
            for (me, other) in [(u, w), (w, u)] {
                let tri = triangles[me.triangle as usize];
                let k = (0..3)
                    .find(|&k| {
                        let (a, b) = (tri[k], tri[(k + 1) % 3]);
                        a.min(b) == lo && a.max(b) == hi
                    })
                    .expect("edge belongs to its triangle");
                nb[me.triangle as usize][k] = other.triangle;
            }
        }
    }
    nb
}

/// Each triangle's component (triangles joined through shared edges), numbered in the
/// order of their first triangles, and the number of components. For closed,
/// edge-manifold meshes.
pub fn triangle_components(triangles: &[[u32; 3]]) -> (Vec<u32>, usize) {
    let nb = triangle_neighbours(triangles, &EdgeTable::build(triangles));
    let mut component = vec![u32::MAX; triangles.len()];
    let mut count = 0;
    let mut stack = Vec::new();
    for seed in 0..triangles.len() {
        if component[seed] != u32::MAX {
            continue;
        }
        component[seed] = count;
        stack.push(seed as u32);
        while let Some(t) = stack.pop() {
            for n in nb[t as usize] {
                if n != u32::MAX && component[n as usize] == u32::MAX {
                    component[n as usize] = count;
                    stack.push(n);
                }
            }
        }
        count += 1;
    }
    (component, count as usize)
}

/// Topological soundness of a triangle set (a whole surface or part of one).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct SurfaceCheck {
    /// Every edge is used by exactly two triangles.
    pub closed: bool,
    /// No edge has more than two triangles and the triangles around every vertex form one
    /// fan (a single cycle when closed).
    pub manifold: bool,
    /// Every edge shared by two triangles is traversed once in each direction.
    pub oriented: bool,
}

/// Checks `triangles` over `vertex_count` vertices.
pub fn check_surface(triangles: &[[u32; 3]], vertex_count: usize) -> SurfaceCheck {
    let table = EdgeTable::build(triangles);
    let mut closed = true;
    let mut manifold = true;
    let mut oriented = true;
    for e in 0..table.len() {
        let uses = table.uses_of(e);
        match uses.len() {
            2 => oriented &= uses[0].ascending != uses[1].ascending,
            1 => closed = false,
            _ => {
                closed = false;
                manifold = false;
            }
        }
    }
    // Vertex fans: the edges opposite a vertex, in triangle order, must chain into one
    // path (one cycle when closed).
    let mut opposite: Vec<Vec<(u32, u32)>> = vec![Vec::new(); vertex_count];
    for tri in triangles {
        for k in 0..3 {
            opposite[tri[k] as usize].push((tri[(k + 1) % 3], tri[(k + 2) % 3]));
        }
    }
    for fan in opposite.iter_mut().filter(|f| !f.is_empty()) {
        fan.sort_unstable();
        if fan.windows(2).any(|w| w[0].0 == w[1].0) {
            manifold = false;
            continue;
        }
        // Start at an edge whose start is no other edge's end (an open fan), or anywhere.
        let ends: std::collections::HashSet<u32> = fan.iter().map(|e| e.1).collect();
        let start = fan
            .iter()
            .find(|e| !ends.contains(&e.0))
            .copied()
            .unwrap_or(fan[0]);
        let mut visited = 1;
        let mut at = start.1;
        while let Ok(i) = fan.binary_search_by_key(&at, |e| e.0) {
            if fan[i] == start {
                break;
            }
            visited += 1;
            at = fan[i].1;
            if visited > fan.len() {
                break;
            }
        }
        if visited != fan.len() {
            manifold = false;
        }
    }
    SurfaceCheck {
        closed,
        manifold,
        oriented,
    }
}

#[cfg(test)]
mod surface_check_tests {
    use super::*;

    #[test]
    fn tetrahedron_and_its_defects() {
        let tet = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]];
        let ok = check_surface(&tet, 4);
        assert!(ok.closed && ok.manifold && ok.oriented);
        let mut flipped = tet;
        flipped[0] = [0, 1, 2];
        assert!(!check_surface(&flipped, 4).oriented);
        assert!(!check_surface(&tet[..3], 4).closed);
        // Two tetrahedra sharing only a vertex: closed, but not vertex-manifold.
        let two: Vec<[u32; 3]> = tet
            .iter()
            .copied()
            .chain(
                tet.iter()
                    .map(|t| t.map(|v| if v == 0 { 0 } else { v + 3 })),
            )
            .collect();
        let c = check_surface(&two, 7);
        assert!(c.closed && c.oriented && !c.manifold);
    }
}
