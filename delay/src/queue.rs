//! Messages held until their release time.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

#[derive(Debug)]
struct Entry<T> {
    release_time_ns: u64,
    order: u64,
    item: T,
}

impl<T> PartialEq for Entry<T> {
    fn eq(&self, other: &Self) -> bool {
        (self.release_time_ns, self.order) == (other.release_time_ns, other.order)
    }
}
impl<T> Eq for Entry<T> {}
impl<T> PartialOrd for Entry<T> {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl<T> Ord for Entry<T> {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.release_time_ns, self.order).cmp(&(other.release_time_ns, other.order))
    }
}

/// A priority queue of held messages, earliest release first; messages with the same release
/// time come out in the order they were pushed (so FIFO releases stay in send order).
#[derive(Debug)]
pub struct ReleaseQueue<T> {
    heap: BinaryHeap<Reverse<Entry<T>>>,
    pushed: u64,
}

impl<T> Default for ReleaseQueue<T> {
    fn default() -> Self {
        Self { heap: BinaryHeap::new(), pushed: 0 }
    }
}

impl<T> ReleaseQueue<T> {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn push(&mut self, release_time_ns: u64, item: T) {
        let order = self.pushed;
        self.pushed += 1;
        self.heap.push(Reverse(Entry { release_time_ns, order, item }));
    }

    /// Release time of the next message, if any.
    pub fn next_release_ns(&self) -> Option<u64> {
        self.heap.peek().map(|Reverse(e)| e.release_time_ns)
    }

    /// The next message whose release time is at or before `now_ns`.
    pub fn pop_due(&mut self, now_ns: u64) -> Option<(u64, T)> {
        if self.next_release_ns()? <= now_ns { self.pop() } else { None }
    }

    /// The next message, whatever its release time.
    pub fn pop(&mut self) -> Option<(u64, T)> {
        self.heap.pop().map(|Reverse(e)| (e.release_time_ns, e.item))
    }

    /// Every held message, in release order (used to report them dropped).
    pub fn drain(&mut self) -> Vec<(u64, T)> {
        let mut out = Vec::with_capacity(self.heap.len());
        while let Some(x) = self.pop() {
            out.push(x);
        }
        out
    }

    /// The held messages with their release times, in no particular order.
    pub fn iter(&self) -> impl Iterator<Item = (u64, &T)> {
        self.heap.iter().map(|Reverse(e)| (e.release_time_ns, &e.item))
    }

    pub fn len(&self) -> usize {
        self.heap.len()
    }

    pub fn is_empty(&self) -> bool {
        self.heap.is_empty()
    }
}

#[cfg(test)]
mod tests;
