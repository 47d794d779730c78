//! The settings a training run is made of (its `config.toml`): how they resolve from the
//! robot's defaults, a `--config` file and flags, and how they are checked. Shared by the CLI
//! and the Python extension (whose RLlib runs write the same `config.toml`).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use twinbots_api::DesignPattern;
use twinbots_learn::RunDir;
use twinbots_learn::algos;
use twinbots_learn::learner::{Algorithm, config_from};
use twinbots_render::PixelSettings;
use twinbots_task::randomization::Randomization;

use crate::registry::RobotEntry;

mod calibration;
pub use calibration::CalibrationSetting;

/// The plain settings, as a config file names them (the algorithms' tables come on top).
const KEYS: &str = "task, timesteps, arenas, seed, pattern, checkpoint_every, eval_every, eval_episodes, algo, [randomization], [calibration], [pixels], [cell]";

/// Everything a run is made of; written to `config.toml`, read by `--config` and `--resume`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainSettings {
    pub robot: String,
    /// The task learnt (`--task`): one of the robot's tasks that train; none, its main task.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub task: Option<String>,
    pub timesteps: u64,
    pub arenas: usize,
    pub seed: u64,
    /// Design pattern (paper §3): 1 supervised, 2 supervisor + slave over radio, 3 RobotServer.
    pub pattern: u8,
    /// Save a checkpoint (and redraw the learning curve) every this many updates.
    pub checkpoint_every: usize,
    /// Evaluate the deterministic policy every this many updates into `evaluations.csv`
    /// (0: never); an evaluation of at least the solved criterion's window of episodes that
    /// meets it ends training (SB3's EvalCallback with a stop threshold); one that can no
    /// longer meet it stops early. The final model is always evaluated into `eval.json`.
    pub eval_every: usize,
    pub eval_episodes: usize,
    /// The learner: a name of `twinbots_learn::algos::ALGOS` (`twinbots algos` lists them).
    /// Runs written before there was a choice are PPO runs.
    #[serde(default = "first_algorithm")]
    pub algo: String,
    /// Domain randomization (patterns 1 and 2): see `twinbots_task::randomization`.
    #[serde(default)]
    pub randomization: Randomization,
    /// The twin's calibration, if the run has one (`--calibration`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationSetting>,
    /// Pixel observations: the policy sees a camera image instead of the task's state
    /// (`twinbots_render::pixels`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixels: Option<PixelSettings>,
    /// The cell's layout (`--cell FILE`, docs/cells.md), recorded in full: the run does not
    /// depend on the file afterwards. None: the robot's default cell.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cell: Option<toml::Table>,
    /// The algorithms' hyperparameters, each its `[<algo>]` table: the run's own in full, and
    /// any other a config file named (checked, and kept for a later run).
    #[serde(flatten)]
    pub hyperparams: BTreeMap<String, toml::Value>,
}

fn first_algorithm() -> String {
    algos::ALGOS[0].name.into()
}

/// What a `--config` file may set: any subset of the settings but the robot.
#[derive(Clone, Debug, Default, Deserialize)]
pub struct ConfigFile {
    pub task: Option<String>,
    pub timesteps: Option<u64>,
    pub arenas: Option<usize>,
    pub seed: Option<u64>,
    pub pattern: Option<u8>,
    pub checkpoint_every: Option<usize>,
    pub eval_every: Option<usize>,
    pub eval_episodes: Option<usize>,
    pub algo: Option<String>,
    pub randomization: Option<Randomization>,
    pub calibration: Option<CalibrationSetting>,
    pub pixels: Option<PixelSettings>,
    pub cell: Option<toml::Table>,
    /// `[<algo>]` tables, only the keys given: each replaces that key of the robot's tuned
    /// settings (and of the algorithm's defaults).
    #[serde(flatten)]
    pub hyperparams: BTreeMap<String, toml::Value>,
}

/// `value` as the table `[name]` of a known algorithm; anything else is an error naming the key.
fn algorithm_table<'v>(name: &str, value: &'v toml::Value) -> anyhow::Result<(&'static Algorithm, &'v toml::Table)> {
    let algorithm = algos::find(name).map_err(|_| {
        anyhow::anyhow!(
            "unknown field `{name}`: a config file holds {KEYS} and the tables [{}]",
            algos::names().join("], [")
        )
    })?;
    let table =
        value.as_table().ok_or_else(|| anyhow::anyhow!("{name} = {value}: must be a table ([{name}] and its keys)"))?;
    Ok((algorithm, table))
}

