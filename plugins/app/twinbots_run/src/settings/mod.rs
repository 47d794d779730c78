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
use twinbots_task::randomization::{FitSpread, Randomization};

use crate::registry::RobotEntry;

/// Evaluation arenas are seeded away from the training seed, so they never replay training's
/// episodes (primes, far apart: no run's seed range reaches them).
pub const PERIODIC_EVAL_SEED_OFFSET: u64 = 1_000_003;
pub const FINAL_EVAL_SEED_OFFSET: u64 = 2_000_003;

/// The plain settings, as a config file names them (the algorithms' tables come on top).
const KEYS: &str = "task, timesteps, arenas, seed, pattern, checkpoint_every, eval_every, eval_episodes, algo, [randomization], [calibration], [pixels], [cell]";

/// The twin's calibration (`twinbots identify`'s file), recorded in full in the run's
/// `config.toml`: the run does not depend on the file afterwards.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSetting {
    /// The file it was read from.
    pub file: String,
    /// Its `[parameters]`, over the robot's nominal ones.
    pub parameters: BTreeMap<String, f64>,
    /// Its `[spread]`: each fitted value's standard deviation, which
    /// `randomization.calibration_spread` draws with (none in a hand-written file).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub spread: BTreeMap<String, f64>,
}

impl CalibrationSetting {
    /// Reads a calibration file, checked against the robot's parameters.
    pub fn read(entry: &RobotEntry, path: &Path) -> anyhow::Result<Self> {
        let rig = twinbots_sysid::Rig::of(entry)?;
        let (params, spread) =
            twinbots_task::calibration::read_calibration_with_spread(path, &rig.catalogue, rig.robot)?;
        Ok(Self { file: path.display().to_string(), parameters: params.0, spread: spread.0 })
    }

    /// [`CalibrationSetting::read`] of the file, if one is given.
    pub fn read_optional(entry: &RobotEntry, path: Option<&Path>) -> anyhow::Result<Option<Self>> {
        path.map(|path| Self::read(entry, path)).transpose()
    }

    /// The parameters as the resource apps take.
    pub fn parameters(&self) -> twinbots_sim::Parameters {
        twinbots_sim::Parameters(self.parameters.clone())
    }

    /// Puts the calibration over the twin's nominal parameters in `app`, before its start-up
    /// applies them, and its spread where randomization can draw with it.
    pub fn configure(&self, app: &mut bevy::prelude::App) {
        twinbots_task::calibration::calibrate(app, &self.parameters());
        app.insert_resource(FitSpread(twinbots_sim::Parameters(self.spread.clone())));
    }

