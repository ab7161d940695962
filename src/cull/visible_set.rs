//! The answer of a cull: a set of object ids, kept so that building it
//! costs little more than pushing ids.

/// The ids a method found possibly visible; sorted ascending once finished.
///
/// Membership is kept in a bitset beside the ids, so an id pushed twice is
/// stored once and [`VisibleSet::contains`] answers in O(1): a method can
/// skip the tests of an object that another kd leaf already accepted (the
/// ground of a city lies in most leaves). Finishing a large set reads the
/// ids back off the bitset in order instead of sorting them: O(ids + max
/// id / 64), where sorting a street view of a 10k city was most of a
/// frame's cost.
///
/// A method that estimates screen areas (the horizon's LOD option) adds
/// each id with [`VisibleSet::push_with_area`]; then [`VisibleSet::areas`]
/// holds one bound per id, in the same order.
#[derive(Clone, Debug, Default)]
pub struct VisibleSet {
    /// Each id once, in the order first pushed; ascending once finished.
    ids: Vec<u32>,
    /// Bit `id` is set for each id in `ids`; grows to the largest id seen
    /// and is kept (all zero) across [`VisibleSet::clear`].
    members: Vec<u64>,
    /// Pixel bounds as pushed, repeats included until finished.
    areas: Vec<(u32, f64)>,
}

impl PartialEq for VisibleSet {
    fn eq(&self, other: &Self) -> bool {
        // `members` is derived from `ids`; its length is history.
        self.ids == other.ids && self.areas == other.areas
    }
}

