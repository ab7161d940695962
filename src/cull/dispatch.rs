//! The one way a server runs a cull: stateless requests, session frames,
//! WebSocket frames and walkthrough frames all go through
//! [`SceneMethods::cull`]; benches and tests through its blocking twin
//! [`SceneMethods::cull_blocking`]; eval, the command line
//! (`SceneMethods::cull_once`) and tests that must see a method's own
//! failures through [`cull_here`], which does not fall back.
//!
//! A [`CullJob`] runs where the method's [`Execution`] says: inline, on the
//! blocking pool, or on a device's queue. The result is settled one way:
//! - an answer is returned with its job;
//! - a method that fails at run time ([`CullError::Failed`]: a lost device,
//!   a panic) is answered by frustum culling into the same job, the stats
//!   say so ([`Fallback`]) and time the whole attempt, and the client's
//!   cache is made afresh when it can be (a failed cull may have left it
//!   half-updated; every method's state is safe to reuse stale, so the old
//!   one stays when it cannot);
//! - a busy device ([`CullError::Busy`]) is returned with the job, so a
//!   session keeps its cache and buffers and the client can retry;
//! - on the async path, a device job whose answer does not come within the
//!   device's deadline (or whose device stopped) is answered by frustum
//!   culling from copies of its view and avatars, since the device keeps
//!   the job (the blocking paths wait for the device: a hung device hangs
//!   the command, where a person sees it);
//! - a job lost with its blocking thread (a bug: panics are caught before
//!   that) is an internal error, never a fallback that could not answer the
//!   job's dynamic occludees.
//!
//! Every path culls the scene's movable objects ([`crate::scene::Motion`])
//! as dynamic occludees after the job's avatars ([`add_movers`]), and
//! those found visible join the answer ([`take_movers`]): they are in no
//! method's static structures, so no method knows them otherwise.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::time::Instant;

use super::device::Refused;
use super::{
    CullError, CullJob, CullStats, Culler, DeviceQueue, Execution, Fallback, MethodOptions,
    SceneMethods, View,
};
use crate::geom::Aabb;
use crate::scene::Scene;

/// A job after its cull, with what the cull cost and found.
#[derive(Debug)]
pub struct Culled {
    /// The job, its `out` holding the answer (sorted), its cache updated.
    pub job: CullJob,
    /// The answer's stats; `fallback` is set when another method answered.
    pub stats: CullStats,
}

/// A cull that gave no answer: why, and the job when it came back (boxed:
/// a job is large, and this is rare).
#[derive(Debug)]
pub struct Unanswered {
    /// The job, for the caller to keep its cache and buffers; `None` when
    /// it was lost with its thread.
    pub job: Option<Box<CullJob>>,
    /// Why there is no answer.
    pub error: CullError,
}

/// Where a job stands after its method ran.
type Ran = Result<Culled, Unanswered>;

/// A result with the job it came with.
fn ran(job: CullJob, result: Result<CullStats, CullError>) -> Ran {
    match result {
        Ok(stats) => Ok(Culled { job, stats }),
        Err(error) => Err(Unanswered {
            job: Some(Box::new(job)),
            error,
        }),
    }
}

/// What a device job's fallback needs when the device keeps the job.
struct Spare {
    view: View,
    also: Vec<View>,
    boxes: Vec<Aabb>,
    options: MethodOptions,
}

impl Spare {
    fn of(job: &CullJob) -> Spare {
        Spare {
            view: job.view,
            also: job.also.clone(),
            boxes: job.occludees.boxes().to_vec(),
            options: job.cache.options().clone(),
        }
    }

    /// A fresh job for the same view and avatars, failed for `why`; the
    /// dispatch answers it with frustum culling.
    fn instead(self, method: &dyn Culler, why: impl std::fmt::Display) -> Ran {
        let cache = match method.new_cache(&self.options) {
            Ok(cache) => cache,
            Err(e) => {
                return lost(
                    method,
                    format!("{why}; and its cache cannot be made again: {e}"),
                );
            }
        };
        let mut job = CullJob::new(self.view, cache);
        job.also = self.also;
        job.occludees.set_boxes(self.boxes);
        Err(Unanswered {
            job: Some(Box::new(job)),
            error: failed(method, why.to_string()),
        })
    }
}

/// A job that did not come back.
fn lost(method: &dyn Culler, how: impl std::fmt::Display) -> Ran {
    Err(Unanswered {
        job: None,
        error: failed(method, format!("the job was lost: {how}")),
    })
}