/// Reads a cell layout file (`--cell`) as the table a run's settings keep, checked by the robot.
pub fn read_cell(entry: &RobotEntry, path: &Path) -> anyhow::Result<toml::Table> {
    let text = std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let table: toml::Table = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let description =
        entry.cell.ok_or_else(|| anyhow::anyhow!("--cell: {}'s cell is not laid out by a file", entry.name))?;
    (description.install)(&mut bevy::prelude::App::new(), &text, &path.display().to_string())
        .map_err(anyhow::Error::msg)?;
    Ok(table)
}

/// Makes `cell` (a layout as a table) every arena's in `app`.
fn install_cell(app: &mut bevy::prelude::App, entry: &RobotEntry, cell: &toml::Table) -> anyhow::Result<()> {
    let description =
        entry.cell.ok_or_else(|| anyhow::anyhow!("[cell]: {}'s cell is not laid out by a file", entry.name))?;
    (description.install)(app, &toml::to_string(cell)?, "[cell]").map_err(anyhow::Error::msg)
}

impl ConfigFile {
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("{}: cannot read config: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// A config file's text. Read as TOML first, so a value TOML cannot hold is reported at its
    /// line (the algorithms' tables are kept whole, which loses the place in serde's error).
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        let table: toml::Table = toml::from_str(text)?;
        Ok(table.try_into()?)
    }
}

impl TrainSettings {
    /// Puts the run's calibration (if any) over the twin's nominal parameters in `app`, before
    /// its start-up applies them ([`CalibrationSetting::configure`]).
    pub fn calibrate(&self, app: &mut bevy::prelude::App) {
        if let Some(c) = &self.calibration {
            c.configure(app);
        }
    }

    /// The run's calibrated parameters (none without a calibration).
    pub fn calibration_parameters(&self) -> twinbots_sim::Parameters {
        self.calibration.as_ref().map(CalibrationSetting::parameters).unwrap_or_default()
    }

    /// The settings a run directory was made with (its `config.toml`).
    pub fn of_run(run: &RunDir) -> anyhow::Result<Self> {
        let settings: Self = run.read_config()?;
        settings
            .validate()
            .map_err(|e| anyhow::anyhow!("{}: {e}", run.file(twinbots_learn::run_dir::CONFIG).display()))?;
        Ok(settings)
    }

    /// A complete settings file (such as a run's `config.toml`) anywhere.
    pub fn read_file(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let settings: Self = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        settings.validate().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(settings)
    }

    /// A clear error naming the first setting outside its range, before anything runs: counts
    /// of at least one, every algorithm table (its `Algorithm::config`) and the randomization
    /// ranges.
    /// A minibatch larger than a rollout is allowed: it takes the whole rollout, as in SB3.
    pub fn validate(&self) -> anyhow::Result<()> {
        for (key, value) in [
            ("timesteps", self.timesteps),
            ("arenas", self.arenas as u64),
            ("checkpoint_every", self.checkpoint_every as u64),
            ("eval_episodes", self.eval_episodes as u64),
        ] {
            anyhow::ensure!(value >= 1, "{key} = {value}: must be a whole number ≥ 1");
        }
        anyhow::ensure!(self.arenas <= 4096, "arenas = {}: must be at most 4096", self.arenas);
        anyhow::ensure!(
            self.eval_episodes <= 100_000,
            "eval_episodes = {}: must be at most 100000",
            self.eval_episodes
        );
        let algorithm = algos::find(&self.algo).map_err(|e| anyhow::anyhow!("algo = {:?}: {e}", self.algo))?;
        if !algorithm.serves {
            let serving: Vec<&str> = algos::ALGOS.iter().filter(|a| a.serves).map(|a| a.name).collect();
            anyhow::ensure!(
                self.design_pattern()? != DesignPattern::Server,
                "algo = {}: design pattern 3 (the RobotServer) trains with {} only; use pattern 1 or 2",
                self.algo,
                serving.join(", ")
            );
        }
        // Every table is checked, whichever learner runs: a typo is never kept silently.
        for (name, value) in &self.hyperparams {
            let (algorithm, table) = algorithm_table(name, value)?;
            (algorithm.config)(table, self.arenas)?;
        }
        self.design_pattern()?;
        self.randomization.validate()?;
        CalibrationSetting::check_randomization(self.calibration.as_ref(), &self.randomization)?;
        anyhow::ensure!(
            self.cell.is_none() || self.design_pattern()? != DesignPattern::Server,
            "[cell]: design pattern 3's robots build their own (default) cell; use pattern 1 or 2"
        );
        if let Some(pixels) = &self.pixels {
            pixels.validate()?;
            anyhow::ensure!(
                self.design_pattern()? != DesignPattern::Server,
                "[pixels]: design pattern 3 sends the robot's own readings, not the twin's images; use pattern 1 or 2"
            );
        }
        Ok(())
    }

