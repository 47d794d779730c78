//! Running mean and variance of observations (Welford, batched; as SB3's RunningMeanStd), with
//! one difference: a bounded step per sample. Once the statistics rest on [`WARMUP`] samples,
//! each value enters them clipped to mean ± [`ROBUST_SIGMAS`] standard deviations. One wild
//! reading (a faulty sensor's 1e6) then moves the variance by at most ROBUST_SIGMAS²/count
//! times itself instead of 1e12/count; a working sensor's values are folded in exactly as SB3
//! does. (At 10 σ, the bound normalised values are clipped to, the clipping also caught the
//! UR5e's own readings as its policy changed, and its PPO reach solved at 368,640 steps instead
//! of 286,720; at 100 σ the run is the same as without the clipping: 286,720 steps, 98 %.) Implausible readings are refused before
//! they get here (`twinbots_link::checks`): this is the second line.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunningMeanStd {
    pub mean: Vec<f64>,
    pub var: Vec<f64>,
    pub count: f64,
}

/// Normalised observations are clipped to ±this.
pub const CLIP: f32 = 10.0;
/// Samples after which values entering the statistics are clipped to mean ± ROBUST_SIGMAS σ.
pub const WARMUP: f64 = 1000.0;
/// How far from the mean, in standard deviations, a value may enter the statistics.
pub const ROBUST_SIGMAS: f64 = 100.0;

impl RunningMeanStd {
    pub fn new(dim: usize) -> Self {
        Self { mean: vec![0.0; dim], var: vec![1.0; dim], count: 1e-4 }
    }

    /// Folds in a batch of flat observations.
    pub fn update(&mut self, batch: &[f32]) {
        let dim = self.mean.len();
        let n = (batch.len() / dim) as f64;
        if n == 0.0 {
            return;
        }
        let robust = self.count >= WARMUP;
        for k in 0..dim {
            let reach = ROBUST_SIGMAS * (self.var[k] + 1e-8).sqrt();
            let (lo, hi) = (self.mean[k] - reach, self.mean[k] + reach);
            let xs =
                batch.iter().skip(k).step_by(dim).map(|&x| if robust { (x as f64).clamp(lo, hi) } else { x as f64 });
            let mean = xs.clone().sum::<f64>() / n;
            let var = xs.map(|x| (x - mean).powi(2)).sum::<f64>() / n;
            let mut value = Moments::of(self, k);
            value.fold(Moments { mean, var, count: n });
            (self.mean[k], self.var[k]) = (value.mean, value.var);
        }
        self.count += n;
    }

    /// An error unless every statistic is finite (a model with others is unusable).
    pub fn check_finite(&self) -> anyhow::Result<()> {
        let finite = self.mean.iter().chain(&self.var).all(|x| x.is_finite()) && self.count.is_finite();
        anyhow::ensure!(finite, "the observation statistics are not finite: the model is unusable");
        Ok(())
    }

    /// `(x - mean) / sqrt(var + 1e-8)`, clipped.
    pub fn normalize(&self, batch: &[f32]) -> Vec<f32> {
        let dim = self.mean.len();
        batch
            .iter()
            .enumerate()
            .map(|(i, &x)| {
                let k = i % dim;
                (((x as f64 - self.mean[k]) / (self.var[k] + 1e-8).sqrt()) as f32).clamp(-CLIP, CLIP)
            })
            .collect()
    }
}

/// Robots a value's statistics are judged among: with fewer, every robot's readings count.
pub const JUDGED_FROM: usize = 3;
/// Readings a robot has sent before it is judged (its own statistics settle first).
pub const JUDGED_AFTER: f64 = 100.0;
/// How far a robot's statistics of a value may stray from the robots' median before its
/// readings of that value stop counting: its standard deviation within this many times the
/// median one, its mean within this many median standard deviations of the median mean.
pub const CONSENSUS_FACTOR: f64 = 5.0;

/// The observation statistics of a run whose observations come from several robots (the
/// RobotServer, design pattern 3): each robot's readings kept apart, and per value the run's
/// statistics are those of the robots that agree with the rest. A robot whose readings of a
/// value stray from the others' (a sensor that reports wild values that are still plausible:
/// a pole rate of ±100 rad/s where the others see ±2) stops counting for that value, all its
/// readings of it, for as long as it strays; its other values still count. With fewer than
/// [`JUDGED_FROM`] robots past [`JUDGED_AFTER`] readings, nobody is judged. Robots that agree,
/// folded together, are SB3's statistics of their readings (Chan's parallel combination).
#[derive(Clone, Debug)]
pub struct RobotStatistics {
    /// Per value, what the run knew before these robots (a resumed model's statistics), and
    /// the robots that have left, folded in as they left (as far as they agreed then).
    settled: Vec<Moments>,
    robots: BTreeMap<u64, RunningMeanStd>,
}

