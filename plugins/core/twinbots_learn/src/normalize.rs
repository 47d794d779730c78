//! Running mean and variance of observations (Welford, batched; as SB3's RunningMeanStd).

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunningMeanStd {
    pub mean: Vec<f64>,
    pub var: Vec<f64>,
    pub count: f64,
}

/// Normalised observations are clipped to ±this.
pub const CLIP: f32 = 10.0;

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
        for k in 0..dim {
            let xs = batch.iter().skip(k).step_by(dim).map(|&x| x as f64);
            let mean = xs.clone().sum::<f64>() / n;
            let var = xs.map(|x| (x - mean).powi(2)).sum::<f64>() / n;
            let delta = mean - self.mean[k];
            let total = self.count + n;
            self.mean[k] += delta * n / total;
            let m2 = self.var[k] * self.count + var * n + delta * delta * self.count * n / total;
            self.var[k] = m2 / total;
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

/// `raw` normalised with `rms` if the model normalises, else as it is: what every learner feeds
/// its networks.
pub fn normalized(rms: Option<&RunningMeanStd>, raw: &[f32]) -> Vec<f32> {
    match rms {
        Some(rms) => rms.normalize(raw),
        None => raw.to_vec(),
    }
}
