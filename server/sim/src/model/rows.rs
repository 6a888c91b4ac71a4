//! Compressed rows: entries grouped by row, `items[start[i]..start[i + 1]]` for row i. The
//! rest grid's cells (`neighbours::RestGrid`) and the surface's adjacency lists
//! (`pipeline::surface`) are filled this way, in place, so that a re-cut landing refills
//! them without allocating.

/// Entries grouped by row.
#[derive(Debug, Clone, Default)]
pub(crate) struct Rows {
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Rows {
    /// `n` rows from `pairs` (row, entry).
    pub fn build(n: usize, pairs: impl Iterator<Item = (u32, u32)> + Clone) -> Self {
        let mut rows = Self::default();
        rows.refill(n, pairs);
        rows
    }

    /// Room for `rows` rows and `items` entries, for [`Self::refill`] to fill without
    /// allocating.
    pub fn reserve(&mut self, rows: usize, items: usize) {
        self.start.reserve(rows + 1);
        self.items.reserve(items);
    }

    /// `n` rows from `pairs` (row, entry), in this value's buffers: no allocation while
    /// they have room. Within a row, entries keep the order of `pairs`.
    pub fn refill(&mut self, n: usize, pairs: impl Iterator<Item = (u32, u32)> + Clone) {
        let start = &mut self.start;
        start.clear();
        start.resize(n + 1, 0);
        for (a, _) in pairs.clone() {
            start[a as usize + 1] += 1;
        }
        for i in 1..=n {
            start[i] += start[i - 1];
        }
        self.items.clear();
        self.items.resize(start[n] as usize, 0);
        // Each row's start is its cursor while it fills; it then holds the next row's
        // start, and the starts are shifted back by one row.
        for (a, b) in pairs {
            let cursor = &mut start[a as usize];
            self.items[*cursor as usize] = b;
            *cursor += 1;
        }
        start.copy_within(0..n, 1);
        start[0] = 0;
    }

    /// Row `i`'s entries.
    #[inline]
    pub fn of(&self, i: usize) -> &[u32] {
        &self.items[self.start[i] as usize..self.start[i + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows refilled in place give what a fresh build gives, entries in input order.
    #[test]
    fn refilled_rows_are_the_built_ones() {
        let pairs = [(2u32, 7u32), (0, 1), (2, 3), (1, 4), (0, 5)];
        let built = Rows::build(3, pairs.iter().copied());
        assert_eq!(built.of(0), &[1, 5]);
        assert_eq!(built.of(1), &[4]);
        assert_eq!(built.of(2), &[7, 3]);
        let mut refilled = Rows::build(5, [(4u32, 9u32)].into_iter());
        refilled.refill(3, pairs.iter().copied());
        for i in 0..3 {
            assert_eq!(refilled.of(i), built.of(i));
        }
    }
}
