//! Process settings under which small networks learn at the speed of their arithmetic. Made
//! once, by `threads::configure` and by every learner's constructor (tests and the Python
//! extension make learners without `configure`). Neither changes a result.

use std::sync::OnceLock;

/// Matrix products of fewer multiply-adds than this run on one thread (gemm's default:
/// 48·48·256). Between a learner's many small ops the pool's workers sleep, and a product
/// split over them first wakes one, ≈ 50 µs on this 2-core VM, while a 256×64×64 product (a
/// minibatch through a 64-unit layer) takes ≈ 20 µs on one core: at gemm's default, SAC's
/// gradient steps took 40 % longer and the cart-pole's PPO updates 43 % (measured
/// 2026-11-27). Products of camera policies' convolutions (10⁸ and more) still split.
const GEMM_THREADING_THRESHOLD: usize = 256 * 256 * 256;

/// glibc's allocator returns freed memory at the top of its heap to the system once more than
/// this is free (its default: 128 KiB, adapting). A learner's step frees and allocates the same few hundred KiB of tensors over and
/// over: at the defaults each step gave pages back (`madvise`) and faulted them in again,
/// zeroed (measured 2026-11-27: SAC's gradient steps 8 % faster in `train`, 40 % in the test
/// binary, with these). Freed memory is kept for reuse instead; a replay buffer, far larger,
/// is still mapped on its own.
const KEEP_FREED_BYTES: i32 = 512 << 20;
/// Blocks from this size up are mapped on their own (glibc's default: 128 KiB, adapting).
const MAP_ON_ITS_OWN_BYTES: i32 = 32 << 20;

/// Small matrix products on the calling thread ([`GEMM_THREADING_THRESHOLD`]) and freed memory
/// kept for reuse ([`KEEP_FREED_BYTES`]): settings of the process, made once.
pub fn for_small_networks() {
    static DONE: OnceLock<()> = OnceLock::new();
    DONE.get_or_init(|| {
        gemm::set_threading_threshold(GEMM_THREADING_THRESHOLD);
        keep_freed_memory();
    });
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn keep_freed_memory() {
    // SAFETY: mallopt only sets parameters of glibc's allocator, under its own lock.
    unsafe {
        libc::mallopt(libc::M_TRIM_THRESHOLD, KEEP_FREED_BYTES);
        libc::mallopt(libc::M_MMAP_THRESHOLD, MAP_ON_ITS_OWN_BYTES);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn keep_freed_memory() {}
