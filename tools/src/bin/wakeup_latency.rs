//! How late does this machine wake a 500 Hz loop? One thread sleeps to absolute 2 ms
//! deadlines for `SECONDS` and records how late each wake-up comes (as `cyclictest` does), with
//! nothing of twinbots running: what it sees is the kernel's and the hypervisor's, the floor
//! under `bench rtde`'s "no missed cycle". Run it under `chrt -f 50` for real-time priority.
//!
//! `cargo run --release -p twinbots_tools --bin wakeup_latency -- [SECONDS]`

use std::time::{Duration, Instant};

use anyhow::Context;

const PERIOD: Duration = Duration::from_micros(2000);

fn main() -> anyhow::Result<()> {
    let seconds: u64 =
        std::env::args().nth(1).map_or(Ok(600), |s| s.parse()).context("SECONDS must be a whole number")?;
    anyhow::ensure!(seconds > 0, "SECONDS must be at least 1, not {seconds}");
    let cycles = seconds * 500;
    let start = Instant::now();
    let mut late_us: Vec<u64> = Vec::with_capacity(cycles as usize);
    for k in 1..=cycles {
        let deadline = start + PERIOD * k as u32;
        let now = Instant::now();
        if deadline > now {
            std::thread::sleep(deadline - now);
        }
        late_us.push(Instant::now().saturating_duration_since(deadline).as_micros() as u64);
    }
    let mut sorted = late_us.clone();
    sorted.sort_unstable();
    let quantile = |q: f64| sorted[((sorted.len() - 1) as f64 * q) as usize];
    let later_than = |us: u64| late_us.iter().filter(|&&l| l > us).count();
    println!(
        "{} wake-ups every 2 ms: late by p50 {} µs, p99 {} µs, p99.99 {} µs, max {} µs; later than 1 ms: {}, than 2 ms (a missed cycle): {}",
        late_us.len(),
        quantile(0.5),
        quantile(0.99),
        quantile(0.9999),
        sorted.last().copied().unwrap_or(0),
        later_than(1000),
        later_than(2000)
    );
    let mut worst: Vec<(usize, u64)> = late_us.iter().copied().enumerate().filter(|(_, l)| *l > 2000).collect();
    worst.sort_by_key(|&(_, l)| std::cmp::Reverse(l));
    for (k, l) in worst.into_iter().take(10) {
        println!("  {:.3} s in: {l} µs late", (k + 1) as f64 * PERIOD.as_secs_f64());
    }
    Ok(())
}