/// Adds `scene`'s movable objects, at their current boxes, to the job's
/// dynamic occludees after its avatars, unless `method` culls them itself;
/// returns how many avatars the job had.
pub fn add_movers(scene: &Scene, method: &dyn Culler, job: &mut CullJob) -> usize {
    let avatars = job.occludees.boxes().len();
    if !scene.motion().is_empty() && !method.culls_movers() {
        scene
            .motion()
            .with_boxes(|boxes| job.occludees.extend_boxes(boxes.iter().copied()));
    }
    avatars
}

/// After a cull: the movable objects found visible join the answer (ids
/// stay ascending), and the occludees are the job's avatars again.
pub fn take_movers(scene: &Scene, job: &mut CullJob, avatars: usize) -> u64 {
    let motion = scene.motion();
    if motion.is_empty() || job.occludees.boxes().len() <= avatars {
        job.occludees.truncate(avatars);
        return 0;
    }
    let mut added = 0;
    // With pixel bounds, a mover's is the whole view (no tighter one known).
    let [w, h] = job.view.camera().viewport;
    let areas = job.out.has_areas();
    for (k, id) in motion.ids().enumerate() {
        if job.occludees.visible()[avatars + k] && !job.out.contains(id) {
            if areas {
                job.out.push_with_area(id, w as f64 * h as f64);
            } else {
                job.out.push(id);
            }
            added += 1;
        }
    }
    job.out.finish();
    job.occludees.truncate(avatars);
    added
}

impl SceneMethods {
    /// Culls `job` with `method` where the method runs, without blocking
    /// the async worker for more than an inline method's microseconds. The
    /// scene's movable objects are culled as dynamic occludees.
    pub async fn cull(
        &self,
        method: &Arc<dyn Culler>,
        mut job: CullJob,
    ) -> Result<Culled, Unanswered> {
        let avatars = add_movers(self.scene(), &**method, &mut job);
        let ran = self.cull_moved(method, job).await;
        self.settle_movers(ran, avatars)
    }

    /// The movers' part of an answer ([`take_movers`]).
    fn settle_movers(&self, ran: Ran, avatars: usize) -> Ran {
        match ran {
            Ok(mut culled) => {
                culled.stats.visible += take_movers(self.scene(), &mut culled.job, avatars);
                Ok(culled)
            }
            Err(mut unanswered) => {
                if let Some(job) = unanswered.job.as_mut() {
                    job.occludees.truncate(avatars);
                }
                Err(unanswered)
            }
        }
    }

