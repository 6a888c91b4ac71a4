//! Material samples that follow the points through fixed rows of weights,
//! `x_s = Σ_k c_sk p_k + (X_s − Σ_k c_sk X_k)`: linear in the points, so a force f on a
//! sample reaches them as `c_sk f` and a spring k on it adds `k c cᵀ` to the stiffness.
//! The held vertices (`held`) and the tool's contact samples (`contact`) are such samples.

use crate::math::Vec3;

/// Samples and their rows, compressed.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EmbeddedRows {
    start: Vec<u32>,
    points: Vec<u32>,
    weights: Vec<f64>,
    /// `X_s − Σ c X_k`.
    offset: Vec<Vec3>,
    /// The points any sample follows, each once, ascending.
    reached: Vec<u32>,
}

impl EmbeddedRows {
    /// Samples at rest positions `rest`, each following its row, over points at rest
    /// positions `rest_points`.
    pub fn new<'a>(
        rows: impl Iterator<Item = (&'a [(u32, f64)], Vec3)>,
        rest_points: &[Vec3],
    ) -> Self {
        let mut out = Self {
            start: vec![0],
            ..Self::default()
        };
        let mut seen = vec![false; rest_points.len()];
        for (row, rest) in rows {
            out.push(row, rest, rest_points, &mut seen);
        }
        out.finish(&mut seen);
        out
    }

    /// No samples, with room for `samples` of them following `entries` points in all,
    /// over `points` points: [`Self::clear`] and [`Self::push`] then refill it without
    /// allocating while they fit (the blade's samples, rebuilt on the simulation thread).
    pub fn with_room(points: usize, samples: usize, entries: usize) -> Self {
        let mut start = Vec::with_capacity(samples + 1);
        start.push(0);
        Self {
            start,
            points: Vec::with_capacity(entries),
            weights: Vec::with_capacity(entries),
            offset: Vec::with_capacity(samples),
            reached: Vec::with_capacity(points),
        }
    }

    /// Removes every sample (keeps the room).
    pub fn clear(&mut self) {
        self.start.truncate(1);
        self.points.clear();
        self.weights.clear();
        self.offset.clear();
        self.reached.clear();
    }

    /// Whether a sample of `entries` more points still fits the room (`with_room`).
    pub fn fits(&self, entries: usize) -> bool {
        self.offset.len() < self.offset.capacity()
            && self.points.len() + entries <= self.points.capacity()
    }

    /// Adds a sample at rest position `rest` following `row` over points at
    /// `rest_points`; `seen` (one flag per point, all false between builds) marks the
    /// points already reached. Call [`Self::finish`] after the last.
    pub fn push(
        &mut self,
        row: &[(u32, f64)],
        rest: Vec3,
        rest_points: &[Vec3],
        seen: &mut [bool],
    ) {
        let mut followed = Vec3::zeros();
        for &(k, w) in row {
            self.points.push(k);
            self.weights.push(w);
            followed += rest_points[k as usize] * w;
            if !std::mem::replace(&mut seen[k as usize], true) {
                self.reached.push(k);
            }
        }
        self.start.push(self.points.len() as u32);
        self.offset.push(rest - followed);
    }

    /// Sorts the points reached and clears their flags in `seen`.
    pub fn finish(&mut self, seen: &mut [bool]) {
        self.reached.sort_unstable();
        for &k in &self.reached {
            seen[k as usize] = false;
        }
    }

    /// Keeps the samples `keep[s]` says, in order, in place (no allocation); `seen` as for
    /// [`Self::push`].
    pub fn retain(&mut self, keep: &[bool], seen: &mut [bool]) {
        let (mut kept, mut entries) = (0, 0);
        let mut from = self.start[0] as usize;
        self.reached.clear();
        for (s, &k) in keep.iter().enumerate().take(self.len()) {
            let to = self.start[s + 1] as usize;
            if k {
                for i in from..to {
                    let point = self.points[i];
                    self.points[entries] = point;
                    self.weights[entries] = self.weights[i];
                    entries += 1;
                    if !std::mem::replace(&mut seen[point as usize], true) {
                        self.reached.push(point);
                    }
                }
                self.offset[kept] = self.offset[s];
                kept += 1;
                self.start[kept] = entries as u32;
            }
            from = to;
        }
        self.start.truncate(kept + 1);
        self.points.truncate(entries);
        self.weights.truncate(entries);
        self.offset.truncate(kept);
        self.finish(seen);
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.offset.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.offset.is_empty()
    }

