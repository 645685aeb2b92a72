//! The cap on open server streams (`--max-streams`), as every service answers it.

use std::future::Future;
use std::time::Duration;

use tonic::{Code, Status};

/// The call was refused with `RESOURCE_EXHAUSTED`, naming the limit and the flag.
pub fn assert_exhausted<T>(result: Result<T, Status>, max_streams: usize) {
    match result {
        Ok(_) => panic!("a stream beyond --max-streams {max_streams} was accepted"),
        Err(s) => {
            assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
            let named = format!("--max-streams {max_streams}");
            assert!(s.message().contains(&named), "{:?} does not name `{named}`", s.message());
        }
    }
}

/// Calls `open` until it is not refused with `RESOURCE_EXHAUSTED` and returns what it gave: a
/// dropped stream frees its slot once the server has seen the client hang up, which takes a
/// moment. Panics on any other error, or when no slot is freed within `patience`.
pub async fn open_when_a_slot_is_free<T, F, Fut>(what: &str, patience: Duration, mut open: F) -> T
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<T, Status>>,
{
    let deadline = tokio::time::Instant::now() + patience;
    loop {
        match open().await {
            Ok(v) => return v,
            Err(s) if s.code() == Code::ResourceExhausted => {
                if tokio::time::Instant::now() >= deadline {
                    panic!("{what}: no slot was freed within {patience:?}: {s:?}");
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            Err(s) => panic!("{what}: {s:?}"),
        }
    }
}
