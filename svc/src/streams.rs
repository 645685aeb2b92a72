//! Server streams that cannot exhaust a service: a cap on how many are open at once
//! ([`StreamSlots`], `RESOURCE_EXHAUSTED` beyond it), and a bounded per-subscriber buffer that
//! never makes its writer wait and drops its *oldest* item when full ([`drop_oldest`]).
//!
//! Why drop the oldest: a subscriber of state samples or telemetry wants the freshest state
//! when it reads again; a sample that sat in a queue while the reader was away is stale, and
//! a writer that waited for a slow reader would hold up the simulation or the other readers.
//! The writer gets the evicted item back, so the service can count and report it.

use std::collections::{HashMap, VecDeque};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::task::{Context, Poll, Waker};

use tokio::sync::Notify;
use tokio_stream::Stream;

/// Default of every service's `--max-streams`: server streams open at once. Each stream
/// costs a task, a buffer of at most its subscriber's bound, and the transport's buffers:
/// measured, 159-707 KiB of netem's memory per stream whose reader stopped, depending on the
/// reader's HTTP/2 window (BENCHMARKS.md, "netem's memory per idle stream"), so 64 of them
/// stay under 50 MB.
pub const DEFAULT_MAX_STREAMS: usize = 64;

/// The flag a `RESOURCE_EXHAUSTED` answer names.
pub const MAX_STREAMS_FLAG: &str = "--max-streams";
/// The flag a `RESOURCE_EXHAUSTED` answer names when one client holds its share.
pub const MAX_STREAMS_PER_CLIENT_FLAG: &str = "--max-streams-per-client";

/// The streams a service has open: at most `max` at once, and at most `per_client` of them
/// for one client ([`crate::connections::client_of`]), so that one client cannot take them
/// all. Cheap to clone (one shared count).
#[derive(Debug, Clone)]
pub struct StreamSlots {
    inner: Arc<Slots>,
}

#[derive(Debug)]
struct Slots {
    /// The service, as its binary is called (`plant`, `netem`, `controller`).
    service: &'static str,
    max: usize,
    per_client: usize,
    open: Mutex<Open>,
}

#[derive(Debug, Default)]
struct Open {
    total: usize,
    by_client: HashMap<String, usize>,
}

impl Slots {
    fn lock(&self) -> MutexGuard<'_, Open> {
        // Nothing here panics while holding the lock; a poisoned count is still a count.
        self.open.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// One open stream's slot; dropping it (with its stream) frees the slot.
#[derive(Debug)]
pub struct StreamSlot {
    inner: Arc<Slots>,
    client: String,
}

impl Drop for StreamSlot {
    fn drop(&mut self) {
        let mut open = self.inner.lock();
        open.total -= 1;
        if let Some(n) = open.by_client.get_mut(&self.client) {
            *n -= 1;
            if *n == 0 {
                open.by_client.remove(&self.client);
            }
        }
    }
}

impl StreamSlots {
    /// At most `max` streams open at once on `service`, `per_client` of them for one client
    /// (0 refuses every stream; services validate `max >= 1` in their configuration).
    pub fn new(service: &'static str, max: usize, per_client: usize) -> Self {
        Self { inner: Arc::new(Slots { service, max, per_client, open: Mutex::new(Open::default()) }) }
    }

    pub fn max(&self) -> usize {
        self.inner.max
    }

    /// Streams open right now.
    pub fn open(&self) -> usize {
        self.inner.lock().total
    }

    /// A slot for a new `what` stream of `request`'s client, or `RESOURCE_EXHAUSTED` naming
    /// the limit reached and the flag that raises it.
    pub fn acquire<T>(&self, request: &tonic::Request<T>, what: &str) -> Result<StreamSlot, tonic::Status> {
        self.acquire_for(crate::connections::client_of(request), what)
    }

