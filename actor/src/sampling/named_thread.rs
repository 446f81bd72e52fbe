//! Scoped threads with names. The environments' threads, their thread
//! pools' and the U-Net's batching threads carry names (`env-3`,
//! `unet-batch`), so that a per-thread CPU account of the process
//! (`deploy/throughput.sh`, `top -H`) tells which kind of work kept a core
//! busy instead of listing every thread as `actor`.

use std::thread::{Scope, ScopedJoinHandle};

/// Starts `f` on a thread named `name` in `scope`. Panics, as
/// [`Scope::spawn`] does, if the system cannot start a thread.
pub(crate) fn spawn_named<'scope, 'env, T: Send + 'scope>(
    scope: &'scope Scope<'scope, 'env>,
    name: String,
    f: impl FnOnce() -> T + Send + 'scope,
) -> ScopedJoinHandle<'scope, T> {
    std::thread::Builder::new()
        .name(name)
        .spawn_scoped(scope, f)
        .expect("the system could not start a thread")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_thread_carries_its_name() {
        let name = std::thread::scope(|scope| {
            spawn_named(scope, "env-7".to_owned(), || {
                std::thread::current().name().map(str::to_owned)
            })
            .join()
            .expect("the thread ran")
        });
        assert_eq!(name.as_deref(), Some("env-7"));
    }
}
