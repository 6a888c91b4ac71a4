//! A half-edge view of a closed, edge-manifold, oriented triangle mesh with the three local
//! edits a remesher needs: split, collapse and flip. Each edit keeps the surface closed,
//! manifold and oriented; the checks that decide whether an edit is wise (lengths, angles,
//! folds) belong to the caller, the topological preconditions are checked here.
//!
//! Half-edge `h` belongs to face `h / 3` when it was made from a triangle; edits reuse and
//! append slots, so only the arrays below say where a half-edge is. Dead faces and vertices
//! are marked with [`NONE`] and dropped by [`HalfEdgeMesh::to_trimesh`].

use std::collections::HashMap;

use crate::geometry::TriMesh;
use crate::math::Vec3;

/// Marks a dead slot (a removed face or vertex).
pub const NONE: u32 = u32::MAX;

/// Half-edge arrays: `to[h]` is the vertex `h` points to, `next[h]` the next half-edge of
/// its face, `twin[h]` the opposite half-edge, `face[h]` its face (`NONE` once removed).
#[derive(Debug, Clone)]
pub struct HalfEdgeMesh {
    /// Vertex positions.
    pub pos: Vec<Vec3>,
    /// One outgoing half-edge per vertex (`NONE` for a removed vertex).
    pub out: Vec<u32>,
    /// Marks on edges (both half-edges) that splits pass on to both halves and collapses to
    /// the edge an edge is glued to: the remesher's feature lines.
    pub marked: Vec<bool>,
    to: Vec<u32>,
    next: Vec<u32>,
    twin: Vec<u32>,
    face: Vec<u32>,
    face_he: Vec<u32>,
}

/// Why a mesh has no half-edge view.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HalfEdgeError {
    /// An edge is used by other than one triangle in each direction.
    #[error("the edge between vertices {} and {} is not used once each way", edge[0], edge[1])]
    NotManifold {
        /// The edge's vertices.
        edge: [u32; 2],
    },
}