    /// `randomization`'s check that a spread it draws with is there.
    pub fn check_randomization(calibration: Option<&Self>, randomization: &Randomization) -> anyhow::Result<()> {
        randomization.check_spread(calibration.is_some_and(|c| !c.spread.is_empty()))
    }
}

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
        self.seed.wrapping_add(PERIODIC_EVAL_SEED_OFFSET)
    }

    /// The seed of the final model's evaluation (`eval.json`, `twinbots eval`).
    pub fn final_eval_seed(&self) -> u64 {
        self.seed.wrapping_add(FINAL_EVAL_SEED_OFFSET)
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
mod tests {
    use rand::{Rng, SeedableRng};
    use twinbots_learn::SacConfig;

    use super::*;

    #[test]
    fn sac_settings_resolve_from_the_robots_sac_defaults_key_by_key_and_refuse_what_sac_cannot_do() {
        let ur5e = crate::registry::find("ur5e").unwrap();
        let file: ConfigFile = toml::from_str("algo = \"sac\"\n[sac]\nbatch_size = 128\n").unwrap();
        let s = TrainSettings::resolve(&ur5e, file, ConfigFile::default()).unwrap();
        let defaults = ur5e.defaults.of("sac");
        assert_eq!(
            (s.algo.as_str(), s.arenas, s.timesteps, s.eval_every),
            ("sac", defaults.arenas, defaults.timesteps, defaults.eval_every)
        );
        let tuned: SacConfig = defaults.config().unwrap();
        assert_eq!(
            s.config_of::<SacConfig>("sac").unwrap(),
            SacConfig { batch_size: 128, ..tuned },
            "a [sac] key replaced more than itself"
        );
        let flags = ConfigFile { algo: Some("ppo".into()), ..Default::default() };
        let file: ConfigFile = toml::from_str("algo = \"sac\"\n").unwrap();
        assert_eq!(TrainSettings::resolve(&ur5e, file, flags).unwrap().algo, "ppo", "the flag did not win");

        let sac = || ConfigFile { algo: Some("sac".into()), ..Default::default() };
        let cartpole = crate::registry::find("cartpole").unwrap();
        let err = TrainSettings::resolve(&cartpole, sac(), ConfigFile::default()).unwrap_err().to_string();
        assert!(err.contains("algo = sac") && err.contains("Box"), "{err}");
        let pattern3 = ConfigFile { pattern: Some(3), ..Default::default() };
        // The RobotServer trains SAC too (its line of the table says it `serves`).
        assert_eq!(TrainSettings::resolve(&ur5e, sac(), pattern3).unwrap().algo, "sac");
        let file: ConfigFile = toml::from_str("[sac]\ntau = 2.0\n").unwrap();
        let err = TrainSettings::resolve(&ur5e, file, sac()).unwrap_err().to_string();
        assert!(err.starts_with("sac.tau = 2"), "{err}");
    }

    /// Every key a config file may hold, with the kind of value it takes.
    const KEYS: &[&str] = &[
        "task",
        "timesteps",
        "arenas",
        "seed",
        "pattern",
        "checkpoint_every",
        "eval_every",
        "eval_episodes",
        "ppo.learning_rate",
        "ppo.linear_lr",
        "ppo.n_steps",
        "ppo.batch_size",
        "ppo.n_epochs",
        "ppo.gamma",
        "ppo.gae_lambda",
        "ppo.clip_range",
        "ppo.ent_coef",
        "ppo.vf_coef",
        "ppo.max_grad_norm",
        "ppo.target_kl",
        "ppo.normalize_advantage",
        "ppo.normalize_observations",
        "ppo.hidden",
        "ppo.log_std_init",
        "ppo.no_such_key",
        "algo",
        "sac.learning_rate",
        "sac.buffer_size",
        "sac.learning_starts",
        "sac.batch_size",
        "sac.tau",
        "sac.gamma",
        "sac.train_freq",
        "sac.gradient_steps",
        "sac.learn_ent_coef",
        "sac.ent_coef_init",
        "sac.target_entropy",
        "sac.target_update_interval",
        "sac.hidden",
        "sac.normalize_observations",
        "sac.log_interval",
        "sac.her_goals",
        "sac.typo",
        "randomization.start_window",
        "randomization.action_probability",
        "randomization.mass_scale",
        "randomization.friction",
        "randomization.motor_strength",
        "randomization.sensor_noise",
        "randomization.action_latency",
        "randomization.typo",
        "randomization.visual.lights",
        "randomization.visual.light_intensity",
        "randomization.visual.field_of_view",
        "randomization.visual.ambient",
        "randomization.visual.textures",
        "randomization.visual.typo",
    ];
    const VALUES: &[&str] = &[
        "0",
        "1",
        "-1",
        "2",
        "3",
        "64",
        "4096",
        "4097",
        "18446744073709551615",
        "-9223372036854775808",
        "0.5",
        "1e-300",
        "1e300",
        "1e39",
        "nan",
        "inf",
        "-inf",
        "true",
        "\"x\"",
        "[]",
        "[0]",
        "[64, 64]",
        "[1.0, 0.5]",
        "[0.5, 1.0]",
        "[0, inf]",
        "[nan, 1]",
        "[1, 2, 3]",
        "[100000000, 1]",
        "{}",
        "\"sac\"",
        "\"ppo\"",
        "\"balance\"",
    ];

    /// Random config files made of real keys and hostile values: every one resolves to valid
    /// settings or to an error naming a key, and none panics.
    #[test]
    fn no_config_file_panics_and_every_refusal_names_its_key() {
        let entry = crate::registry::find("cartpole").unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let (mut accepted, mut refused) = (0, 0);
        for _ in 0..20_000 {
            let mut tables: std::collections::BTreeMap<&str, Vec<String>> = Default::default();
            for _ in 0..rng.random_range(1..4) {
                let key = KEYS[rng.random_range(0..KEYS.len())];
                let value = VALUES[rng.random_range(0..VALUES.len())];
                let (table, name) = key.split_once('.').unwrap_or(("", key));
                tables.entry(table).or_default().push(format!("{name} = {value}"));
            }
            let mut text = String::new();
            for (table, lines) in &tables {
                if !table.is_empty() {
                    text += &format!("[{table}]\n");
                }
                for line in lines {
                    text += line;
                    text.push('\n');
                }
            }
            let outcome =
                ConfigFile::parse(&text).and_then(|file| TrainSettings::resolve(&entry, file, ConfigFile::default()));
            match outcome {
                Ok(settings) => {
                    settings.validate().unwrap();
                    accepted += 1;
                }
                Err(e) => {
                    let message = format!("{e:#}");
                    let named = KEYS.iter().any(|k| message.contains(k.rsplit('.').next().unwrap()))
                        || message.contains("duplicate key");
                    assert!(named, "{text:?} was refused without naming a key: {message}");
                    refused += 1;
                }
            }
        }
        assert!(accepted > 800 && refused > 1000, "{accepted} accepted, {refused} refused: the values are not a mix");
    }
}
