//! Running pipeline work without the GIL while Ctrl-C still works.
//!
//! Python runs its signal handlers only on the main thread, and only when that thread holds the GIL.
//! So the work runs on a scoped worker thread while the calling thread waits without the GIL in
//! short slices; between slices it takes the GIL and runs the pending signal handlers
//! (`Python::check_signals`). When one raises (Ctrl-C raises `KeyboardInterrupt`), the pipeline's
//! cancellation flag is set, the worker stops after its current iteration (or frame, or stage), and
//! the exception is re-raised: nothing is left running and no half-made scene is returned. A panic on
//! the worker becomes a `RuntimeError` rather than aborting the interpreter.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::Duration;

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;

/// How long the caller waits without the GIL before it checks for signals.
const SLICE: Duration = Duration::from_millis(50);

/// Set when the worker ends, by return or by panic.
struct Done<'a>(&'a (Mutex<bool>, Condvar));

impl Drop for Done<'_> {
    fn drop(&mut self) {
        let (lock, cv) = self.0;
        *lock.lock().unwrap_or_else(|e| e.into_inner()) = true;
        cv.notify_all();
    }
}

/// Runs `work(cancel)` on a worker thread without the GIL; see the module docs.
pub fn run<T: Send>(py: Python<'_>, work: impl FnOnce(&AtomicBool) -> T + Send) -> PyResult<T> {
    let cancel = AtomicBool::new(false);
    let done = (Mutex::new(false), Condvar::new());
    std::thread::scope(|s| {
        let handle = s.spawn(|| {
            let _done = Done(&done);
            work(&cancel)
        });
        let mut raised: Option<PyErr> = None;
        loop {
            let finished = py.detach(|| {
                let (lock, cv) = &done;
                let guard = lock.lock().unwrap_or_else(|e| e.into_inner());
                let (guard, _) = cv
                    .wait_timeout_while(guard, SLICE, |d| !*d)
                    .unwrap_or_else(|e| e.into_inner());
                *guard
            });
            if finished {
                break;
            }
            if raised.is_none()
                && let Err(e) = py.check_signals()
            {
                cancel.store(true, Ordering::SeqCst);
                raised = Some(e);
            }
        }
        let joined = py.detach(|| handle.join());
        if let Some(e) = raised {
            return Err(e);
        }
        joined.map_err(|p| {
            let what = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            PyRuntimeError::new_err(format!("internal error in trand: {what}"))
        })
    })
}