    /// A slot for a new `what` stream of `client`, as [`StreamSlots::acquire`].
    pub fn acquire_for(&self, client: String, what: &str) -> Result<StreamSlot, tonic::Status> {
        let Slots { service, max, per_client, .. } = &*self.inner;
        let mut open = self.inner.lock();
        if open.total >= *max {
            let n = open.total;
            return Err(tonic::Status::resource_exhausted(format!(
                "{service}: {n} streams are open, the most it serves at once ({MAX_STREAMS_FLAG} {max}); \
                 this {what} stream is refused: close a stream, or start the {service} with a larger \
                 {MAX_STREAMS_FLAG}"
            )));
        }
        let mine = open.by_client.get(&client).copied().unwrap_or(0);
        if mine >= (*per_client).min(*max) {
            return Err(tonic::Status::resource_exhausted(format!(
                "{service}: {client} holds {mine} streams, the most one client may hold \
                 ({MAX_STREAMS_PER_CLIENT_FLAG} {per_client}); this {what} stream is refused: close \
                 a stream, or start the {service} with a larger {MAX_STREAMS_PER_CLIENT_FLAG}"
            )));
        }
        open.total += 1;
        *open.by_client.entry(client.clone()).or_insert(0) += 1;
        drop(open);
        Ok(StreamSlot { inner: self.inner.clone(), client })
    }

    /// `stream` holding a slot of `client` until it is dropped (when the client goes away or
    /// the stream ends), or `RESOURCE_EXHAUSTED` as [`StreamSlots::acquire`].
    pub fn guard<S>(&self, client: String, what: &str, stream: S) -> Result<Guarded<S>, tonic::Status> {
        Ok(Guarded { stream, _slot: self.acquire_for(client, what)? })
    }
}

/// A stream that holds a [`StreamSlot`] for as long as it lives.
#[derive(Debug)]
pub struct Guarded<S> {
    stream: S,
    _slot: StreamSlot,
}

impl<S> Guarded<S> {
    /// `stream` holding `slot` (acquired before the work of opening the stream was done).
    pub fn new(stream: S, slot: StreamSlot) -> Self {
        Self { stream, _slot: slot }
    }
}

impl<S: Stream + Unpin> Stream for Guarded<S> {
    type Item = S::Item;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<S::Item>> {
        Pin::new(&mut self.stream).poll_next(cx)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        self.stream.size_hint()
    }
}

/// A buffer of at most `capacity` items (at least 1) between writers that never wait and
/// one reader: when it is full, a push evicts the oldest item and returns it. Memory grows
/// with what is queued, up to `capacity` items.
pub fn drop_oldest<T>(capacity: usize) -> (Writer<T>, Reader<T>) {
    let ring = Arc::new(Ring {
        state: Mutex::new(State {
            items: VecDeque::new(),
            capacity: capacity.max(1),
            writers: 1,
            reader_gone: false,
            finished: false,
            waker: None,
        }),
        reader_gone: Notify::new(),
    });
    (Writer { ring: ring.clone() }, Reader { ring })
}

struct Ring<T> {
    state: Mutex<State<T>>,
    /// Wakes writers waiting in [`Writer::closed`].
    reader_gone: Notify,
}

struct State<T> {
    items: VecDeque<T>,
    capacity: usize,
    writers: usize,
    reader_gone: bool,
    /// A last item was pushed: later pushes are refused, the reader ends after it.
    finished: bool,
    waker: Option<Waker>,
}

impl<T> Ring<T> {
    fn lock(&self) -> MutexGuard<'_, State<T>> {
        // Nothing here panics while holding the lock; a poisoned queue is still a queue.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// What became of a pushed item.
#[derive(Debug, PartialEq, Eq)]
pub enum Pushed<T> {
    /// Queued, with room to spare or in the place of nothing.
    Queued,
    /// Queued; the buffer was full and this, its oldest item, was evicted.
    Evicted(T),
    /// Not queued: the reader is gone, or a last item was pushed before.
    Closed(T),
}

/// The writing end; clones share the buffer, and the reader ends when every writer is gone
/// and the buffer is empty.
pub struct Writer<T> {
    ring: Arc<Ring<T>>,
}

impl<T> Clone for Writer<T> {
    fn clone(&self) -> Self {
        self.ring.lock().writers += 1;
        Self { ring: self.ring.clone() }
    }
}

impl<T> Drop for Writer<T> {
    fn drop(&mut self) {
        let waker = {
            let mut s = self.ring.lock();
            s.writers -= 1;
            if s.writers == 0 { s.waker.take() } else { None }
        };
        if let Some(w) = waker {
            w.wake();
        }
    }
}

impl<T> Writer<T> {
    /// Queues `item` without waiting; see [`Pushed`].
    pub fn push(&self, item: T) -> Pushed<T> {
        self.push_inner(item, false)
    }

