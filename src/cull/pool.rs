//! Scratch buffers lent to one cull at a time, for methods whose buffers
//! are large next to what a client must keep between frames.
//!
//! A method that kept such buffers per client would hold one set per
//! session (most of them idle); one that made them per cull would
//! allocate, and fault in, a whole set each frame. A pool holds the sets
//! no cull is using, the last given back on top (the warmest in the
//! cache), at most `capacity` of them: as many as culls ran at once, up
//! to a busy server's concurrency; more are freed when given back.

use std::sync::{Mutex, PoisonError};

/// Spare buffers of type `T` (module docs).
pub struct BufferPool<T> {
    spare: Mutex<Vec<T>>,
    capacity: usize,
}

impl<T> BufferPool<T> {
    /// An empty pool that keeps at most `capacity` spares.
    pub fn new(capacity: usize) -> Self {
        BufferPool {
            spare: Mutex::new(Vec::new()),
            capacity,
        }
    }

    /// The spare given back last, if any. A std mutex: it is held for a
    /// pop or a push, never across an await; a panic while it was held
    /// leaves the list as it was, so poisoning is ignored.
    pub fn take(&self) -> Option<T> {
        self.spare
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .pop()
    }

    /// Gives `buffers` back: kept when fewer than `capacity` spares are,
    /// else freed.
    pub fn put(&self, buffers: T) {
        let mut spare = self.spare.lock().unwrap_or_else(PoisonError::into_inner);
        if spare.len() < self.capacity {
            spare.push(buffers);
        }
    }

    /// How many spares it holds.
    pub fn len(&self) -> usize {
        self.spare
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len()
    }

    /// Whether it holds none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_last_given_back_is_lent_first_and_extras_are_freed() {
        let pool = BufferPool::new(2);
        assert_eq!(pool.take(), None::<u32>);
        for b in [1, 2, 3] {
            pool.put(b);
        }
        assert_eq!(pool.len(), 2);
        assert_eq!(pool.take(), Some(2));
        assert_eq!(pool.take(), Some(1));
        assert!(pool.is_empty());
    }
}
