//! A device's work queue: the execution mode of methods that run on
//! hardware (GPU occlusion queries, Tai & Hsu), or anything else that must
//! be driven from one thread.
//!
//! One thread owns the device and takes jobs from a bounded queue; what
//! waits in the queue when the thread comes back for more is run as one
//! batch ([`Culler::cull_batch`]), so requests that arrive together share a
//! submission. Callers never block an async worker on it: a full queue
//! refuses at once (the server answers 503 with `Retry-After`), and the
//! answer comes back through a one-shot channel that the caller awaits.
//! A panic in a batch fails that batch's jobs (each then answered by
//! frustum culling), not the thread; a device that does not answer a job
//! within its deadline has that job answered by frustum culling too, and
//! skips it if it comes to it later (a slow device must not hang its
//! clients, nor spend its recovery on answers nobody waits for). While it
//! is stuck, its full queue refuses new jobs (503 `busy`).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::time::Duration;

use tokio::sync::oneshot;

use super::{CullError, CullJob, CullStats, Culler};

/// What a device answers for one job: the job back, with the cull's result.
pub type DeviceReply = (CullJob, Result<CullStats, CullError>);

/// One job in the queue, with where its answer goes.
struct Submission {
    method: Arc<dyn Culler>,
    job: CullJob,
    reply: oneshot::Sender<DeviceReply>,
}

/// Why a job was not queued; the job comes back with it (boxed: a job is
/// large, and refusals are rare).
#[derive(Debug)]
pub enum Refused {
    /// The queue is full: try again later.
    Full(Box<CullJob>),
    /// The device's thread has stopped.
    Stopped(Box<CullJob>),
}

/// How a device's queue is sized and timed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeviceLimits {
    /// Most jobs waiting; past it, submissions are refused (503 `busy`).
    pub capacity: usize,
    /// Most jobs run as one batch.
    pub max_batch: usize,
    /// What a refused client is told to wait (`Retry-After`).
    pub retry_after: Duration,
    /// How long a caller waits for the device's answer before answering
    /// with frustum culling instead.
    pub deadline: Duration,
}

impl Default for DeviceLimits {
    fn default() -> Self {
        DeviceLimits {
            capacity: 256,
            max_batch: 64,
            retry_after: Duration::from_secs(1),
            deadline: Duration::from_secs(2),
        }
    }
}

/// A bounded queue in front of a thread that owns a device.
pub struct DeviceQueue {
    name: String,
    sender: SyncSender<Submission>,
    limits: DeviceLimits,
}

impl std::fmt::Debug for DeviceQueue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceQueue")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

impl DeviceQueue {
    /// Starts the device's thread, named `pvsd-device-{name}`, within `limits`.
    pub fn start(name: &str, limits: DeviceLimits) -> std::io::Result<Arc<DeviceQueue>> {
        let (sender, receiver) = sync_channel(limits.capacity.max(1));
        let max_batch = limits.max_batch.max(1);
        std::thread::Builder::new()
            .name(format!("pvsd-device-{name}"))
            .spawn(move || work(receiver, max_batch))?;
        Ok(Arc::new(DeviceQueue {
            name: name.to_string(),
            sender,
            limits,
        }))
    }

    /// The device's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its limits.
    pub fn limits(&self) -> DeviceLimits {
        self.limits
    }

    /// Queues `job` for `method` without waiting; the answer arrives on the
    /// returned channel.
    pub fn submit(
        &self,
        method: Arc<dyn Culler>,
        job: CullJob,
    ) -> Result<oneshot::Receiver<DeviceReply>, Refused> {
        let (reply, answer) = oneshot::channel();
        match self.sender.try_send(Submission { method, job, reply }) {
            Ok(()) => Ok(answer),
            Err(TrySendError::Full(s)) => Err(Refused::Full(Box::new(s.job))),
            Err(TrySendError::Disconnected(s)) => Err(Refused::Stopped(Box::new(s.job))),
        }
    }
}

/// The device thread: runs batches until every sender is gone.
fn work(receiver: Receiver<Submission>, max_batch: usize) {
    while let Ok(first) = receiver.recv() {
        let mut batch = vec![first];
        while batch.len() < max_batch {
            match receiver.try_recv() {
                Ok(s) => batch.push(s),
                Err(_) => break,
            }
        }
        // A caller past its deadline was answered by frustum culling and
        // waits no more: a device that fell behind skips its stale work.
        batch.retain(|s| !s.reply.is_closed());
        // One batch per method, in arrival order within each.
        while !batch.is_empty() {
            let method = batch[0].method.clone();
            let (same, rest): (Vec<_>, Vec<_>) = batch
                .into_iter()
                .partition(|s| Arc::ptr_eq(&s.method, &method));
            batch = rest;
            let (mut jobs, replies): (Vec<_>, Vec<_>) =
                same.into_iter().map(|s| (s.job, s.reply)).unzip();
            let results = catch_unwind(AssertUnwindSafe(|| method.cull_batch(&mut jobs)))
                .ok()
                .filter(|r| r.len() == jobs.len())
                .unwrap_or_else(|| {
                    let failed = Err(CullError::Failed {
                        method: method.name(),
                        reason: "the device failed while culling a batch".into(),
                    });
                    vec![failed; jobs.len()]
                });
            for ((job, result), reply) in jobs.into_iter().zip(results).zip(replies) {
                // A caller that stopped waiting no longer wants the answer.
                let _ = reply.send((job, result));
            }
        }
    }
}
