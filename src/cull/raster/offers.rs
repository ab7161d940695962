//! What a `raster` frame has offered to draw and not drawn yet: visible
//! objects, and the clusters of those a test has split, found by the
//! screen cell a test needs covered. Each offer is listed in the bins of
//! [`BIN`]×[`BIN`] cells its rectangle meets (one covering more than [`WIDE`] bins
//! in a list every lookup reads), so a lookup reads the offers near one
//! cell, not all of them: a walk through a scene of hundreds of visible
//! objects makes thousands of lookups a frame.

use crate::cull::depth::CellRect;
use crate::geom::PlaneMask;

/// A visible object, or one of its clusters, offered for drawing: drawn
/// only when a box it may hide is tested, so that what hides nothing costs
/// nothing.
#[derive(Clone, Copy, Debug)]
pub struct Offer {
    pub object: u32,
    /// The cluster's index among the object's, or [`WHOLE`].
    pub cluster: u32,
    /// A cluster's pixels per scene unit at its nearest depth (unused for
    /// a whole object).
    pub scale: f64,
    /// The frustum planes its box crosses.
    pub crossed: PlaneMask,
    /// Which side of its surfaces faces away from the eye (negative: the
    /// side its normals point to is out; zero: both are drawn).
    pub away: f64,
    /// Whether the eye is outside the object's box and the box beyond
    /// the near plane: its proxies may be drawn.
    pub outside: bool,
    /// The cells its box may cover, and the greatest inverse depth any
    /// of its surfaces can write.
    pub rect: CellRect,
    pub w: f32,
    /// How far a cluster's box is from the eye: clusters are drawn
    /// nearest first (unused for a whole object, which is split first).
    pub distance: f64,
}

/// [`Offer::cluster`] of an object not yet split into its clusters.
pub const WHOLE: u32 = u32::MAX;

/// Cells per bin side.
const BIN: usize = 16;

/// An offer meeting more bins than this is read by every lookup instead.
const WIDE: usize = 16;

/// What a lookup reads of an offer, kept apart from the rest so that a
/// bin's offers are read from a few cache lines: its rectangle and its
/// inverse depth, `-∞` once taken (drawn or split).
#[derive(Clone, Copy, Debug)]
struct Key {
    rect: [u32; 4],
    w: f32,
}

/// The offers of one frame; see the module doc.
#[derive(Debug, Default)]
pub struct Offers {
    /// Every offer of the frame.
    all: Vec<Offer>,
    keys: Vec<Key>,
    /// Per bin, row by row, the offers whose rectangle meets it.
    bins: Vec<Vec<u32>>,
    across: usize,
    wide: Vec<u32>,
    /// Offers not taken.
    live: usize,
}

impl Offers {
    /// Empties it for a frame of `cols × rows` cells.
    pub fn reset(&mut self, (cols, rows): (usize, usize)) {
        self.all.clear();
        self.keys.clear();
        self.wide.clear();
        self.live = 0;
        self.across = cols.div_ceil(BIN);
        let count = self.across * rows.div_ceil(BIN);
        for bin in self.bins.iter_mut().take(count) {
            bin.clear();
        }
        self.bins.resize_with(count, Vec::new);
    }

    /// Whether every offer is taken.
    pub fn is_empty(&self) -> bool {
        self.live == 0
    }

    /// Adds `offer`.
    pub fn add(&mut self, offer: Offer) {
        let i = self.all.len() as u32;
        let r = offer.rect;
        let (bx0, bx1, by0, by1) = (r.x0 / BIN, r.x1 / BIN, r.y0 / BIN, r.y1 / BIN);
        if (bx1 - bx0 + 1) * (by1 - by0 + 1) > WIDE {
            self.wide.push(i);
        } else {
            for by in by0..=by1 {
                for bx in bx0..=bx1 {
                    self.bins[by * self.across + bx].push(i);
                }
            }
        }
        self.all.push(offer);
        self.keys.push(Key {
            rect: [r.x0, r.y0, r.x1, r.y1].map(|c| c as u32),
            w: offer.w,
        });
        self.live += 1;
    }

    /// Into `out`, the offers not taken whose rectangle holds cell `(x, y)`
    /// and that may be nearer than inverse depth `w`. Taken offers met on
    /// the way leave the lists.
    pub fn covering(&mut self, (x, y): (usize, usize), w: f32, out: &mut Vec<u32>) {
        out.clear();
        let (keys, x, y) = (&self.keys, x as u32, y as u32);
        let mut look = |i: &u32| {
            let k = keys[*i as usize];
            let [x0, y0, x1, y1] = k.rect;
            if k.w >= w && x0 <= x && x <= x1 && y0 <= y && y <= y1 {
                out.push(*i);
            }
            k.w != f32::NEG_INFINITY
        };
        self.bins[(y as usize / BIN) * self.across + x as usize / BIN].retain(&mut look);
        self.wide.retain(&mut look);
    }

    /// Offer `i`.
    pub fn get(&self, i: u32) -> &Offer {
        &self.all[i as usize]
    }

    /// Takes offer `i` (once).
    pub fn take(&mut self, i: u32) -> Offer {
        let key = &mut self.keys[i as usize];
        debug_assert!(key.w != f32::NEG_INFINITY, "an offer is taken once");
        key.w = f32::NEG_INFINITY;
        self.live -= 1;
        self.all[i as usize]
    }

    /// Bytes held on the heap.
    pub fn heap_bytes(&self) -> usize {
        self.all.capacity() * std::mem::size_of::<Offer>()
            + self.keys.capacity() * std::mem::size_of::<Key>()
            + self.bins.iter().map(|b| b.capacity() * 4 + 24).sum::<usize>()
            + self.wide.capacity() * 4
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn offer(x0: usize, y0: usize, x1: usize, y1: usize, w: f32) -> Offer {
        Offer {
            object: 0,
            cluster: WHOLE,
            scale: 1.0,
            crossed: 0,
            away: 0.0,
            outside: false,
            rect: CellRect { x0, y0, x1, y1 },
            w,
            distance: 0.0,
        }
    }

    #[test]
    fn a_lookup_finds_the_offers_over_a_cell_until_taken() {
        let mut offers = Offers::default();
        offers.reset((100, 60));
        offers.add(offer(0, 0, 3, 3, 1.0)); // one bin
        offers.add(offer(5, 5, 40, 20, 2.0)); // several bins
        offers.add(offer(0, 0, 99, 59, 3.0)); // wide
        offers.add(offer(30, 10, 30, 10, 0.5)); // farther than asked below
        let mut out = Vec::new();
        offers.covering((2, 2), 0.9, &mut out);
        assert_eq!(out, [0, 2]);
        offers.covering((30, 10), 0.9, &mut out);
        assert_eq!(out, [1, 2]);
        offers.covering((30, 10), 0.4, &mut out);
        assert_eq!(out, [1, 3, 2]);
        offers.covering((99, 59), 0.0, &mut out);
        assert_eq!(out, [2]);
        assert_eq!(offers.take(2).w, 3.0);
        offers.covering((99, 59), 0.0, &mut out);
        assert!(out.is_empty());
        for i in [0, 1, 3] {
            offers.take(i);
        }
        assert!(offers.is_empty());
        // A new frame forgets them, at another size too.
        offers.reset((20, 20));
        offers.covering((19, 19), 0.0, &mut out);
        assert!(out.is_empty() && offers.is_empty());
    }
}