    /// The task the run's model learns (the robot's main task unless `task` names another),
    /// observed through the camera with `[pixels]`.
    pub fn task(&self, entry: &RobotEntry) -> anyhow::Result<twinbots_api::TaskSpec> {
        let mut spec = (entry.trained_task(self.task.as_deref()).map_err(|e| anyhow::anyhow!("task: {e}"))?.0.spec)();
        if let Some(pixels) = &self.pixels {
            pixels.observe_task(&mut spec)?;
        }
        Ok(spec)
    }

    /// The name of the task the run learns.
    pub fn task_name(&self, entry: &RobotEntry) -> anyhow::Result<&'static str> {
        Ok(entry.trained_task(self.task.as_deref()).map_err(|e| anyhow::anyhow!("task: {e}"))?.0.name)
    }

    /// The task a model drives in another command (`capture`, `view`): `task` if named, else
    /// the task the model's run (`model`, if any) learnt, else the robot's main one (`None`).
    pub fn task_for(task: Option<&str>, model: Option<&Path>) -> anyhow::Result<Option<String>> {
        match (task, model) {
            (Some(task), _) => Ok(Some(task.to_string())),
            (None, Some(run)) => Ok(Self::of_run(&RunDir::new(run))?.task),
            (None, None) => Ok(None),
        }
    }

    /// [`TrainSettings::observe`] with the settings of the run in `run`: a model of that run
    /// driving an app of another command (`capture --model`, `view --model`) sees what it
    /// learnt on.
    pub fn observe_as_run(
        run: &Path,
        app: &mut bevy::prelude::App,
        entry: &RobotEntry,
        arenas: usize,
    ) -> anyhow::Result<()> {
        Self::of_run(&RunDir::new(run))?.observe(app, entry, arenas)
    }

    /// Sets up a robot's `app` of `arenas` arenas as the run's envs are, before its start-up:
    /// the cell's layout with `[cell]`, pixel observations with `[pixels]` (an error when no
    /// graphics adapter exists).
    pub fn observe(&self, app: &mut bevy::prelude::App, entry: &RobotEntry, arenas: usize) -> anyhow::Result<()> {
        if let Some(cell) = &self.cell {
            install_cell(app, entry, cell)?;
        }
        match &self.pixels {
            Some(pixels) => pixels.install(app, &entry.framing, arenas),
            None => Ok(()),
        }
    }

    pub fn design_pattern(&self) -> anyhow::Result<DesignPattern> {
        DesignPattern::from_number(self.pattern)
            .ok_or_else(|| anyhow::anyhow!("pattern must be 1, 2 or 3, got {}", self.pattern))
    }

    /// The pattern the run's model runs under in this process (evaluation): its own, except
    /// that a pattern-3 model runs under pattern 1 (the policy is the same; only where it is
    /// hosted differs).
    pub fn in_process_pattern(&self) -> anyhow::Result<DesignPattern> {
        Ok(match self.design_pattern()? {
            DesignPattern::Server => DesignPattern::Supervised,
            p => p,
        })
    }

    /// The seed of the periodic evaluations (the same each time, so they compare).
    pub fn periodic_eval_seed(&self) -> u64 {
        self.seed.wrapping_add(twinbots_api::seeds::PERIODIC_EVALUATION)
    }

    /// The seed of the final model's evaluation (`eval.json`, `twinbots eval`).
    pub fn final_eval_seed(&self) -> u64 {
        self.seed.wrapping_add(twinbots_api::seeds::FINAL_EVALUATION)
    }

    /// The run's algorithm.
    pub fn algorithm(&self) -> anyhow::Result<&'static Algorithm> {
        algos::find(&self.algo)
    }

    /// The `[<name>]` table in full (the algorithm's defaults where the settings name none).
    pub fn table_of(&self, name: &str) -> anyhow::Result<toml::Table> {
        let algorithm = algos::find(name)?;
        let keys = match self.hyperparams.get(name) {
            Some(value) => algorithm_table(name, value)?.1.clone(),
            None => toml::Table::new(),
        };
        (algorithm.config)(&keys, self.arenas)
    }

    /// The `[<name>]` table as the algorithm's own config type (`PpoConfig`).
    pub fn config_of<T: Serialize + serde::de::DeserializeOwned + Default>(&self, name: &str) -> anyhow::Result<T> {
        config_from(&self.table_of(name)?, name)
    }

    /// The robot's defaults, then the config file, then command-line flags, key by key (an
    /// `[<algo>]` table replaces only the keys it names, over the robot's tuning of that
    /// algorithm); the result is validated. The robot's defaults for the chosen algorithm
    /// (arenas, budget, evaluation interval) come first.
    pub fn resolve(entry: &RobotEntry, file: ConfigFile, flags: ConfigFile) -> anyhow::Result<Self> {
        let task = flags.task.clone().or(file.task.clone());
        let (description, defaults) = entry.trained_task(task.as_deref()).map_err(|e| anyhow::anyhow!("task: {e}"))?;
        let name = flags.algo.clone().or(file.algo.clone()).unwrap_or_else(|| defaults.algo.to_string());
        let algorithm = algos::find(&name).map_err(|e| anyhow::anyhow!("algo = {name:?}: {e}"))?;
        let chosen = defaults.of(algorithm.name);
        let mut s = Self {
            robot: entry.name.to_string(),
            // The main task is left unnamed: its runs read as they always did.
            task: task.filter(|t| t != entry.main_task().name),
            timesteps: chosen.timesteps,
            arenas: chosen.arenas,
            seed: 0,
            pattern: 1,
            checkpoint_every: 10,
            eval_every: chosen.eval_every,
            eval_episodes: defaults.eval_episodes,
            algo: algorithm.name.to_string(),
            randomization: Randomization::default(),
            calibration: None,
            pixels: None,
            cell: None,
            hyperparams: BTreeMap::new(),
        };
        if algorithm.continuous_only {
            let actions = (description.spec)().action_space;
            anyhow::ensure!(
                matches!(actions, twinbots_api::Space::Box { .. }),
                "algo = {}: {}'s actions are {actions}; {} needs continuous (Box) actions: use algo = {}",
                algorithm.name,
                entry.name,
                algorithm.name.to_uppercase(),
                algos::ALGOS[0].name
            );
        }
        // Each table named anywhere starts from the robot's tuning of that algorithm.
        let tuned = |algorithm: &Algorithm| -> anyhow::Result<toml::Table> {
            defaults.of(algorithm.name).keys().map_err(|e| anyhow::anyhow!("robot {}: {e}", entry.name))
        };
        let mut tables: BTreeMap<String, toml::Table> =
            BTreeMap::from([(algorithm.name.to_string(), tuned(algorithm)?)]);
        for layer in [file, flags] {
            s.timesteps = layer.timesteps.unwrap_or(s.timesteps);
            s.arenas = layer.arenas.unwrap_or(s.arenas);
            s.seed = layer.seed.unwrap_or(s.seed);
            s.pattern = layer.pattern.unwrap_or(s.pattern);
            s.checkpoint_every = layer.checkpoint_every.unwrap_or(s.checkpoint_every);
            s.eval_every = layer.eval_every.unwrap_or(s.eval_every);
            s.eval_episodes = layer.eval_episodes.unwrap_or(s.eval_episodes);
            s.randomization = layer.randomization.unwrap_or(s.randomization);
            s.calibration = layer.calibration.or(s.calibration);
            s.pixels = layer.pixels.or(s.pixels);
            s.cell = layer.cell.or(s.cell);
            for (name, value) in &layer.hyperparams {
                let (algorithm, keys) = algorithm_table(name, value)?;
                let table = match tables.remove(name) {
                    Some(table) => table,
                    None => tuned(algorithm)?,
                };
                let mut merged = table;
                merged.extend(keys.clone());
                tables.insert(name.clone(), merged);
            }
        }
        for (name, keys) in tables {
            let algorithm = algos::find(&name)?;
            s.hyperparams.insert(name, toml::Value::Table((algorithm.config)(&keys, s.arenas)?));
        }
        s.validate()?;
        Ok(s)
    }
}

#[cfg(test)]
mod tests;
