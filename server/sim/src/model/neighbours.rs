//! Rest-space neighbourhoods of the interior points: the kernel, a uniform grid for radius
//! queries, and fixed-capacity neighbour lists that a cut can edit in place.

use super::rows::Rows;
use crate::math::{Aabb, Vec3};

/// The MLS weight kernel `ŵ(r) = (1 − r²/h²)³` for `r < h` (physics.md §1.2). The poly6
/// normalisation is left out: it cancels in the MLS gradient.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kernel {
    /// Support radius h (m).
    pub support_m: f64,
}

impl Kernel {
    /// Weight at squared distance `r2` (m²); zero at and beyond the support.
    #[inline]
    pub fn weight_sq(&self, r2: f64) -> f64 {
        let q = 1.0 - r2 / (self.support_m * self.support_m);
        if q <= 0.0 { 0.0 } else { q * q * q }
    }
}

/// A uniform grid over rest positions with cells of the support radius, so a radius-h query
/// looks at 27 cells. Built once; cuts change neighbour lists, not rest positions.
#[derive(Debug, Clone)]
pub struct RestGrid {
    origin: Vec3,
    cell_m: f64,
    dims: [usize; 3],
    /// The points in each cell.
    cells: Rows,
}

impl RestGrid {
    /// Bins `positions` into cells of size `cell_m`.
    pub fn build(positions: &[Vec3], cell_m: f64) -> Self {
        let mut grid = Self {
            origin: Vec3::zeros(),
            cell_m,
            dims: [1; 3],
            cells: Rows::default(),
        };
        grid.rebin(positions, cell_m);
        grid
    }

    /// Room for `cells` cells and `items` points, for [`Self::rebin`] to fill without
    /// allocating.
    pub fn reserve(&mut self, cells: usize, items: usize) {
        self.cells.reserve(cells, items);
    }

    /// Bins `positions` anew into cells of size `cell_m`, in this grid's buffers: no
    /// allocation while they have room.
    pub fn rebin(&mut self, positions: &[Vec3], cell_m: f64) {
        let bbox = Aabb::around(positions);
        self.origin = if bbox.is_empty() {
            Vec3::zeros()
        } else {
            bbox.min_v()
        };
        let size = if bbox.is_empty() {
            Vec3::zeros()
        } else {
            bbox.size()
        };
        self.cell_m = cell_m;
        self.dims = [0, 1, 2].map(|a| (size[a] / cell_m).floor() as usize + 1);
        let n = self.dims[0] * self.dims[1] * self.dims[2];
        let mut cells = std::mem::take(&mut self.cells);
        let grid = &*self;
        let pairs = (positions.iter().enumerate()).map(|(i, p)| (grid.cell_of(p) as u32, i as u32));
        cells.refill(n, pairs);
        self.cells = cells;
    }

    fn coords(&self, p: &Vec3) -> [i64; 3] {
        [0, 1, 2].map(|a| ((p[a] - self.origin[a]) / self.cell_m).floor() as i64)
    }

    fn cell_of(&self, p: &Vec3) -> usize {
        let c = self.coords(p);
        let c = [0, 1, 2].map(|a| c[a].clamp(0, self.dims[a] as i64 - 1) as usize);
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    /// Calls `f(j, r²)` for every point j with `|X_j − p|² < radius²`. `radius` may exceed
    /// the cell size (more cells are visited).
    pub fn for_each_within(
        &self,
        positions: &[Vec3],
        p: &Vec3,
        radius: f64,
        mut f: impl FnMut(u32, f64),
    ) {
        let reach = (radius / self.cell_m).ceil() as i64;
        let c = self.coords(p);
        let r2 = radius * radius;
        for z in (c[2] - reach).max(0)..=(c[2] + reach).min(self.dims[2] as i64 - 1) {
            for y in (c[1] - reach).max(0)..=(c[1] + reach).min(self.dims[1] as i64 - 1) {
                for x in (c[0] - reach).max(0)..=(c[0] + reach).min(self.dims[0] as i64 - 1) {
                    let cell = x as usize + self.dims[0] * (y as usize + self.dims[1] * z as usize);
                    for &j in self.cells.of(cell) {
                        let d2 = (positions[j as usize] - p).norm_squared();
                        if d2 < r2 {
                            f(j, d2);
                        }
                    }
                }
            }
        }
    }
}

/// Neighbour lists N(i) with a fixed capacity per point, so that cuts (removing pairs) and
/// virtual points (adding pairs) edit them in place without reallocating.
#[derive(Debug, Clone, PartialEq)]
pub struct Neighbourhoods {
    capacity: usize,
    counts: Vec<u32>,
    ids: Vec<u32>,
    /// Per slot, a distance added to the pair's rest distance in the kernel (m): zero, or the
    /// transparency of a pair that crosses the cut near its front (physics.md §4.3).
    extra: Vec<f64>,
}

/// A neighbour list is full; the model was built with too little headroom.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("point {point} already has the maximum of {capacity} neighbours")]
pub struct NeighbourCapacityError {
    /// The point whose list is full.
    pub point: u32,
    /// The capacity.
    pub capacity: usize,
}

impl Neighbourhoods {
    /// Finds, for every point, the other points strictly within `support_m` (those at exactly
    /// h have zero weight and are left out), keeping `headroom` free slots per point.
    pub fn build(positions: &[Vec3], grid: &RestGrid, support_m: f64, headroom: usize) -> Self {
        // Points exactly at h would have zero weight; the tolerance keeps lattice neighbours at
        // 2s out of the list when h = 2s, whatever the rounding.
        let radius = support_m * (1.0 - 1e-9);
        let mut lists: Vec<Vec<u32>> = Vec::with_capacity(positions.len());
        for (i, p) in positions.iter().enumerate() {
            let mut list = Vec::new();
            grid.for_each_within(positions, p, radius, |j, _| {
                if j as usize != i {
                    list.push(j);
                }
            });
            list.sort_unstable();
            lists.push(list);
        }
        let capacity = lists.iter().map(Vec::len).max().unwrap_or(0) + headroom;
        let mut counts = Vec::with_capacity(positions.len());
        let mut ids = vec![u32::MAX; capacity * positions.len()];
        for (i, list) in lists.iter().enumerate() {
            counts.push(list.len() as u32);
            ids[i * capacity..i * capacity + list.len()].copy_from_slice(list);
        }
        Self {
            capacity,
            counts,
            extra: vec![0.0; ids.len()],
            ids,
        }
    }

