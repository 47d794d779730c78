//! The process's thread pools, set up once, deliberately, for the machine it runs on.
//!
//! One pool does the CPU-parallel work: rayon's global pool, sized to the cores this process
//! may use. Arenas step side by side on it (`twinbots_sim::physics`), and candle's matrix
//! products (gemm) split over it when they are large enough to gain: from 256·256·256
//! multiply-adds on (`crate::tuning`; the MLPs of our policies stay on one thread, camera
//! policies' convolutions split).
//!
//! Candle sizes gemm's parallelism on every matrix product by reading `RAYON_NUM_THREADS`;
//! when it is unset, candle counts the physical cores by parsing `/proc/cpuinfo`, again on
//! every product. That read costs ~60 µs (measured on a 2-core VM), several times per policy
//! forward pass: it made 2048 steps of rollout inference take ~700 ms instead of ~50 ms.
//! [`configure`] sets the variable once, so candle never counts again.
//!
//! Bevy is built without its `multi_threaded` feature: its schedules run on the thread that
//! calls `App::update` and its task pools start no threads, so there is nothing of Bevy's to
//! size here.

use std::num::NonZeroUsize;
use std::sync::OnceLock;

/// The variable candle and rayon both read for their thread count.
const THREAD_COUNT_VAR: &str = "RAYON_NUM_THREADS";

/// Sets up the thread pools and returns how many threads they use. Call it first thing in
/// `main`, before any other thread starts (it may set an environment variable); later calls
/// return the first call's answer. A `RAYON_NUM_THREADS` set by the user is kept; otherwise the
/// count is the cores this process may run on (its CPU affinity and cgroup quota).
pub fn configure() -> usize {
    static THREADS: OnceLock<usize> = OnceLock::new();
    *THREADS.get_or_init(|| {
        let threads = std::env::var(THREAD_COUNT_VAR)
            .ok()
            .and_then(|v| v.parse::<usize>().ok())
            .filter(|&n| n > 0)
            .unwrap_or_else(|| {
                let cores = std::thread::available_parallelism().map_or(1, NonZeroUsize::get);
                // SAFETY: `configure` runs at start-up, before the process starts other
                // threads (see its contract), so nothing reads the environment concurrently.
                unsafe { std::env::set_var(THREAD_COUNT_VAR, cores.to_string()) };
                cores
            });
        crate::tuning::for_small_networks();
        // Fails only if the global pool already exists (something used rayon first, e.g. an
        // earlier test in the same process); that pool then keeps its size.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("twinbots-worker-{i}"))
            .build_global();
        threads
    })
}

/// How long a side of [`with_helper`] spins for the other's next message before it sleeps.
/// Waking a sleeping thread costs ≈ 50 µs on a 2-core VM, a sixth of half a PPO minibatch;
/// within a burst the other side answers in well under this.
const SPIN: std::time::Duration = std::time::Duration::from_millis(1);

/// The caller's end of a second thread that does one kind of job for a burst of work: an
/// update's second half-minibatches.
pub struct Helper<J, R> {
    jobs: std::sync::mpsc::Sender<J>,
    results: std::sync::mpsc::Receiver<R>,
}

impl<J, R> Helper<J, R> {
    /// Hands the helper its next job (answered in order by [`Helper::result`]).
    pub fn submit(&self, job: J) -> anyhow::Result<()> {
        self.jobs.send(job).map_err(|_| anyhow::anyhow!("the helper thread has stopped"))
    }

    /// The answer to the oldest job not yet answered.
    pub fn result(&self) -> anyhow::Result<R> {
        wait(&self.results).ok_or_else(|| anyhow::anyhow!("the helper thread stopped before it answered"))
    }
}

/// Minibatches of this many rows or more are computed in two halves ([`halves`]).
const SPLIT_FROM: usize = 64;

/// The rows of a minibatch of `len` as the learners compute it: in one part, or from
/// [`SPLIT_FROM`] rows on in two halves whose losses and gradients add up to the minibatch's
/// (the second for a [`Helper`]). A rule of the minibatch's size, never of the machine: a seed
/// gives the same bits on one core as on many (one core does both halves in turn).
#[allow(clippy::single_range_in_vec_init)] // a list of ranges that holds one or two
pub fn halves(len: usize) -> Vec<std::ops::Range<usize>> {
    if len < SPLIT_FROM { vec![0..len] } else { vec![0..len / 2, len / 2..len] }
}

/// Does `jobs` (one or two) with `work`, answering in their order: the second on `helper`
/// while this thread does the first, or one after the other without a helper.
pub fn share<J, R>(helper: Option<&Helper<J, R>>, work: &impl Fn(J) -> R, jobs: Vec<J>) -> anyhow::Result<Vec<R>> {
    anyhow::ensure!(jobs.len() <= 2, "{} jobs to share between two threads", jobs.len());
    let mut jobs = jobs.into_iter();
    Ok(match (helper, jobs.next(), jobs.next()) {
        (Some(helper), Some(first), Some(second)) => {
            helper.submit(second)?;
            let first = work(first);
            vec![first, helper.result()?]
        }
        (_, first, second) => first.into_iter().chain(second).map(work).collect(),
    })
}

/// Runs `body` with a helper thread that answers each job with `work`, while the pool has two
/// threads or more; with one, `body` gets none and does the jobs itself. The helper spins
/// between jobs ([`SPIN`]), so it lives only as long as `body`: one burst.
pub fn with_helper<J: Send, R: Send, T>(
    work: impl Fn(J) -> R + Sync,
    body: impl FnOnce(Option<&Helper<J, R>>) -> T,
) -> T {
    if rayon::current_num_threads() < 2 {
        return body(None);
    }
    std::thread::scope(|scope| {
        let (jobs, job_inbox) = std::sync::mpsc::channel::<J>();
        let (answers, results) = std::sync::mpsc::channel::<R>();
        let work = &work;
        let helper = std::thread::Builder::new().name("twinbots-helper".into()).spawn_scoped(scope, move || {
            while let Some(job) = wait(&job_inbox) {
                if answers.send(work(job)).is_err() {
                    break;
                }
            }
        });
        match helper {
            // Dropping the `Helper` after `body` disconnects the helper, which ends.
            Ok(_) => body(Some(&Helper { jobs, results })),
            // No thread to be had: the body does the jobs itself.
            Err(_) => body(None),
        }
    })
}

/// The next message, spinning for [`SPIN`] before it sleeps; none once the sender is gone.
fn wait<T>(inbox: &std::sync::mpsc::Receiver<T>) -> Option<T> {
    use std::sync::mpsc::TryRecvError;
    let started = std::time::Instant::now();
    loop {
        match inbox.try_recv() {
            Ok(message) => return Some(message),
            Err(TryRecvError::Disconnected) => return None,
            Err(TryRecvError::Empty) if started.elapsed() < SPIN => std::hint::spin_loop(),
            Err(TryRecvError::Empty) => return inbox.recv().ok(),
        }
    }
}