    /// Queues a last item (an end-of-stream status, say): pushes after it are refused, so it
    /// is never evicted, and the reader ends after reading it.
    pub fn push_last(&self, item: T) -> Pushed<T> {
        self.push_inner(item, true)
    }

    fn push_inner(&self, item: T, last: bool) -> Pushed<T> {
        let (pushed, waker) = {
            let mut s = self.ring.lock();
            if s.reader_gone || s.finished {
                return Pushed::Closed(item);
            }
            let evicted = if s.items.len() >= s.capacity { s.items.pop_front() } else { None };
            s.items.push_back(item);
            s.finished = last;
            (evicted.map_or(Pushed::Queued, Pushed::Evicted), s.waker.take())
        };
        if let Some(w) = waker {
            w.wake();
        }
        pushed
    }

    /// Whether the reader is gone (a push would be refused).
    pub fn is_closed(&self) -> bool {
        self.ring.lock().reader_gone
    }

    /// Resolves when the reader is gone.
    pub async fn closed(&self) {
        loop {
            let notified = self.ring.reader_gone.notified();
            if self.is_closed() {
                return;
            }
            notified.await;
        }
    }
}

/// The reading end: a [`Stream`] of the items in push order, the evicted ones missing. It
/// ends when every writer is gone (or after a last item) and the buffer is empty.
pub struct Reader<T> {
    ring: Arc<Ring<T>>,
}

impl<T> Reader<T> {
    /// The next item, `Pending` until there is one, `None` at the end.
    pub fn poll_recv(&mut self, cx: &mut Context<'_>) -> Poll<Option<T>> {
        let mut s = self.ring.lock();
        if let Some(item) = s.items.pop_front() {
            return Poll::Ready(Some(item));
        }
        if s.writers == 0 || s.finished {
            return Poll::Ready(None);
        }
        s.waker = Some(cx.waker().clone());
        Poll::Pending
    }