    /// The same lists followed by `extra` empty ones (with the same capacity), for nodes
    /// added later, such as virtual points.
    pub fn with_spare_lists(&self, extra: usize) -> Self {
        let mut out = self.clone();
        out.counts.resize(self.counts.len() + extra, 0);
        out.ids.resize(out.counts.len() * self.capacity, u32::MAX);
        out.extra.resize(out.ids.len(), 0.0);
        out
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.counts.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.counts.is_empty()
    }

    /// Slots per point.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// N(i).
    #[inline]
    pub fn of(&self, i: usize) -> &[u32] {
        let start = i * self.capacity;
        &self.ids[start..start + self.counts[i] as usize]
    }

    /// Removes j from N(i); returns whether it was there.
    pub fn remove(&mut self, i: usize, j: u32) -> bool {
        let start = i * self.capacity;
        let n = self.counts[i] as usize;
        let Some(k) = self.ids[start..start + n].iter().position(|&x| x == j) else {
            return false;
        };
        self.ids[start + k] = self.ids[start + n - 1];
        self.extra[start + k] = self.extra[start + n - 1];
        self.ids[start + n - 1] = u32::MAX;
        self.extra[start + n - 1] = 0.0;
        self.counts[i] -= 1;
        true
    }

    /// The kernel-distance additions of N(i), slot by slot (see [`Neighbourhoods::of`]).
    #[inline]
    pub fn extra_of(&self, i: usize) -> &[f64] {
        let start = i * self.capacity;
        &self.extra[start..start + self.counts[i] as usize]
    }

    /// Sets the kernel-distance addition of the pair (i, j) on both sides; returns whether
    /// the pair is there.
    pub fn set_extra(&mut self, i: usize, j: u32, extra_m: f64) -> bool {
        let mut found = true;
        for (a, b) in [(i, j), (j as usize, i as u32)] {
            let start = a * self.capacity;
            match self.of(a).iter().position(|&x| x == b) {
                Some(k) => self.extra[start + k] = extra_m,
                None => found = false,
            }
        }
        found
    }

    /// Adds j to N(i) if it is not there yet.
    pub fn add(&mut self, i: usize, j: u32) -> Result<(), NeighbourCapacityError> {
        if self.of(i).contains(&j) {
            return Ok(());
        }
        let n = self.counts[i] as usize;
        if n == self.capacity {
            return Err(NeighbourCapacityError {
                point: i as u32,
                capacity: self.capacity,
            });
        }
        self.ids[i * self.capacity + n] = j;
        self.extra[i * self.capacity + n] = 0.0;
        self.counts[i] += 1;
        Ok(())
    }

    /// Smallest, mean and largest neighbour count.
    pub fn count_stats(&self) -> (usize, f64, usize) {
        let min = self.counts.iter().copied().min().unwrap_or(0) as usize;
        let max = self.counts.iter().copied().max().unwrap_or(0) as usize;
        let mean = if self.counts.is_empty() {
            0.0
        } else {
            self.counts.iter().map(|&c| c as f64).sum::<f64>() / self.counts.len() as f64
        };
        (min, mean, max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube_lattice(n: usize, s: f64) -> Vec<Vec3> {
        let mut v = Vec::new();
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    v.push(Vec3::new(i as f64, j as f64, k as f64) * s);
                }
            }
        }
        v
    }

    #[test]
    fn interior_lattice_point_has_26_neighbours_at_h_2s() {
        let s = 0.003;
        let pts = cube_lattice(5, s);
        let grid = RestGrid::build(&pts, 2.0 * s);
        let nb = Neighbourhoods::build(&pts, &grid, 2.0 * s, 4);
        let centre = 2 + 5 * (2 + 5 * 2);
        assert_eq!(nb.of(centre).len(), 26);
        assert_eq!(nb.of(0).len(), 7);
        assert_eq!(nb.capacity(), 30);
    }

    #[test]
    fn neighbour_lists_are_symmetric_and_editable() {
        let s = 0.002;
        let pts = cube_lattice(4, s);
        let grid = RestGrid::build(&pts, 1.5 * s);
        let mut nb = Neighbourhoods::build(&pts, &grid, 1.5 * s, 2);
        for i in 0..pts.len() {
            for &j in nb.of(i) {
                assert!(nb.of(j as usize).contains(&(i as u32)));
            }
        }
        let j = nb.of(5)[0];
        assert!(nb.remove(5, j));
        assert!(!nb.of(5).contains(&j));
        assert!(!nb.remove(5, j));
        nb.add(5, j).unwrap();
        assert!(nb.of(5).contains(&j));
    }

    #[test]
    fn kernel_is_one_at_zero_and_zero_at_support() {
        let k = Kernel { support_m: 0.004 };
        assert_eq!(k.weight_sq(0.0), 1.0);
        assert_eq!(k.weight_sq(0.004 * 0.004), 0.0);
        assert!((k.weight_sq(0.002 * 0.002) - 0.421875).abs() < 1e-15);
    }
}