    async fn cull_moved(
        &self,
        method: &Arc<dyn Culler>,
        mut job: CullJob,
    ) -> Result<Culled, Unanswered> {
        let start = Instant::now();
        let ran = match self.execution_of(method.as_ref()) {
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
                    Err(e) => lost(&**method, e),
                }
            }
            Execution::Device(queue) => {
                // What a fallback needs if the device keeps the job: the
                // view, the avatars and the options (copies; a device job
                // is worth far more than they cost).
                let spare = Spare::of(&job);
                match queue.submit(method.clone(), job) {
                    Ok(answer) => match tokio::time::timeout(queue.limits().deadline, answer).await
                    {
                        Ok(Ok((job, result))) => ran(job, result),
                        Ok(Err(_)) => spare.instead(&**method, STOPPED),
                        Err(_) => spare.instead(
                            &**method,
                            format!("no answer within {:?}", queue.limits().deadline),
                        ),
                    },
                    Err(refused) => refused_by(&queue, &**method, refused),
                }
            }
        };
        self.settle(method, start, ran)
    }

    /// [`SceneMethods::cull`] on the calling thread: inline and blocking
    /// methods run here, a device method's job is queued and waited for.
    /// Never call it from an async worker.
    pub fn cull_blocking(
        &self,
        method: &Arc<dyn Culler>,
        mut job: CullJob,
    ) -> Result<Culled, Unanswered> {
        let start = Instant::now();
        let avatars = add_movers(self.scene(), &**method, &mut job);
        let ran = run_waiting(method, job);
        let ran = self.settle(method, start, ran);
        self.settle_movers(ran, avatars)
    }

    /// Turns a method's result into an answer: its own, or frustum
    /// culling's when it failed (module docs).
    fn settle(&self, method: &Arc<dyn Culler>, start: Instant, ran: Ran) -> Ran {
        let (mut job, reason) = match ran {
            Err(Unanswered {
                job: Some(job),
                error: CullError::Failed { reason, .. },
            }) => (job, reason),
            other => return other,
        };
        tracing::warn!(method = method.name(), %reason, "cull failed; answering with frustum culling");
        match method.new_cache(job.cache.options()) {
            Ok(fresh) => job.cache = fresh,
            Err(e) => tracing::error!(method = method.name(), %e, "cannot remake a cache"),
        }
        // Frustum culling answers into the job's own buffers, with a cache
        // of its own (it keeps no state).
        let fallback = self.fallback();
        let cache = match fallback.new_cache(&MethodOptions::new()) {
            Ok(cache) => cache,
            Err(e) => {
                let error = failed(&**fallback, e.to_string());
                return Err(Unanswered {
                    job: Some(job),
                    error,
                });
            }
        };
        let mut instead = CullJob {
            view: job.view,
            also: std::mem::take(&mut job.also),
            cache,
            out: std::mem::take(&mut job.out),
            occludees: std::mem::take(&mut job.occludees),
        };
        // A method that culls the movers itself left them out of the
        // occludees: frustum culling takes them as occludees instead.
        let own_movers = method.culls_movers();
        let avatars = instead.occludees.boxes().len();
        if own_movers {
            add_movers(self.scene(), &**fallback, &mut instead);
        }
        let result = fallback.cull(&mut instead);
        let movers = if own_movers {
            take_movers(self.scene(), &mut instead, avatars)
        } else {
            0
        };
        job.out = instead.out;
        job.also = instead.also;
        job.occludees = instead.occludees;
        let mut stats = match result {
            Ok(stats) => stats,
            Err(error) => {
                return Err(Unanswered {
                    job: Some(job),
                    error,
                });
            }
        };
        stats.visible += movers;
        stats.method = method.name();
        stats.cull_us = start.elapsed().as_secs_f64() * 1e6;
        stats.fallback = Some(Fallback {
            method: fallback.name(),
            reason,
        });
        Ok(Culled { job: *job, stats })
    }
}

/// Culls `job` with `method` on the calling thread, waiting for a device
/// method's device, with no fallback: for callers that report a failure
/// themselves (eval measures a method, not its fallback; tests must see a
/// method fail). `scene`'s movable objects are culled as dynamic
/// occludees, as [`SceneMethods::cull`] does. Never call it from an async
/// worker.
pub fn cull_here(
    scene: &Scene,
    method: &Arc<dyn Culler>,
    mut job: CullJob,
) -> Result<Culled, CullError> {
    let avatars = add_movers(scene, &**method, &mut job);
    let mut culled = run_waiting(method, job).map_err(|u| u.error)?;
    culled.stats.visible += take_movers(scene, &mut culled.job, avatars);
    Ok(culled)
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
                Err(_) => lost(&**method, STOPPED),
            },
            Err(refused) => refused_by(&queue, &**method, refused),
        },
    }
}

/// Runs one cull, a panic turned into a failure. What panicked goes to the
/// log; the client hears only that the method failed.
fn run_caught(method: &dyn Culler, job: &mut CullJob) -> Result<CullStats, CullError> {
    catch_unwind(AssertUnwindSafe(|| method.cull(job))).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic".into());
        tracing::error!(method = method.name(), panic = %what, "a cull panicked");
        Err(failed(method, PANICKED))
    })
}

/// The reason a client hears for a method that panicked.
pub const PANICKED: &str = "the method panicked (the details are in the server's log)";

/// Why a job that was queued never came back.
const STOPPED: &str = "the device stopped before answering";

fn failed(method: &dyn Culler, reason: impl Into<String>) -> CullError {
    CullError::Failed {
        method: method.name(),
        reason: reason.into(),
    }
}

/// What a refused submission means for the caller.
fn refused_by(queue: &DeviceQueue, method: &dyn Culler, refused: Refused) -> Ran {
    let (job, error) = match refused {
        Refused::Full(job) => (
            job,
            CullError::Busy {
                method: method.name(),
                retry_after: queue.limits().retry_after,
            },
        ),
        Refused::Stopped(job) => (
            job,
            failed(method, format!("device '{}' has stopped", queue.name())),
        ),
    };
    Err(Unanswered {
        job: Some(job),
        error,
    })
}
