//! Frame deltas: what a session sends after the first frame.
//!
//! [`diff`] turns two ascending id sets into the ids added and removed
//! (O(n), both sets sorted); a client applies `removed` then `added` to the
//! set it holds. [`IdSet`] keeps a past frame's set in its `x-pvs` encoding
//! (a quarter of the memory of `u32`s or less), so a server can keep a few
//! per session and answer against an older `base`.

use crate::xpvs;

/// A sorted id set kept in its encoded form (a session's past frames).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct IdSet {
    bytes: Box<[u8]>,
}

impl IdSet {
    /// Encodes strictly ascending `ids`.
    pub fn new(ids: &[u32]) -> IdSet {
        let mut out = Vec::with_capacity(1 + ids.len() * 2);
        xpvs::put_ids(&mut out, ids);
        IdSet {
            bytes: out.into_boxed_slice(),
        }
    }

    /// The ids, into `out` (cleared first).
    pub fn decode_into(&self, out: &mut Vec<u32>) {
        out.clear();
        xpvs::ids_into(&self.bytes, out).expect("an IdSet holds what IdSet::new encoded");
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.bytes.len()
    }
}

/// The changes from ascending `old` to ascending `new`: ids `new` adds and
/// ids it removes, both ascending.
pub fn diff(old: &[u32], new: &[u32], added: &mut Vec<u32>, removed: &mut Vec<u32>) {
    added.clear();
    removed.clear();
    let (mut i, mut j) = (0, 0);
    while i < old.len() && j < new.len() {
        match old[i].cmp(&new[j]) {
            std::cmp::Ordering::Less => {
                removed.push(old[i]);
                i += 1;
            }
            std::cmp::Ordering::Greater => {
                added.push(new[j]);
                j += 1;
            }
            std::cmp::Ordering::Equal => {
                i += 1;
                j += 1;
            }
        }
    }
    removed.extend_from_slice(&old[i..]);
    added.extend_from_slice(&new[j..]);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diff_and_idset() {
        let (mut a, mut r) = (vec![], vec![]);
        diff(&[1, 2, 5, 9], &[2, 3, 9, 11], &mut a, &mut r);
        assert_eq!((a.as_slice(), r.as_slice()), (&[3, 11][..], &[1, 5][..]));
        let set = IdSet::new(&[4, 8, 1000]);
        let mut out = vec![7];
        set.decode_into(&mut out);
        assert_eq!(out, [4, 8, 1000]);
    }
}
