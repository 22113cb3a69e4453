//! The thread pool the bindings run the core on in a forked process.
//!
//! rayon's global pool cannot be rebuilt. A process forked from one that had used it (the
//! default start method of `multiprocessing` on Linux, after any call into the core) holds
//! a copy of the pool's bookkeeping but none of its threads, so its first parallel call
//! would wait forever. The process that loaded the module runs the core on the global pool
//! as usual; any other process (a fork, or a fork of a fork) runs it inside a pool of its
//! own, built on first use. Such a pool reads `RAYON_NUM_THREADS` as the global one does.
//! (A pool for every process would cost the loading process a hand-over to the pool's
//! threads on every call: 7 us, against 1.7 us for a one-matrix polar decomposition.)

use std::sync::{Arc, Mutex, OnceLock};

use pyo3::Python;
use rayon::{ThreadPool, ThreadPoolBuilder};

/// The process that loaded the module: the one whose global pool is sound.
static LOADER: OnceLock<u32> = OnceLock::new();

/// A forked process's pool and that process.
static FORKED_POOL: Mutex<Option<(u32, Arc<ThreadPool>)>> = Mutex::new(None);

/// Records the loading process (at module initialisation).
pub(crate) fn register() {
    LOADER.get_or_init(std::process::id);
}

/// This forked process's pool, built on first use; `None` when no thread could be started
/// (the caller then runs on rayon's global pool, which may hang, as before this module).
fn forked_pool(pid: u32) -> Option<Arc<ThreadPool>> {
    // The lock is held for a lookup only, so a fork can hardly catch it held; a poisoned
    // lock holds a valid slot all the same.
    let mut slot = FORKED_POOL
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some((owner, pool)) = slot.as_ref() {
        if *owner == pid {
            return Some(Arc::clone(pool));
        }
    }
    // Built by the parent before this fork: its threads do not exist here, and dropping
    // it would signal threads that were never started. Leak it (one per fork).
    if let Some(stale) = slot.take() {
        std::mem::forget(stale);
    }
    let pool = Arc::new(
        ThreadPoolBuilder::new()
            .thread_name(|i| format!("elastocap-{i}"))
            .build()
            .ok()?,
    );
    *slot = Some((pid, Arc::clone(&pool)));
    Some(pool)
}

/// `f` with the GIL released, on a pool that has its threads in this process (module docs).
pub(crate) fn detach<T, F>(py: Python<'_>, f: F) -> T
where
    T: Send,
    F: Send + FnOnce() -> T,
{
    py.detach(|| {
        let pid = std::process::id();
        if LOADER.get() == Some(&pid) {
            return f();
        }
        match forked_pool(pid) {
            Some(pool) => pool.install(f),
            None => f(),
        }
    })
}