    /// Items queued right now.
    pub fn len(&self) -> usize {
        self.ring.lock().items.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Stops reading: later pushes are refused, and the items still queued are returned (so
    /// that the service can account for them).
    pub fn close(&mut self) -> Vec<T> {
        let left = {
            let mut s = self.ring.lock();
            s.reader_gone = true;
            s.items.drain(..).collect()
        };
        self.ring.reader_gone.notify_waiters();
        left
    }
}

impl<T> Drop for Reader<T> {
    fn drop(&mut self) {
        self.close();
    }
}

impl<T> Stream for Reader<T> {
    type Item = T;

    fn poll_next(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<T>> {
        self.get_mut().poll_recv(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio_stream::StreamExt;

    #[tokio::test]
    async fn a_full_buffer_evicts_its_oldest_so_a_late_reader_gets_the_newest() {
        let (w, mut r) = drop_oldest::<u32>(4);
        let evicted: Vec<u32> = (0..10)
            .filter_map(|k| match w.push(k) {
                Pushed::Queued => None,
                Pushed::Evicted(old) => Some(old),
                Pushed::Closed(_) => panic!("the reader is there"),
            })
            .collect();
        assert_eq!(evicted, vec![0, 1, 2, 3, 4, 5]);
        assert_eq!(r.len(), 4, "never more than the capacity");
        drop(w);
        let got: Vec<u32> = (&mut r).collect().await;
        assert_eq!(got, vec![6, 7, 8, 9]);
    }

    #[tokio::test]
    async fn a_last_item_ends_the_stream_and_is_never_evicted() {
        let (w, r) = drop_oldest::<&str>(2);
        let other = w.clone();
        assert_eq!(w.push("a"), Pushed::Queued);
        assert_eq!(w.push("b"), Pushed::Queued);
        assert_eq!(w.push_last("end"), Pushed::Evicted("a"));
        assert_eq!(other.push("late"), Pushed::Closed("late"));
        // Writers still alive do not keep the stream open past its last item.
        let got: Vec<&str> = r.collect().await;
        assert_eq!(got, vec!["b", "end"]);
    }

    #[tokio::test]
    async fn a_gone_reader_refuses_pushes_returns_what_was_queued_and_wakes_writers() {
        let (w, mut r) = drop_oldest::<u32>(8);
        assert_eq!(w.push(1), Pushed::Queued);
        let waiting = tokio::spawn({
            let w = w.clone();
            async move { w.closed().await }
        });
        assert_eq!(r.close(), vec![1]);
        assert!(w.is_closed());
        assert_eq!(w.push(2), Pushed::Closed(2));
        waiting.await.expect("closed() resolves once the reader is gone");
    }

    #[tokio::test]
    async fn the_reader_waits_for_a_push_and_ends_when_the_writers_are_gone() {
        let (w, mut r) = drop_oldest::<u32>(1);
        let reader = tokio::spawn(async move {
            let first = r.next().await;
            let end = r.next().await;
            (first, end)
        });
        tokio::task::yield_now().await;
        assert_eq!(w.push(7), Pushed::Queued);
        drop(w);
        assert_eq!(reader.await.expect("reader"), (Some(7), None));
    }

    #[tokio::test]
    async fn slots_refuse_beyond_the_cap_naming_it_and_the_flag_and_free_on_drop() {
        let slots = StreamSlots::new("netem", 2, 16);
        let a = slots.acquire_for("address 127.0.0.1".into(), "StreamState").expect("first");
        let _b = slots
            .guard("address 127.0.0.2".into(), "StreamState", tokio_stream::empty::<()>())
            .expect("second");
        let refused = slots.acquire_for("address 127.0.0.3".into(), "StreamDeliveries").expect_err("third");
        assert_eq!(refused.code(), tonic::Code::ResourceExhausted);
        for part in ["netem", "--max-streams 2", "StreamDeliveries"] {
            assert!(refused.message().contains(part), "{part:?} not in {:?}", refused.message());
        }
        drop(a);
        assert_eq!(slots.open(), 1);
        slots.acquire_for("address 127.0.0.3".into(), "StreamState").expect("a freed slot is taken again");
    }

    #[tokio::test]
    async fn one_client_holds_at_most_its_share_and_the_others_still_get_slots() {
        let slots = StreamSlots::new("plant", 64, 16);
        let greedy: Vec<_> = (0..16)
            .map(|_| slots.acquire_for("certificate hog".into(), "StreamState").expect("within the share"))
            .collect();
        let refused = slots.acquire_for("certificate hog".into(), "StreamState").expect_err("the 17th");
        assert_eq!(refused.code(), tonic::Code::ResourceExhausted);
        for part in ["plant", "certificate hog", "holds 16", "--max-streams-per-client 16"] {
            assert!(refused.message().contains(part), "{part:?} not in {:?}", refused.message());
        }
        let other =
            slots.acquire_for("certificate controller".into(), "StreamState").expect("another client");
        assert_eq!(slots.open(), 17);
        drop(greedy);
        let _again = slots
            .acquire_for("certificate hog".into(), "StreamState")
            .expect("its slots are freed with its streams");
        drop(other);
        assert_eq!(slots.open(), 1);
    }
}