impl HalfEdgeMesh {
    /// The half-edge view of a closed, manifold, consistently oriented mesh.
    pub fn new(mesh: &TriMesh) -> Result<Self, HalfEdgeError> {
        let n = mesh.triangles.len() * 3;
        let mut to = Vec::with_capacity(n);
        let mut next = Vec::with_capacity(n);
        let mut face = Vec::with_capacity(n);
        let mut out = vec![NONE; mesh.positions.len()];
        let mut by_ends: HashMap<(u32, u32), u32> = HashMap::with_capacity(n);
        let mut ends = Vec::with_capacity(n);
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let h = (3 * t + k) as u32;
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                to.push(b);
                next.push((3 * t + (k + 1) % 3) as u32);
                face.push(t as u32);
                out[a as usize] = h;
                ends.push((a, b));
                if by_ends.insert((a, b), h).is_some() {
                    return Err(HalfEdgeError::NotManifold { edge: [a, b] });
                }
            }
        }
        // (In half-edge order, so an error names the same edge every run.)
        let mut twin = vec![NONE; n];
        for (h, &(a, b)) in ends.iter().enumerate() {
            match by_ends.get(&(b, a)) {
                Some(&t) => twin[h] = t,
                None => return Err(HalfEdgeError::NotManifold { edge: [a, b] }),
            }
        }
        Ok(Self {
            pos: mesh.positions.clone(),
            out,
            marked: vec![false; n],
            to,
            next,
            twin,
            face,
            face_he: (0..mesh.triangles.len() as u32).map(|t| 3 * t).collect(),
        })
    }

    /// Number of half-edge slots (alive or not).
    pub fn half_edge_slots(&self) -> usize {
        self.to.len()
    }

    /// Whether half-edge `h` is still part of the surface.
    pub fn alive(&self, h: u32) -> bool {
        self.face[h as usize] != NONE
    }

    /// The vertex `h` points to.
    pub fn head(&self, h: u32) -> u32 {
        self.to[h as usize]
    }

    /// The vertex `h` leaves.
    pub fn tail(&self, h: u32) -> u32 {
        self.to[self.twin[h as usize] as usize]
    }

    /// The opposite half-edge.
    pub fn twin(&self, h: u32) -> u32 {
        self.twin[h as usize]
    }

    /// The next half-edge around `h`'s face.
    pub fn next(&self, h: u32) -> u32 {
        self.next[h as usize]
    }

    /// The vertex facing `h` in its face.
    pub fn opposite(&self, h: u32) -> u32 {
        self.to[self.next[h as usize] as usize]
    }

    /// The half-edges leaving `v`, in order around it, into `into` (cleared first).
    pub fn outgoing(&self, v: u32, into: &mut Vec<u32>) {
        into.clear();
        let start = self.out[v as usize];
        if start == NONE {
            return;
        }
        let mut h = start;
        loop {
            into.push(h);
            // Into v along the previous edge of h's face, then out along the next face.
            h = self.next[self.twin[h as usize] as usize];
            if h == start || into.len() > self.to.len() {
                debug_assert!(h == start, "vertex {v}: its fan does not close");
                break;
            }
        }
    }

    /// Number of edges at `v`.
    pub fn valence(&self, v: u32) -> usize {
        let start = self.out[v as usize];
        let mut h = start;
        let mut n = 0;
        loop {
            n += 1;
            h = self.next[self.twin[h as usize] as usize];
            // (A fan longer than the whole mesh is a broken structure, not a vertex.)
            if h == start || n > self.to.len() {
                debug_assert!(h == start, "vertex {v}: its fan does not close");
                return n;
            }
        }
    }

    /// The half-edge from `a` to `b`, if they share an edge.
    pub fn find(&self, a: u32, b: u32) -> Option<u32> {
        let start = self.out[a as usize];
        let mut h = start;
        for _ in 0..self.to.len() {
            if self.to[h as usize] == b {
                return Some(h);
            }
            h = self.next[self.twin[h as usize] as usize];
            if h == start {
                return None;
            }
        }
        debug_assert!(false, "vertex {a}: its fan does not close");
        None
    }

    /// The corners of `h`'s face starting at `h`'s tail.
    pub fn face_corners(&self, h: u32) -> [u32; 3] {
        let n = self.next[h as usize];
        [self.tail(h), self.to[h as usize], self.to[n as usize]]
    }

    /// The two faces of the edge `h` (a → b): `f0 = (a, b, c)` with half-edges h, h1, h2
    /// and `f1 = (b, a, d)` with t (h's twin), t1, t2; as `(t, [h1, h2, t1, t2], [a, b, c,
    /// d], [f0, f1])`.
    fn diamond(&self, h: u32) -> (u32, [u32; 4], [u32; 4], [u32; 2]) {
        let t = self.twin[h as usize];
        let (h1, t1) = (self.next[h as usize], self.next[t as usize]);
        let (h2, t2) = (self.next[h1 as usize], self.next[t1 as usize]);
        let ends = [self.tail(h), self.to[h as usize]];
        let facing = [self.to[h1 as usize], self.to[t1 as usize]];
        (
            t,
            [h1, h2, t1, t2],
            [ends[0], ends[1], facing[0], facing[1]],
            [self.face[h as usize], self.face[t as usize]],
        )
    }

    /// Splits the edge of `h` at `p`: its two faces become four. Returns the new vertex.
    pub fn split(&mut self, h: u32, p: Vec3) -> u32 {
        let (t, [h1, h2, t1, t2], [a, b, c, d], [f0, f1]) = self.diamond(h);
        let m = self.pos.len() as u32;
        self.pos.push(p);
        let (f2, f3) = (self.face_he.len() as u32, self.face_he.len() as u32 + 1);
        let base = self.to.len() as u32;
        // New half-edges: e1 m→c, e2 m→b, e3 c→m, e4 m→d, e5 m→a, e6 d→m.
        let [e1, e2, e3, e4, e5, e6] = [0, 1, 2, 3, 4, 5].map(|k| base + k);
        self.to.extend([c, b, m, d, a, m]);
        self.twin.extend([e3, t, e1, e6, h, e4]);
        self.next.extend([h2, h1, e2, t2, t1, e5]);
        self.face.extend([f0, f2, f2, f1, f3, f3]);
        let m_ab = self.marked[h as usize];
        self.marked.extend([false, m_ab, false, false, m_ab, false]);
        self.face_he.extend([e2, e5]);
        // f0 = (a, m, c): h a→m, e1 m→c, h2 c→a.  f2 = (m, b, c): e2, h1, e3.
        // f1 = (b, m, d): t b→m, e4 m→d, t2 d→b.  f3 = (m, a, d): e5, t1, e6.
        self.to[h as usize] = m;
        self.to[t as usize] = m;
        self.twin[h as usize] = e5;
        self.twin[t as usize] = e2;
        self.next[h as usize] = e1;
        self.next[t as usize] = e4;
        self.next[h1 as usize] = e3;
        self.next[t1 as usize] = e6;
        self.face[h1 as usize] = f2;
        self.face[t1 as usize] = f3;
        self.face_he[f0 as usize] = h;
        self.face_he[f1 as usize] = t;
        self.out.push(e2);
        self.out[a as usize] = h;
        self.out[b as usize] = t;
        m
    }

    /// Whether collapsing `h`'s edge keeps the surface a closed 2-manifold: the two ends
    /// share exactly the two vertices facing the edge (the link condition), and neither of
    /// those drops below three edges.
    pub fn can_collapse(&self, h: u32, scratch: &mut Vec<u32>) -> bool {
        let t = self.twin[h as usize];
        let (a, b) = (self.tail(h), self.to[h as usize]);
        let (c, d) = (self.opposite(h), self.opposite(t));
        if c == d || self.valence(c) <= 3 || self.valence(d) <= 3 {
            return false;
        }
        self.outgoing(b, scratch);
        let shared = scratch
            .iter()
            .filter(|&&o| self.find(a, self.to[o as usize]).is_some())
            .count();
        shared == 2
    }

    /// Collapses `h`'s edge into its head, moved to `p`: the tail and the edge's two faces
    /// go. Check [`Self::can_collapse`] first.
    pub fn collapse(&mut self, h: u32, p: Vec3, scratch: &mut Vec<u32>) {
        let (t, [h1, h2, t1, t2], [a, b, c, d], [f0, f1]) = self.diamond(h);
        // Their outer neighbours: x c→b, y a→c, z d→a, w b→d.
        let [x, y, z, w] = [h1, h2, t1, t2].map(|e| self.twin[e as usize]);
        // Everything that pointed at a now points at b (a tail is its twin's head).
        self.outgoing(a, scratch);
        for &o in scratch.iter() {
            let into = self.twin[o as usize];
            self.to[into as usize] = b;
        }
        self.twin[x as usize] = y;
        self.twin[y as usize] = x;
        self.twin[z as usize] = w;
        self.twin[w as usize] = z;
        for (p, q) in [(x, y), (z, w)] {
            let mark = self.marked[p as usize] || self.marked[q as usize];
            self.marked[p as usize] = mark;
            self.marked[q as usize] = mark;
        }
        for e in [h, h1, h2, t, t1, t2] {
            self.face[e as usize] = NONE;
        }
        self.face_he[f0 as usize] = NONE;
        self.face_he[f1 as usize] = NONE;
        self.out[a as usize] = NONE;
        self.out[b as usize] = y;
        self.out[c as usize] = x;
        self.out[d as usize] = z;
        self.pos[b as usize] = p;
    }

    /// Whether `h`'s edge can be flipped: its facing vertices are distinct, not yet joined,
    /// and its ends keep at least three edges.
    pub fn can_flip(&self, h: u32) -> bool {
        let t = self.twin[h as usize];
        let (c, d) = (self.opposite(h), self.opposite(t));
        c != d
            && self.find(c, d).is_none()
            && self.valence(self.tail(h)) > 3
            && self.valence(self.to[h as usize]) > 3
    }

    /// Turns `h`'s edge to join the two vertices facing it. Check [`Self::can_flip`] first.
    pub fn flip(&mut self, h: u32) {
        let (t, [h1, h2, t1, t2], [a, b, c, d], [f0, f1]) = self.diamond(h);
        // f0 = (c, d, b): h c→d, t2 d→b, h1 b→c.  f1 = (d, c, a): t d→c, h2 c→a, t1 a→d.
        self.to[h as usize] = d;
        self.to[t as usize] = c;
        self.next[h as usize] = t2;
        self.next[t2 as usize] = h1;
        self.next[h1 as usize] = h;
        self.next[t as usize] = h2;
        self.next[h2 as usize] = t1;
        self.next[t1 as usize] = t;
        self.face[t2 as usize] = f0;
        self.face[h2 as usize] = f1;
        self.face_he[f0 as usize] = h;
        self.face_he[f1 as usize] = t;
        self.out[a as usize] = t1;
        self.out[b as usize] = h1;
        self.marked[h as usize] = false;
        self.marked[t as usize] = false;
    }

    /// The live surface as an indexed mesh (dead vertices and faces dropped, vertices
    /// renumbered in order).
    pub fn to_trimesh(&self) -> TriMesh {
        let mut index = vec![NONE; self.pos.len()];
        let mut positions = Vec::new();
        for (v, &o) in self.out.iter().enumerate() {
            if o != NONE {
                index[v] = positions.len() as u32;
                positions.push(self.pos[v]);
            }
        }
        let triangles = self
            .face_he
            .iter()
            .filter(|&&h| h != NONE)
            .map(|&h| self.face_corners(h).map(|v| index[v as usize]))
            .collect();
        TriMesh::new(positions, triangles)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::organs::box_mesh;

    /// Marks follow the edges: a split marked edge leaves two marked halves and unmarked
    /// spokes; a collapse glues each removed face's two outer edges into one, marked if
    /// either was; a flip leaves its new edge unmarked.
    #[test]
    fn marks_follow_splits_collapses_and_flips() {
        let mut hm = HalfEdgeMesh::new(&box_mesh(Vec3::new(1.0, 1.0, 1.0), [2, 2, 2])).unwrap();
        let mut scratch = Vec::new();
        let h = 0;
        let (a, b) = (hm.tail(h), hm.head(h));
        let t = hm.twin(h);
        hm.marked[h as usize] = true;
        hm.marked[t as usize] = true;
        let m = hm.split(h, 0.5 * (hm.pos[a as usize] + hm.pos[b as usize]));
        let marked_at = |hm: &HalfEdgeMesh, v: u32, scratch: &mut Vec<u32>| {
            hm.outgoing(v, scratch);
            let mut ends: Vec<u32> = scratch
                .iter()
                .filter(|&&o| hm.marked[o as usize])
                .map(|&o| hm.head(o))
                .collect();
            ends.sort_unstable();
            ends
        };
        let mut ab = vec![a, b];
        ab.sort_unstable();
        assert_eq!(marked_at(&hm, m, &mut scratch), ab);
        assert_eq!(hm.valence(m), 4);
        // Collapse a spoke m → c: the face (a, m, c)'s outer edges c–a and a–m are glued
        // into one, marked because a–m was.
        let spoke = hm.find(m, hm.opposite(h)).unwrap();
        let c = hm.head(spoke);
        assert!(hm.can_collapse(spoke, &mut scratch));
        let at = hm.pos[c as usize];
        hm.collapse(spoke, at, &mut scratch);
        assert!(hm.find(a, c).is_some_and(|e| hm.marked[e as usize]));
        assert!(hm.find(c, a).is_some_and(|e| hm.marked[e as usize]));
        // Flip an unmarked edge: its new edge is unmarked.
        let e = (0..hm.half_edge_slots() as u32)
            .find(|&e| hm.alive(e) && !hm.marked[e as usize] && hm.can_flip(e))
            .unwrap();
        hm.flip(e);
        assert!(!hm.marked[e as usize] && !hm.marked[hm.twin(e) as usize]);
        let out = hm.to_trimesh();
        let check = crate::geometry::topology::check_surface(&out.triangles, out.positions.len());
        assert!(
            check.closed && check.manifold && check.oriented,
            "{check:?}"
        );
    }
}
