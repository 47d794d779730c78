//! Real-time pacing for the loops that stand in for a robot (`ur-sim`, `ros2`).

use std::time::{Duration, Instant};

/// Paces a loop at one cycle per `period`: sleeps out what is left of each cycle, counts the
/// cycles that ended a whole period or more late, and after a stall (more than ten periods
/// behind) counts on from now instead of running the missed cycles back to back.
pub struct Pacer {
    period: Duration,
    next: Instant,
    /// Cycles that ended a whole period or more after their time.
    pub missed: u64,
}

impl Pacer {
    pub fn new(period: Duration) -> Self {
        Self { period, next: Instant::now(), missed: 0 }
    }

    /// Ends a cycle: waits for the next one's time.
    pub fn wait(&mut self) {
        self.next += self.period;
        let now = Instant::now();
        if now < self.next {
            std::thread::sleep(self.next - now);
        } else if now - self.next >= self.period {
            self.missed += 1;
            if now - self.next > 10 * self.period {
                self.next = now;
            }
        }
    }
}
