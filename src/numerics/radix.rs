//! A stable least-significant-digit radix sort of (key, value) pairs by key: the order of
//! `sort_by_key` (stable), in O(N) passes of 11 bits of the largest key each, instead of a
//! comparison sort's O(N log N).
//!
//! Input: pairs whose keys are small integers (grid cells numbered densely, say). Output: the
//! same pairs ordered by key, pairs of equal key in their input order. Sequential and
//! deterministic; below [`RADIX_MIN`] pairs it is the standard library's stable sort.

/// Bits of the key sorted by each pass.
const DIGIT_BITS: u32 = 11;
/// Fewer pairs than this are sorted by comparison: the counters would cost more than the sort.
const RADIX_MIN: usize = 4096;

/// Sorts `items` by key, stably (pairs of equal key keep their order).
pub(crate) fn sort_pairs_by_key(items: &mut Vec<(u64, u32)>) {
    if items.len() < RADIX_MIN {
        items.sort_by_key(|&(k, _)| k);
        return;
    }
    let max = items.iter().map(|&(k, _)| k).max().unwrap_or(0);
    let bits = u64::BITS - max.leading_zeros();
    let radix = 1usize << DIGIT_BITS;
    let mut counts = vec![0usize; radix];
    let mut other = vec![(0u64, 0u32); items.len()];
    let mut shift = 0;
    while shift < bits {
        counts.fill(0);
        let digit = |k: u64| ((k >> shift) as usize) & (radix - 1);
        for &(k, _) in items.iter() {
            counts[digit(k)] += 1;
        }
        let mut start = 0;
        for c in &mut counts {
            (*c, start) = (start, start + *c);
        }
        for &item in items.iter() {
            let d = digit(item.0);
            other[counts[d]] = item;
            counts[d] += 1;
        }
        std::mem::swap(items, &mut other);
        shift += DIGIT_BITS;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::Lcg;

    #[test]
    fn equals_the_stable_comparison_sort_on_keys_of_every_width() {
        let mut rng = Lcg::new(7);
        for (n, bits) in [(10, 60), (5000, 3), (20_000, 21), (20_000, 40), (9000, 64)] {
            let items: Vec<(u64, u32)> = (0..n)
                .map(|i| {
                    let r = (rng.bits31() << 33) ^ (rng.bits31() << 2) ^ rng.bits31();
                    (if bits == 64 { r } else { r & ((1 << bits) - 1) }, i)
                })
                .collect();
            let mut expected = items.clone();
            expected.sort_by_key(|&(k, _)| k);
            let mut sorted = items;
            sort_pairs_by_key(&mut sorted);
            assert_eq!(sorted, expected, "{n} pairs, {bits}-bit keys");
        }
    }
}
