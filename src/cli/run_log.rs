//! What every training run writes as it goes: `progress.csv`, `learning_curve.png`, atomic
//! checkpoints, and a progress bar with steps/s and the latest mean reward.

use std::io::Write;
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use twinbots_rl::plot::{self, CurvePoint, EvaluationPoint};
use twinbots_rl::{Ppo, SolvedCriterion, UpdateStats};

pub const CSV_HEADER: &str = "update,timesteps,episodes,mean_reward,min_reward,max_reward,mean_length,policy_loss,value_loss,entropy,approx_kl,clip_fraction,learning_rate,steps_per_s,success_rate";

fn csv_row(s: &UpdateStats) -> String {
    format!(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        s.update, s.timesteps, s.episodes, s.mean_reward, s.min_reward, s.max_reward, s.mean_length,
        s.policy_loss, s.value_loss, s.entropy, s.approx_kl, s.clip_fraction, s.learning_rate, s.steps_per_s,
        s.success_rate
    )
}

pub struct RunLog {
    dir: PathBuf,
    csv: std::fs::File,
    pub curve: Vec<CurvePoint>,
    pub evaluations: Vec<EvaluationPoint>,
    title: String,
    solved: Option<SolvedCriterion>,
    checkpoint_every: usize,
    bar: ProgressBar,
    total: u64,
}

impl RunLog {
    /// Appends to `dir/progress.csv` (writing its header if new); `curve` holds earlier points.
    pub fn open(dir: &Path, title: String, solved: Option<SolvedCriterion>, checkpoint_every: usize, total: u64, start: u64, curve: Vec<CurvePoint>) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir.join("checkpoints"))?;
        let path = dir.join("progress.csv");
        if !path.exists() {
            std::fs::write(&path, format!("{CSV_HEADER}\n"))?;
        }
        let csv = std::fs::OpenOptions::new().append(true).open(&path)?;
        let bar = ProgressBar::new(total);
        bar.set_style(ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} steps {msg}")?.progress_chars("=> "));
        bar.set_position(start.min(total));
        Ok(Self { dir: dir.to_path_buf(), csv, curve, evaluations: Vec::new(), title, solved, checkpoint_every: checkpoint_every.max(1), bar, total })
    }

    /// Logs an update; every `checkpoint_every` updates, saves a checkpoint and redraws the curve.
    pub fn on_update(&mut self, s: &UpdateStats, model: &Ppo) -> anyhow::Result<()> {
        writeln!(self.csv, "{}", csv_row(s))?;
        self.curve.push(CurvePoint {
            timesteps: s.timesteps,
            mean_reward: s.mean_reward,
            min_reward: s.min_reward,
            max_reward: s.max_reward,
            success_rate: s.success_rate,
        });
        self.bar.set_position(s.timesteps.min(self.total));
        let success = if s.success_rate.is_finite() { format!(", success {:.0} %", 100.0 * s.success_rate) } else { String::new() };
        self.bar.set_message(format!("{:.0} steps/s, mean reward {:.1}{success} ({} episodes)", s.steps_per_s, s.mean_reward, s.episodes));
        if s.update % self.checkpoint_every == 0 {
            model.save(self.dir.join("checkpoints").join(format!("step_{:010}", s.timesteps)))?;
            self.plot()?;
        }
        Ok(())
    }

    pub fn plot(&self) -> anyhow::Result<()> {
        plot::learning_curve(&self.dir.join("learning_curve.png"), &self.title, &self.curve, &self.evaluations, self.solved)
    }

    pub fn finish(&self) -> anyhow::Result<()> {
        self.bar.finish();
        self.plot()
    }
}