/// Mean and variance of one value over `count` samples.
#[derive(Clone, Copy, Debug)]
struct Moments {
    mean: f64,
    var: f64,
    count: f64,
}

impl Moments {
    fn of(rms: &RunningMeanStd, k: usize) -> Self {
        Self { mean: rms.mean[k], var: rms.var[k], count: rms.count }
    }

    /// Folds `other` in (Chan et al.'s combination, as [`RunningMeanStd::update`] folds a batch).
    fn fold(&mut self, other: Moments) {
        let total = self.count + other.count;
        let delta = other.mean - self.mean;
        self.mean += delta * other.count / total;
        self.var = (self.var * self.count + other.var * other.count + delta * delta * self.count * other.count / total)
            / total;
        self.count = total;
    }
}

impl RobotStatistics {
    /// Starting from the model's statistics (a new model's, or a resumed one's).
    pub fn new(model: &RunningMeanStd) -> Self {
        Self { settled: (0..model.mean.len()).map(|k| Moments::of(model, k)).collect(), robots: BTreeMap::new() }
    }

    /// Folds `raw` (rows of one robot's observations) into that robot's statistics.
    pub fn observe(&mut self, robot: u64, raw: &[f32]) {
        let dim = self.settled.len();
        self.robots.entry(robot).or_insert_with(|| RunningMeanStd::new(dim)).update(raw);
    }

    /// A robot left: what it sent stays, as far as it agreed with the others.
    pub fn leave(&mut self, robot: u64) {
        let bounds = self.bounds();
        if let Some(gone) = self.robots.remove(&robot) {
            for (k, settled) in self.settled.iter_mut().enumerate() {
                if agrees(&gone, k, bounds[k]) {
                    settled.fold(Moments::of(&gone, k));
                }
            }
        }
    }

    /// Per value, the robots' median mean and how far from it (and how large a standard
    /// deviation) a robot's statistics may be and still count; `None` where nobody is judged.
    fn bounds(&self) -> Vec<Option<(f64, f64)>> {
        let judged: Vec<&RunningMeanStd> = self.robots.values().filter(|rms| rms.count >= JUDGED_AFTER).collect();
        if judged.len() < JUDGED_FROM {
            return vec![None; self.settled.len()];
        }
        let mut values = Vec::with_capacity(judged.len());
        (0..self.settled.len())
            .map(|k| {
                values.clear();
                values.extend(judged.iter().map(|r| r.var[k]));
                let median_var = median(&mut values);
                values.clear();
                values.extend(judged.iter().map(|r| r.mean[k]));
                let median_mean = median(&mut values);
                Some((median_mean, CONSENSUS_FACTOR * (median_var + 1e-8).sqrt()))
            })
            .collect()
    }

    /// The run's statistics: per value, the settled ones with the agreeing robots' folded in
    /// (the count is the largest of the values'). Runs on every observation a robot sends, so
    /// it judges in place: no list of who agrees, medians by selection rather than sorting.
    pub fn consensus(&self) -> RunningMeanStd {
        let dim = self.settled.len();
        let mut out = RunningMeanStd { mean: vec![0.0; dim], var: vec![0.0; dim], count: 0.0 };
        for (k, bound) in self.bounds().into_iter().enumerate() {
            let mut value = self.settled[k];
            for robot in self.robots.values().filter(|r| agrees(r, k, bound)) {
                value.fold(Moments::of(robot, k));
            }
            (out.mean[k], out.var[k]) = (value.mean, value.var);
            out.count = out.count.max(value.count);
        }
        out
    }
}

/// Whether `robot`'s statistics of value `k` lie within `bound` (as `RobotStatistics::bounds` gives it).
fn agrees(robot: &RunningMeanStd, k: usize, bound: Option<(f64, f64)>) -> bool {
    bound
        .is_none_or(|(median_mean, reach)| robot.var[k].sqrt() <= reach && (robot.mean[k] - median_mean).abs() <= reach)
}

/// The median of `values` (the mean of the middle two for an even count), reordering them.
fn median(values: &mut [f64]) -> f64 {
    let n = values.len();
    let (lower, middle, _) = values.select_nth_unstable_by(n / 2, f64::total_cmp);
    let middle = *middle;
    if n % 2 == 1 {
        middle
    } else {
        let below = lower.iter().copied().max_by(f64::total_cmp).expect("an even count of at least 2");
        (below + middle) / 2.0
    }
}