impl VisibleSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Empties the set, keeping its allocations for the next frame.
    pub fn clear(&mut self) {
        if self.ids.len() * 4 < self.members.len() {
            for &id in &self.ids {
                self.members[id as usize >> 6] = 0;
            }
        } else {
            self.members.fill(0);
        }
        self.ids.clear();
        self.areas.clear();
    }

    /// Whether `id` was pushed.
    #[inline]
    pub fn contains(&self, id: u32) -> bool {
        self.members
            .get(id as usize >> 6)
            .is_some_and(|w| w & (1 << (id & 63)) != 0)
    }

    /// Adds an id; a repeat changes nothing.
    #[inline]
    pub fn push(&mut self, id: u32) {
        let word = id as usize >> 6;
        if word >= self.members.len() {
            self.members.resize(word + 1, 0);
        }
        let bit = 1u64 << (id & 63);
        if self.members[word] & bit == 0 {
            self.members[word] |= bit;
            self.ids.push(id);
        }
    }

    /// Adds an id with an upper bound of the pixels it covers (of repeats,
    /// the largest bound is kept).
    pub fn push_with_area(&mut self, id: u32, pixels: f64) {
        self.push(id);
        self.areas.push((id, pixels));
    }

    /// Adds ids; repeats change nothing.
    pub fn extend_from_slice(&mut self, ids: &[u32]) {
        // Whole subtrees of a kd-tree come here, many of their ids repeats:
        // write every id and advance past the new ones only, so a repeat
        // costs no mispredicted branch (growing is rare and predicted).
        let mut len = self.ids.len();
        self.ids.resize(len + ids.len(), 0);
        for &id in ids {
            let w = id as usize >> 6;
            if w >= self.members.len() {
                self.members.resize(w + 1, 0);
            }
            let word = &mut self.members[w];
            let bit = 1u64 << (id & 63);
            let new = *word & bit == 0;
            *word |= bit;
            self.ids[len] = id;
            len += usize::from(new);
        }
        self.ids.truncate(len);
    }

    /// Keeps only the ids `keep` accepts (aggressive methods drop objects this way).
    pub fn retain(&mut self, mut keep: impl FnMut(&u32) -> bool) {
        let members = &mut self.members;
        self.ids.retain(|id| {
            let kept = keep(id);
            if !kept {
                members[*id as usize >> 6] &= !(1 << (id & 63));
            }
            kept
        });
        let members = &self.members;
        self.areas
            .retain(|(id, _)| members[*id as usize >> 6] & (1 << (id & 63)) != 0);
    }

    /// Whether ids were pushed with pixel bounds ([`VisibleSet::push_with_area`]).
    pub fn has_areas(&self) -> bool {
        !self.areas.is_empty()
    }

    /// Sorts the ids ascending.
    pub fn finish(&mut self) {
        // Reading the bitset costs a word per 64 ids of range; sorting,
        // about log2(n) steps per id. Read it when that is cheaper.
        if self.ids.len() * 8 >= self.members.len() {
            self.ids.clear();
            for (w, &word) in self.members.iter().enumerate() {
                let mut bits = word;
                while bits != 0 {
                    self.ids.push(((w as u32) << 6) | bits.trailing_zeros());
                    bits &= bits - 1;
                }
            }
        } else {
            self.ids.sort_unstable();
        }
        if !self.areas.is_empty() {
            // One bound per id: the largest of its repeats.
            self.areas
                .sort_unstable_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)));
            self.areas.dedup_by_key(|a| a.0);
            debug_assert_eq!(self.areas.len(), self.ids.len());
        }
    }

    /// Pixel bounds, one per id in [`VisibleSet::ids`] order, when the
    /// method gave them (finished sets only).
    pub fn areas(&self) -> Option<Vec<f64>> {
        (!self.areas.is_empty() && self.areas.len() == self.ids.len())
            .then(|| self.areas.iter().map(|a| a.1).collect())
    }

    /// The ids (sorted once finished).
    pub fn ids(&self) -> &[u32] {
        &self.ids
    }

    /// Bytes its buffers hold on the heap.
    pub fn heap_bytes(&self) -> usize {
        self.ids.capacity() * std::mem::size_of::<u32>()
            + self.members.capacity() * std::mem::size_of::<u64>()
            + self.areas.capacity() * std::mem::size_of::<(u32, f64)>()
    }

    /// How many ids.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use proptest::prelude::*;

    use super::VisibleSet;

    proptest! {
        /// Frames of pushes with repeats, retains and clears in between
        /// give the sorted distinct ids, whichever way `finish` reads them:
        /// dense frames (ids under 5000) read the bitset, sparse ones (ids
        /// spread to a million) are sorted.
        #[test]
        fn a_set_is_its_distinct_ids_sorted(
            frames in prop::collection::vec(
                (prop::collection::vec(0u32..5000, 0..400), 0u32..5000, any::<bool>(), any::<bool>()),
                1..6,
            )
        ) {
            let mut set = VisibleSet::new();
            for (pushed, cut, retain, sparse) in frames {
                let spread = if sparse { 200 } else { 1 };
                let pushed: Vec<u32> = pushed.iter().map(|id| id * spread).collect();
                let cut = cut * spread;
                set.clear();
                let mut expected: BTreeSet<u32> = BTreeSet::new();
                // Alternately one by one and as slices, as kd subtrees come.
                for (i, chunk) in pushed.chunks(7).enumerate() {
                    if i % 2 == 0 {
                        set.extend_from_slice(chunk);
                    } else {
                        chunk.iter().for_each(|&id| set.push(id));
                    }
                }
                expected.extend(pushed.iter().copied());
                if retain {
                    set.retain(|&id| id < cut);
                    expected.retain(|&id| id < cut);
                }
                for id in (0..5000).chain(pushed.iter().flat_map(|&id| [id, id + 1])) {
                    prop_assert_eq!(set.contains(id), expected.contains(&id));
                }
                set.finish();
                let want: Vec<u32> = expected.into_iter().collect();
                prop_assert_eq!(set.ids(), &want[..]);
            }
        }
    }

    #[test]
    fn areas_keep_the_largest_bound_of_repeats() {
        let mut set = VisibleSet::new();
        set.push_with_area(9, 1.0);
        set.push_with_area(2, 5.0);
        set.push_with_area(9, 3.0);
        set.finish();
        assert_eq!(set.ids(), &[2, 9]);
        assert_eq!(set.areas(), Some(vec![5.0, 3.0]));
        set.clear();
        assert!(set.is_empty() && !set.contains(9) && set.areas().is_none());
    }

    #[test]
    fn a_dense_set_and_a_sparse_one_finish_alike() {
        // 3000 ids under 4096 read off the bitset; 3 ids under 1e6 are sorted.
        let mut dense = VisibleSet::new();
        for id in (0..3000u32).rev() {
            dense.push(id);
            dense.push(id);
        }
        dense.finish();
        assert!(dense.ids().iter().copied().eq(0..3000));
        let mut sparse = VisibleSet::new();
        for id in [999_999, 7, 500_000, 7] {
            sparse.push(id);
        }
        sparse.finish();
        assert_eq!(sparse.ids(), &[7, 500_000, 999_999]);
    }
}
