//! A run directory: what a training run leaves behind, read and written by name.
//!
//! ```text
//! runs/<robot>-<time>/
//!   config.toml                      the resolved settings (the caller's type)
//!   progress.csv                     one row per update (`UpdateStats`, the algorithm's own
//!                                    figures among its columns), read by column name
//!   evaluations.csv                  periodic evaluations of the deterministic policy
//!   checkpoints/step_<timesteps>/    models saved while training, each renamed into place whole
//!   model/                           the final model
//!   learning_curve.png
//!   eval.json                        the final model's evaluation
//!   summary.json                     how the run went (`Summary`)
//!   events.out.tfevents.*            TensorBoard scalars (one file per process that trained)
//! ```
//!
//! Every file is written whole through a temporary file and a rename, or appended one row at a
//! time, so a run killed at any moment leaves files that `--resume` can read.

mod summary;
mod table;

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;
use serde::de::DeserializeOwned;

pub use summary::{EvaluationSummary, Summary, TimeBreakdown};
pub use table::{Row, Table};

use crate::agent::{Agent, LoadAgent};
use crate::evaluation::EvalResult;
use crate::model_io::{METADATA_FILE, ModelError, WEIGHTS_FILE, write_atomic};
use crate::stats::UpdateStats;

pub const CONFIG: &str = "config.toml";
pub const PROGRESS: &str = "progress.csv";
pub const EVALUATIONS: &str = "evaluations.csv";
pub const CHECKPOINTS: &str = "checkpoints";
pub const MODEL: &str = "model";
pub const LEARNING_CURVE: &str = "learning_curve.png";
pub const EVAL: &str = "eval.json";
pub const SUMMARY: &str = "summary.json";

/// One row of `evaluations.csv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvaluationRow {
    pub timesteps: u64,
    pub mean_score: f32,
    pub std_score: f32,
    pub mean_length: f32,
    /// For tasks that report success.
    pub success_rate: Option<f32>,
}

/// A run directory's path and the files in it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RunDir {
    path: PathBuf,
}

impl RunDir {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self { path: path.into() }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The path of the file (or folder) `name` in the run.
    pub fn file(&self, name: &str) -> PathBuf {
        self.path.join(name)
    }

    /// Creates the directory and its `checkpoints/`.
    pub fn create(&self) -> anyhow::Result<()> {
        let checkpoints = self.file(CHECKPOINTS);
        std::fs::create_dir_all(&checkpoints).map_err(|e| anyhow::anyhow!("{}: {e}", checkpoints.display()))
    }

    /// Whether a run has already logged here.
    pub fn holds_run(&self) -> bool {
        self.file(PROGRESS).exists()
    }

