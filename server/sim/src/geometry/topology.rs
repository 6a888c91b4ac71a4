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
