//! How the evaluation walks the box: spans and runs of chunks, the split into halves, and
//! the halves run one after the other or on two threads.

use super::*;

/// Runs `a` and `b`, one after the other or as a `rayon::join`.
pub(super) fn both<A: Send, B: Send>(
    threads: Threads,
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    threads.both(a, b)
}

/// Each field cut at chunk `at`: the first parts, then the second.
pub(super) fn split_each<T, const N: usize>(
    fields: &mut [Vec<T>; N],
    at: usize,
) -> ([&mut [T]; N], [&mut [T]; N]) {
    let mut parts = fields.each_mut().map(|f| {
        let (a, b) = f.split_at_mut(at);
        (Some(a), Some(b))
    });
    let first = std::array::from_fn(|i| parts[i].0.take().expect("taken once"));
    let second = std::array::from_fn(|i| parts[i].1.take().expect("taken once"));
    (first, second)
}

/// The spans clipped to the chunks `range`, each as (first chunk, length, index of its first
/// chunk's terms).
pub(super) fn spans_within(
    spans: &[Span],
    range: std::ops::Range<usize>,
) -> impl Iterator<Item = (usize, usize, usize)> + '_ {
    spans.iter().filter_map(move |s| {
        let (first, end) = (s.chunk as usize, (s.chunk + s.len) as usize);
        let lo = first.max(range.start);
        let hi = end.min(range.end);
        (lo < hi).then(|| (lo, hi - lo, s.terms as usize + lo - first))
    })
}

/// Runs of consecutive chunks of a sorted list, with their terms, joined across gaps of up
/// to [`JOIN_GAP_CHUNKS`] chunks within one span (the lanes of a gap chunk have no stress in
/// the evaluation, and what is gathered there is not read): a short run costs its set-up and
/// the plane sums of a chunk on either side.
pub(super) fn runs_of(stencil: &LatticeStencil, chunks: &[u32], runs: &mut Vec<Span>) {
    runs.clear();
    for &c in chunks {
        let terms = stencil.terms_of_chunk(c as usize);
        match runs.last_mut() {
            Some(last)
                if c - (last.chunk + last.len) <= JOIN_GAP_CHUNKS as u32
                    && terms - last.terms == c - last.chunk =>
            {
                last.len = c + 1 - last.chunk;
            }
            _ => runs.push(Span {
                chunk: c,
                len: 1,
                terms,
            }),
        }
    }
}

/// The chunk that splits `runs` into halves of about the same number of chunks.
pub(super) fn halfway(runs: &[Span], end: usize) -> usize {
    let total: usize = runs.iter().map(|s| s.len as usize).sum();
    let mut left = total / 2;
    for s in runs {
        if (s.len as usize) > left {
            return s.chunk as usize + left;
        }
        left -= s.len as usize;
    }
    end
}
