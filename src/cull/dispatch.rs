//! The one way every cull is run: stateless requests, session frames,
//! WebSocket frames, walkthrough frames, eval and the command line.
//!
//! [`SceneMethods::cull`] runs a [`CullJob`] where the method's
//! [`Execution`] says (inline, on the blocking pool, or on a device's
//! queue) and awaits it; [`SceneMethods::cull_blocking`] does the same on
//! the calling thread for callers outside the async runtime. Both settle
//! the result the same way: a method that fails at run time (a lost
//! device, a panic) is answered by frustum culling, the stats say so
//! ([`Fallback`]), and the client's cache is made afresh, since a failed
//! cull may have left it half-updated. Only a busy device is an error: the
//! client is asked to come back ([`CullError::Busy`]).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;

use super::device::Refused;
use super::{
    CullError, CullJob, CullStats, Culler, Execution, Fallback, MethodOptions, SceneMethods, View,
};

/// A job after its cull, with what the cull cost and found.
#[derive(Debug)]
pub struct Culled {
    /// The job, its `out` holding the answer (sorted), its cache updated.
    pub job: CullJob,
    /// The answer's stats; `fallback` is set when another method answered.
    pub stats: CullStats,
}

/// Where a job stands after its method ran: culled, or failed with the
/// job (unless it was lost with a thread; boxed, as failures are rare and
/// a job is large).
type Ran = Result<Culled, (Option<Box<CullJob>>, CullError)>;

/// A result with the job it came with.
fn ran(job: CullJob, result: Result<CullStats, CullError>) -> Ran {
    match result {
        Ok(stats) => Ok(Culled { job, stats }),
        Err(e) => Err((Some(Box::new(job)), e)),
    }
}

impl SceneMethods {
    /// Culls `job` with `method` where the method runs, without blocking
    /// the async worker for more than an inline method's microseconds.
    ///
    /// Errors only with [`CullError::Busy`] (the device's queue is full),
    /// or when a failed method's cache cannot be made again.
    pub async fn cull(
        &self,
        method: &Arc<dyn Culler>,
        mut job: CullJob,
    ) -> Result<Culled, CullError> {
        let (view, options) = (job.view, job.cache_options());
        let ran: Ran = match method.execution() {
            Execution::Inline => {
                let result = run_caught(&**method, &mut job);
                ran(job, result)
            }
            Execution::Blocking => {
                let m = method.clone();
                let task = tokio::task::spawn_blocking(move || {
                    let result = run_caught(&*m, &mut job);
                    (job, result)
                });
                match task.await {
                    Ok((job, result)) => ran(job, result),
                    Err(e) => Err((None, failed(&**method, format!("its task ended: {e}")))),
                }
            }
            Execution::Device(queue) => match queue.submit(method.clone(), job) {
                Ok(answer) => match answer.await {
                    Ok((job, result)) => ran(job, result),
                    Err(_) => Err((None, failed(&**method, STOPPED))),
                },
                Err(refused) => refused_by(&queue, &**method, refused),
            },
        };
        self.settle(method, view, &options, ran)
    }

    /// [`SceneMethods::cull`] on the calling thread: inline and blocking
    /// methods run here, a device method's job is queued and waited for.
    /// Never call it from an async worker.
    pub fn cull_blocking(
        &self,
        method: &Arc<dyn Culler>,
        job: CullJob,
    ) -> Result<Culled, CullError> {
        let (view, options) = (job.view, job.cache_options());
        let ran = run_waiting(method, job);
        self.settle(method, view, &options, ran)
    }

    /// Turns a method's result into an answer: its own, or frustum
    /// culling's when it failed.
    fn settle(
        &self,
        method: &Arc<dyn Culler>,
        view: View,
        options: &MethodOptions,
        ran: Ran,
    ) -> Result<Culled, CullError> {
        let (job, reason) = match ran {
            Ok(culled) => return Ok(culled),
            Err((_, busy @ CullError::Busy { .. })) => return Err(busy),
            Err((job, CullError::Failed { reason, .. })) => (job, reason),
        };
        tracing::warn!(method = method.name(), %reason, "cull failed; answering with frustum culling");
        let remade = method.new_cache(options).map_err(|e| {
            failed(
                &**method,
                format!("{reason}; and its cache cannot be made again: {e}"),
            )
        })?;
        let mut job = match job {
            Some(mut job) => {
                job.cache = remade;
                *job
            }
            None => CullJob::new(view, remade),
        };
        // Frustum culling answers into the job's own buffers, with a cache
        // of its own (it keeps no state).
        let fallback = self.fallback();
        let cache = fallback
            .new_cache(&MethodOptions::new())
            .map_err(|e| failed(&**fallback, e.to_string()))?;
        let mut instead = CullJob {
            view,
            cache,
            out: std::mem::take(&mut job.out),
            occludees: std::mem::take(&mut job.occludees),
        };
        let mut stats = fallback.cull(&mut instead)?;
        job.out = instead.out;
        job.occludees = instead.occludees;
        stats.method = method.name();
        stats.fallback = Some(Fallback {
            method: fallback.name(),
            reason,
        });
        Ok(Culled { job, stats })
    }
}

impl CullJob {
    /// The options its cache was made with (a counted reference).
    fn cache_options(&self) -> Arc<MethodOptions> {
        self.cache.shared_options()
    }
}

/// Culls `job` with `method` on the calling thread, waiting for a device
/// method's device, with no fallback: for callers that report a failure
/// themselves (eval measures a method, not its fallback). Never call it
/// from an async worker.
pub fn cull_here(method: &Arc<dyn Culler>, job: CullJob) -> Result<Culled, CullError> {
    run_waiting(method, job).map_err(|(_, e)| e)
}

/// Runs `job` where `method` runs, waiting on this thread.
fn run_waiting(method: &Arc<dyn Culler>, mut job: CullJob) -> Ran {
    match method.execution() {
        Execution::Inline | Execution::Blocking => {
            let result = run_caught(&**method, &mut job);
            ran(job, result)
        }
        Execution::Device(queue) => match queue.submit(method.clone(), job) {
            Ok(answer) => match answer.blocking_recv() {
                Ok((job, result)) => ran(job, result),
                Err(_) => Err((None, failed(&**method, STOPPED))),
            },
            Err(refused) => refused_by(&queue, &**method, refused),
        },
    }
}

/// Runs one cull, a panic turned into a failure.
fn run_caught(method: &dyn Culler, job: &mut CullJob) -> Result<CullStats, CullError> {
    catch_unwind(AssertUnwindSafe(|| method.cull(job))).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic".into());
        Err(failed(method, format!("panicked: {what}")))
    })
}

/// Why a job that was queued never came back.
const STOPPED: &str = "the device stopped before answering";

fn failed(method: &dyn Culler, reason: impl Into<String>) -> CullError {
    CullError::Failed {
        method: method.name(),
        reason: reason.into(),
    }
}

/// What a refused submission means for the caller.
fn refused_by(queue: &super::DeviceQueue, method: &dyn Culler, refused: Refused) -> Ran {
    match refused {
        Refused::Full(job) => Err((
            Some(job),
            CullError::Busy {
                method: method.name(),
                retry_after: queue.retry_after(),
            },
        )),
        Refused::Stopped(job) => Err((
            Some(job),
            failed(method, format!("device '{}' has stopped", queue.name())),
        )),
    }
}