    /// Writes the run's settings into `config.toml`.
    pub fn write_config<T: Serialize>(&self, config: &T) -> anyhow::Result<()> {
        let path = self.file(CONFIG);
        write_atomic(&path, toml::to_string_pretty(config)?.as_bytes())
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// The settings the run was made with; a misspelt key is an error naming it and its line
    /// (when `T` denies unknown fields).
    pub fn read_config<T: DeserializeOwned>(&self) -> anyhow::Result<T> {
        let path = self.file(CONFIG);
        let text = std::fs::read_to_string(&path)
            .map_err(|e| anyhow::anyhow!("{}: not a run directory: {e}", path.display()))?;
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// A new TensorBoard event file in the run (`tensorboard --logdir runs` shows every run).
    pub fn event_writer(&self) -> anyhow::Result<crate::tensorboard::EventWriter> {
        crate::tensorboard::EventWriter::create(&self.path)
    }

    /// Saves the final model into `model/`.
    pub fn save_model(&self, model: &dyn Agent) -> anyhow::Result<()> {
        Ok(model.save(&self.file(MODEL))?)
    }

    /// Saves `model` as `checkpoints/step_<timesteps>/`: written under another name and
    /// renamed into place, so a checkpoint is either complete or absent.
    pub fn save_checkpoint(&self, model: &dyn Agent) -> anyhow::Result<PathBuf> {
        let name = format!("step_{:010}", model.timesteps());
        let dir = self.file(CHECKPOINTS).join(&name);
        let partial = self.file(CHECKPOINTS).join(format!("{name}.partial"));
        let _ = std::fs::remove_dir_all(&partial);
        model.save(&partial)?;
        write_checksums(&partial)?;
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::rename(&partial, &dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
        Ok(dir)
    }

    /// The newest complete checkpoint, if any (its checksums are checked on loading).
    pub fn latest_checkpoint(&self) -> Option<PathBuf> {
        self.checkpoints().pop()
    }

    /// The complete checkpoints, oldest first.
    pub fn checkpoints(&self) -> Vec<PathBuf> {
        let Ok(entries) = std::fs::read_dir(self.file(CHECKPOINTS)) else { return Vec::new() };
        let mut dirs: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
                name.starts_with("step_") && !name.ends_with(".partial")
            })
            .filter(|p| p.join(METADATA_FILE).is_file() && p.join(WEIGHTS_FILE).is_file())
            .collect();
        dirs.sort();
        dirs
    }

    /// The newest checkpoint that loads: one that does not (damaged, or with non-finite
    /// weights) is reported on stderr and the one before it tried. Returns its path and model.
    pub fn load_newest_checkpoint<M: LoadAgent>(&self) -> anyhow::Result<(PathBuf, M)> {
        self.newest_checkpoint_with(M::load)
    }

    /// [`Self::load_newest_checkpoint`] with the loader `load` (an algorithm's, from
    /// `crate::algos`).
    pub fn newest_checkpoint_with<M>(
        &self,
        load: impl Fn(&Path) -> Result<M, ModelError>,
    ) -> anyhow::Result<(PathBuf, M)> {
        let checkpoints = self.checkpoints();
        anyhow::ensure!(!checkpoints.is_empty(), "{}: no checkpoint to resume from", self.path.display());
        for dir in checkpoints.iter().rev() {
            match verify_checksums(dir).and_then(|()| load(dir).map_err(anyhow::Error::from)) {
                Ok(model) => return Ok((dir.clone(), model)),
                Err(e) => {
                    eprintln!("warning: checkpoint {} is unusable ({e}); trying the one before it", dir.display())
                }
            }
        }
        anyhow::bail!(
            "{}: none of its {} checkpoints loads (see the warnings above)",
            self.path.display(),
            checkpoints.len()
        )
    }

    /// Its final model, else its newest checkpoint that loads (with the loader `load`, an
    /// algorithm's from `crate::algos`); returns where the model came from too.
    pub fn trained_with<M>(&self, load: impl Fn(&Path) -> Result<M, ModelError>) -> anyhow::Result<(PathBuf, M)> {
        let model = self.file(MODEL);
        if model.join(METADATA_FILE).is_file() {
            return Ok((model.clone(), load(&model)?));
        }
        anyhow::ensure!(!self.checkpoints().is_empty(), "{}: no model or checkpoint", self.path.display());
        self.newest_checkpoint_with(load)
    }

    /// Where the run's trained model may be: its final model, then its checkpoints, newest
    /// first.
    pub fn saved_models(&self) -> Vec<PathBuf> {
        let mut saved = vec![self.file(MODEL)];
        saved.extend(self.checkpoints().into_iter().rev());
        saved
    }

    /// Appends an update's row to `progress.csv` (with the header if the file is new).
    pub fn append_progress(&self, stats: &UpdateStats) -> anyhow::Result<()> {
        let cells = progress_cells(stats);
        append_row(&self.file(PROGRESS), &cells.iter().map(|(n, v)| (n.as_str(), v.clone())).collect::<Vec<_>>())
    }

    /// Appends a row given by column name (the common columns and an algorithm's figures
    /// `train`, e.g. `ppo::TRAIN_FIGURES`; the rest count as missing), for updates made outside
    /// twinbots (the RLlib path). An unknown name is an error.
    pub fn append_progress_columns(
        &self,
        columns: &std::collections::HashMap<String, f64>,
        train: &[&str],
    ) -> anyhow::Result<()> {
        let known = progress_columns(train);
        if let Some(unknown) = columns.keys().find(|name| !known.contains(name)) {
            anyhow::bail!("progress.csv has no column '{unknown}'; its columns: {}", known.join(", "));
        }
        // Whole numbers print without a fraction, so count columns parse as counts.
        self.append_progress(&stats_from_columns(&|name| columns.get(name).map(|v| v.to_string()), &known))
    }

    /// Every row of `progress.csv`, read by column name (rows cut short by a crash are skipped).
    pub fn read_progress(&self) -> anyhow::Result<Vec<UpdateStats>> {
        let table = Table::read(&self.file(PROGRESS))?;
        Ok(complete_rows(&table).map(|r| stats_from_columns(&|name| r.get::<String>(name), &table.header)).collect())
    }

    /// An error if `progress.csv` exists with other columns than this build writes for an
    /// algorithm whose figures are `train` (rows appended to it would not match its header).
    pub fn check_progress_columns(&self, train: &[&str]) -> anyhow::Result<()> {
        let table = Table::read(&self.file(PROGRESS))?;
        let ours = progress_columns(train);
        anyhow::ensure!(
            table.header.is_empty() || table.header == ours,
            "{}: its columns ({}) are not the ones this build writes ({})",
            self.file(PROGRESS).display(),
            table.header.join(","),
            ours.join(",")
        );
        Ok(())
    }

    /// Appends an evaluation at `timesteps` to `evaluations.csv`.
    pub fn append_evaluation(&self, timesteps: u64, result: &EvalResult) -> anyhow::Result<()> {
        let success = result.success_rate.map_or(String::new(), |x| x.to_string());
        append_row(
            &self.file(EVALUATIONS),
            &[
                ("timesteps", timesteps.to_string()),
                ("episodes", result.episodes.to_string()),
                ("mean_score", result.mean_score.to_string()),
                ("std_score", result.std_score.to_string()),
                ("mean_length", result.mean_length.to_string()),
                ("success_rate", success),
            ],
        )
    }

    /// Every row of `evaluations.csv`, read by column name.
    pub fn read_evaluations(&self) -> anyhow::Result<Vec<EvaluationRow>> {
        let table = Table::read(&self.file(EVALUATIONS))?;
        Ok(complete_rows(&table)
            .map(|r| EvaluationRow {
                timesteps: r.get("timesteps").unwrap_or(0),
                mean_score: r.number("mean_score"),
                std_score: r.number("std_score"),
                mean_length: r.number("mean_length"),
                success_rate: r.get("success_rate"),
            })
            .collect())
    }

    /// Drops the rows of `progress.csv` and `evaluations.csv` logged after `timesteps` (and
    /// any cut short), so that a run resumed from a checkpoint at `timesteps` logs them again.
    pub fn truncate_after(&self, timesteps: u64) -> anyhow::Result<()> {
        for path in [self.file(PROGRESS), self.file(EVALUATIONS)] {
            if !path.exists() {
                continue;
            }
            let table = Table::read(&path)?;
            let mut kept = table.header.join(",") + "\n";
            for row in complete_rows(&table).filter(|r| r.get::<u64>("timesteps").is_some_and(|t| t <= timesteps)) {
                kept += row.line;
                kept.push('\n');
            }
            write_atomic(&path, kept.as_bytes()).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        }
        Ok(())
    }

    /// Writes `value` as pretty JSON into the run's file `name` (`eval.json`, `summary.json`…).
    pub fn write_json<T: Serialize>(&self, name: &str, value: &T) -> anyhow::Result<()> {
        let path = self.file(name);
        twinbots_api::files::write_json(&path, value)
    }

    pub fn write_summary(&self, summary: &Summary) -> anyhow::Result<()> {
        self.write_json(SUMMARY, summary)
    }

    pub fn read_summary(&self) -> anyhow::Result<Summary> {
        let path = self.file(SUMMARY);
        let text = std::fs::read_to_string(&path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }
}

/// `progress.csv`'s columns around the algorithm's own figures (which come between).
const LEADING: [&str; 7] =
    ["update", "timesteps", "episodes", "mean_reward", "min_reward", "max_reward", "mean_length"];
const TRAILING: [&str; 4] = ["learning_rate", "steps_per_s", "success_rate", "skipped_steps"];

/// The header of `progress.csv` for an algorithm whose figures are `train`.
fn progress_columns(train: &[&str]) -> Vec<String> {
    LEADING.iter().chain(train).chain(&TRAILING).map(|c| c.to_string()).collect()
}

/// An update's cells, named: the names are `progress.csv`'s header.
fn progress_cells(s: &UpdateStats) -> Vec<(String, String)> {
    let mut cells: Vec<(String, String)> = [
        s.update.to_string(),
        s.timesteps.to_string(),
        s.episodes.to_string(),
        s.mean_reward.to_string(),
        s.min_reward.to_string(),
        s.max_reward.to_string(),
        s.mean_length.to_string(),
    ]
    .into_iter()
    .zip(LEADING)
    .map(|(value, name)| (name.to_string(), value))
    .collect();
    cells.extend(s.train.iter().map(|(name, value)| (name.clone(), value.to_string())));
    let trailing = [
        s.learning_rate.to_string(),
        s.steps_per_s.to_string(),
        s.success_rate.to_string(),
        s.skipped_steps.to_string(),
    ];
    cells.extend(TRAILING.iter().zip(trailing).map(|(name, value)| (name.to_string(), value)));
    cells
}

/// An update's figures from its cells by column name (`columns`: the header): a missing count
/// is 0, a missing figure NaN; every column that is not a common one is the algorithm's.
fn stats_from_columns(cell: &dyn Fn(&str) -> Option<String>, columns: &[String]) -> UpdateStats {
    fn column<T: std::str::FromStr>(cell: &dyn Fn(&str) -> Option<String>, name: &str) -> Option<T> {
        cell(name)?.parse().ok()
    }
    let number = |name: &str| column::<f32>(cell, name).unwrap_or(f32::NAN);
    let common = |name: &String| LEADING.contains(&name.as_str()) || TRAILING.contains(&name.as_str());
    UpdateStats {
        update: column(cell, "update").unwrap_or(0),
        timesteps: column(cell, "timesteps").unwrap_or(0),
        episodes: column(cell, "episodes").unwrap_or(0),
        mean_reward: number("mean_reward"),
        min_reward: number("min_reward"),
        max_reward: number("max_reward"),
        mean_length: number("mean_length"),
        train: columns.iter().filter(|c| !common(c)).map(|c| (c.clone(), number(c))).collect(),
        learning_rate: column(cell, "learning_rate").unwrap_or(f64::NAN),
        steps_per_s: number("steps_per_s"),
        success_rate: number("success_rate"),
        skipped_steps: column(cell, "skipped_steps").unwrap_or(0),
        // Not a column: a logged row is one that was used.
        applied_steps: 0,
    }
}

/// Rows with a cell for every column and a timestep count: a crash mid-write leaves neither.
fn complete_rows(table: &Table) -> impl Iterator<Item = Row<'_>> {
    table.rows().filter(|r| r.line.split(',').count() == table.header.len() && r.get::<u64>("timesteps").is_some())
}

/// Appends one row of named cells to the CSV file at `path`, writing the header first if the
/// file is new. The row goes out in one write, so a crash cannot leave half of it.
fn append_row(path: &Path, cells: &[(&str, String)]) -> anyhow::Result<()> {
    let io = |e: std::io::Error| anyhow::anyhow!("{}: {e}", path.display());
    let mut file = std::fs::OpenOptions::new().create(true).append(true).open(path).map_err(io)?;
    let mut text = String::new();
    if file.metadata().map_err(io)?.len() == 0 {
        text += &cells.iter().map(|(name, _)| *name).collect::<Vec<_>>().join(",");
        text.push('\n');
    }
    text += &cells.iter().map(|(_, value)| value.as_str()).collect::<Vec<_>>().join(",");
    text.push('\n');
    file.write_all(text.as_bytes()).map_err(io)
}

/// Every checkpoint's list of its files with their sizes and CRC-32C, checked before it is
/// resumed from: a flipped byte or a missing file (the optimizer's) makes it unusable, not
/// silently different.
pub const CHECKSUMS_FILE: &str = "checksums.json";

const CRC32C: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// Each file's size and CRC-32C, by name.
type Checksums = std::collections::BTreeMap<String, (u64, u32)>;

fn checksums_of(dir: &Path) -> anyhow::Result<Checksums> {
    let mut sums = Checksums::new();
    let entries = std::fs::read_dir(dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
    for entry in entries {
        let path = entry?.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
        if name == CHECKSUMS_FILE || !path.is_file() {
            continue;
        }
        let bytes = std::fs::read(&path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        sums.insert(name, (bytes.len() as u64, CRC32C.checksum(&bytes)));
    }
    Ok(sums)
}

fn write_checksums(dir: &Path) -> anyhow::Result<()> {
    twinbots_api::files::write_json(&dir.join(CHECKSUMS_FILE), &checksums_of(dir)?)
}

/// Checks a checkpoint against its checksums (one saved before checksums were kept has none:
/// it loads as it is).
fn verify_checksums(dir: &Path) -> anyhow::Result<()> {
    let path = dir.join(CHECKSUMS_FILE);
    if !path.exists() {
        return Ok(());
    }
    let text = std::fs::read_to_string(&path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let expected: Checksums = serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let found = checksums_of(dir)?;
    for (name, (bytes, crc)) in &expected {
        match found.get(name) {
            None => anyhow::bail!("its {name} is missing"),
            Some((b, c)) if b != bytes || c != crc => {
                anyhow::bail!(
                    "its {name} is not as saved ({b} bytes, CRC-32C {c:08x}; saved: {bytes} bytes, {crc:08x})"
                )
            }
            Some(_) => {}
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_run(name: &str) -> RunDir {
        let path = std::env::temp_dir().join(format!("twinbots-run-dir-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        let run = RunDir::new(path);
        run.create().unwrap();
        run
    }

    #[test]
    fn progress_rows_read_back_by_name_and_truncate_to_a_checkpoint() {
        let run = temp_run("progress");
        for update in 1..=4 {
            let stats = UpdateStats {
                update,
                timesteps: 64 * update as u64,
                mean_reward: update as f32,
                success_rate: f32::NAN,
                ..Default::default()
            };
            run.append_progress(&stats).unwrap();
        }
        // A crash in the middle of a row.
        std::fs::OpenOptions::new().append(true).open(run.file(PROGRESS)).unwrap().write_all(b"5,320,1").unwrap();
        let rows = run.read_progress().unwrap();
        assert_eq!(rows.iter().map(|s| s.timesteps).collect::<Vec<_>>(), [64, 128, 192, 256]);
        assert_eq!(rows[2].mean_reward, 3.0);
        assert!(rows[0].success_rate.is_nan());
        run.check_progress_columns(&[]).unwrap();

        run.truncate_after(128).unwrap();
        let rows = run.read_progress().unwrap();
        assert_eq!(rows.iter().map(|s| s.update).collect::<Vec<_>>(), [1, 2]);
        let text = std::fs::read_to_string(run.file(PROGRESS)).unwrap();
        assert!(text.starts_with("update,timesteps,episodes,mean_reward,") && text.ends_with("\n"), "{text}");
        std::fs::remove_dir_all(run.path()).ok();
    }

    #[test]
    fn a_progress_file_with_other_columns_is_refused() {
        let run = temp_run("columns");
        std::fs::write(run.file(PROGRESS), "timesteps,update\n64,1\n").unwrap();
        let err = run.check_progress_columns(&[]).unwrap_err().to_string();
        assert!(err.contains("timesteps,update"), "{err}");
        // It still reads, by name.
        assert_eq!(run.read_progress().unwrap()[0].update, 1);
        std::fs::remove_dir_all(run.path()).ok();
    }
}