    /// The points any sample follows.
    pub fn reached(&self) -> &[u32] {
        &self.reached
    }

    /// The points sample s follows.
    pub fn points_of(&self, s: usize) -> &[u32] {
        &self.points[self.start[s] as usize..self.start[s + 1] as usize]
    }

    /// Sample s's row: (point, weight).
    pub fn row(&self, s: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let (a, b) = (self.start[s] as usize, self.start[s + 1] as usize);
        self.points[a..b]
            .iter()
            .zip(&self.weights[a..b])
            .map(|(&k, &w)| (k as usize, w))
    }

    /// Sample s's position with the points at `p`.
    pub fn position(&self, s: usize, p: &[Vec3]) -> Vec3 {
        self.row(s).fold(self.offset[s], |x, (k, w)| x + p[k] * w)
    }

    /// How far sample s moves when the points move by `dx`.
    pub fn moved(&self, s: usize, dx: &[Vec3]) -> Vec3 {
        self.row(s).fold(Vec3::zeros(), |m, (k, w)| m + dx[k] * w)
    }

    /// Adds force `f` on sample s to the points it follows.
    pub fn spread(&self, s: usize, f: Vec3, out: &mut [Vec3]) {
        for (k, w) in self.row(s) {
            out[k] += f * w;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sample follows its points exactly as far as its row says, and a force on it
    /// reaches them in the same proportions (the transpose).
    #[test]
    fn a_sample_follows_and_spreads_by_its_row() {
        let rest = [Vec3::zeros(), Vec3::new(0.01, 0.0, 0.0)];
        let row = [(0u32, 0.25), (1u32, 0.75)];
        let rows = EmbeddedRows::new(
            [(&row[..], Vec3::new(0.0075, 0.001, 0.0))].into_iter(),
            &rest,
        );
        assert_eq!(rows.reached(), &[0, 1]);
        let shift = Vec3::new(1e-3, 0.0, 0.0);
        let p = [rest[0], rest[1] + shift];
        let x = rows.position(0, &p);
        assert!((x - Vec3::new(0.0075 + 0.75e-3, 0.001, 0.0)).norm() < 1e-15);
        let mut out = [Vec3::zeros(); 2];
        rows.spread(0, Vec3::new(0.0, 2.0, 0.0), &mut out);
        assert_eq!(out, [Vec3::new(0.0, 0.5, 0.0), Vec3::new(0.0, 1.5, 0.0)]);
    }

    /// Retaining keeps the kept samples' rows and places exactly, and what they reach.
    #[test]
    fn retain_keeps_rows_and_reach() {
        let rest = [Vec3::zeros(), Vec3::x(), Vec3::y(), Vec3::z()];
        let rows = [
            vec![(0u32, 0.5), (1u32, 0.5)],
            vec![(2u32, 1.0)],
            vec![(3u32, 0.25), (1u32, 0.75)],
        ];
        let places = [
            Vec3::new(0.5, 0.0, 0.0),
            Vec3::y(),
            Vec3::new(0.7, 0.0, 0.3),
        ];
        let mut all = EmbeddedRows::new(rows.iter().map(|r| &r[..]).zip(places), &rest);
        let p: Vec<Vec3> = rest.iter().map(|x| x * 2.0).collect();
        let third = all.position(2, &p);
        let mut seen = vec![false; 4];
        all.retain(&[true, false, true], &mut seen);
        assert_eq!(all.len(), 2);
        assert_eq!(all.reached(), &[0, 1, 3]);
        assert_eq!(all.position(1, &p), third);
        assert!(seen.iter().all(|&s| !s));
    }
}