/// `raw` normalised with `rms` if the model normalises, else as it is: what every learner feeds
/// its networks.
pub fn normalized(rms: Option<&RunningMeanStd>, raw: &[f32]) -> Vec<f32> {
    match rms {
        Some(rms) => rms.normalize(raw),
        None => raw.to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_wild_value_moves_the_statistics_a_bounded_step() {
        let mut rms = RunningMeanStd::new(1);
        // 2000 readings of a working sensor: mean 0, variance 1 (±1 alternating).
        let clean: Vec<f32> = (0..2000).map(|i| if i % 2 == 0 { 1.0 } else { -1.0 }).collect();
        rms.update(&clean);
        assert!((rms.var[0] - 1.0).abs() < 1e-3);
        let before = rms.clone();
        rms.update(&[1e6]);
        // Clipped to mean + 100 σ: the variance grows by about 100² / 2001, not 1e12 / 2001.
        assert!(rms.var[0] < 6.0 && rms.mean[0] < 0.06, "{rms:?}");
        // Before the warm-up, values go in as they are (SB3's statistics exactly).
        let mut fresh = RunningMeanStd::new(1);
        fresh.update(&[3.0, -3.0]);
        assert!((fresh.var[0] - 9.0).abs() < 1e-3, "{fresh:?}");
        // Within 100 σ a value is folded in exactly.
        let mut exact = before.clone();
        exact.update(&[5.0]);
        let (n, m, v) = (before.count, before.mean[0], before.var[0]);
        let mean = m + (5.0 - m) / (n + 1.0);
        let var = (v * n + (5.0 - m).powi(2) * n / (n + 1.0)) / (n + 1.0);
        assert!((exact.mean[0] - mean).abs() < 1e-12 && (exact.var[0] - var).abs() < 1e-12);
    }

    #[test]
    fn a_robot_whose_readings_stray_from_the_others_stops_counting() {
        // Two values: the first as a working pole-rate sensor reads it (±1.5 about 0.2), the
        // second ±0.3. Robot 3's first value is wild but plausible (±90); its second is fine.
        let honest = |robot: u64, t: usize| {
            [0.2 + 1.5 * ((t as f32) * 0.37 + robot as f32).sin(), 0.3 * (t as f32 * 0.11).cos()]
        };
        let wild = |t: usize| [if t.is_multiple_of(2) { 90.0 } else { -90.0 }, 0.3 * (t as f32 * 0.11).cos()];
        let mut statistics = RobotStatistics::new(&RunningMeanStd::new(2));
        let (mut everyone, mut agreeing) = (RunningMeanStd::new(2), RunningMeanStd::new(1));
        for t in 0..500 {
            for robot in 0..4u64 {
                let reading = if robot == 3 { wild(t) } else { honest(robot, t) };
                statistics.observe(robot, &reading);
                everyone.update(&reading);
                if robot != 3 {
                    agreeing.update(&reading[..1]);
                }
            }
        }
        let consensus = statistics.consensus();
        // Pooled, the wild robot sets the first value's variance (≈ 2,000 against ≈ 1.1).
        assert!(everyone.var[0] > 1000.0, "{everyone:?}");
        assert!((consensus.mean[0] - agreeing.mean[0]).abs() < 1e-6, "{consensus:?} {agreeing:?}");
        assert!((consensus.var[0] - agreeing.var[0]).abs() < 1e-6, "{consensus:?} {agreeing:?}");
        // Its second value agrees with the others', so all four count there.
        assert!(
            (consensus.mean[1] - everyone.mean[1]).abs() < 1e-6 && (consensus.var[1] - everyone.var[1]).abs() < 1e-6
        );
        // A robot that leaves leaves what it sent as far as it agreed.
        statistics.leave(3);
        statistics.leave(0);
        let after = statistics.consensus();
        assert!((after.var[0] - agreeing.var[0]).abs() < 1e-6 && (after.var[1] - everyone.var[1]).abs() < 1e-6);
        // Two robots are not judged: one cannot tell which strays.
        let mut two = RobotStatistics::new(&RunningMeanStd::new(2));
        let mut pooled = RunningMeanStd::new(2);
        for t in 0..500 {
            for (robot, reading) in [(0, honest(0, t)), (1, wild(t))] {
                two.observe(robot, &reading);
                pooled.update(&reading);
            }
        }
        assert!((two.consensus().var[0] - pooled.var[0]).abs() < 1e-6 * pooled.var[0]);
    }
}
