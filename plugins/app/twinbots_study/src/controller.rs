//! What drives the twin in a study: the robot's classical controller, a trained run, or an
//! exported ONNX policy, each on the twin it belongs with.

use std::path::Path;

use twinbots_api::VecEnv;
use twinbots_learn::{Learner, RunDir};
use twinbots_onnx::OnnxPolicy;
use twinbots_task::robot::Feedback;
use twinbots_task::{AppVecEnv, DesignPattern};

use twinbots_run::registry::RobotEntry;
use twinbots_run::run::evaluation_app;
use twinbots_run::settings::TrainSettings;

/// A controller named in a study.
pub enum Controller {
    Classic(Feedback),
    Run { settings: Box<TrainSettings>, model: Box<dyn Learner> },
    Onnx(Box<OnnxPolicy>),
}

/// A controller and the name its results go under.
pub struct NamedController {
    /// `classic`, the run directory's or the ONNX file's name.
    pub label: String,
    /// As the study names it.
    pub spec: String,
    pub controller: Controller,
}

impl NamedController {
    /// Opens `spec`: `classic`, a run directory or an `.onnx` file (relative to `base`), for
    /// `entry`'s main task. Errors say which and why.
    pub fn open(spec: &str, base: &Path, entry: &RobotEntry) -> anyhow::Result<Self> {
        Self::open_for(spec, base, entry, None)
    }

    /// [`NamedController::open`] for the named task (`None`: the main one): `classic` is that
    /// task's scripted controller where it has one.
    pub fn open_for(spec: &str, base: &Path, entry: &RobotEntry, task: Option<&str>) -> anyhow::Result<Self> {
        if spec == "classic" {
            let feedback = entry.classic(task).map_err(|e| anyhow::anyhow!("controller 'classic': {e}"))?;
            return Ok(Self { label: spec.into(), spec: spec.into(), controller: Controller::Classic(feedback) });
        }
        let path = base.join(spec);
        let label = path.file_name().map_or_else(|| spec.to_string(), |s| s.to_string_lossy().to_string());
        let controller = if path.extension().is_some_and(|e| e == "onnx") {
            let policy = OnnxPolicy::load(&path)?;
            anyhow::ensure!(
                policy.metadata.robot == entry.name,
                "controller '{spec}': a policy of {}, not of {}",
                policy.metadata.robot,
                entry.name
            );
            Controller::Onnx(Box::new(policy))
        } else if path.is_dir() {
            let run = RunDir::new(&path);
            let settings = TrainSettings::of_run(&run)?;
            anyhow::ensure!(
                settings.robot == entry.name,
                "controller '{spec}': a run of {}, not of {}",
                settings.robot,
                entry.name
            );
            anyhow::ensure!(
                settings.pixels.is_none(),
                "controller '{spec}': a pixel policy; studies read their signal from the state the task observes, so they take state policies"
            );
            Controller::Run { model: twinbots_learn::algos::load_run(&run)?, settings: Box::new(settings) }
        } else {
            anyhow::bail!(
                "controller '{spec}': neither 'classic', a run directory nor an .onnx file ({} does not exist)",
                path.display()
            );
        };
        Ok(Self { label, spec: spec.into(), controller })
    }

    /// `arenas` arenas of the robot's `task` (`None`: its main one) as this controller runs it:
    /// a run's model on its own twin (pattern, calibration), the others on the nominal twin
    /// under design pattern 1. `prepare` adds to the app before its start-up.
    pub fn env(
        &self,
        entry: &RobotEntry,
        task: Option<&str>,
        arenas: usize,
        seed: u64,
        prepare: impl FnOnce(&mut bevy::app::App) -> anyhow::Result<()>,
    ) -> anyhow::Result<AppVecEnv> {
        let mut app = match &self.controller {
            Controller::Run { settings, .. } => {
                evaluation_app(entry, task, arenas, seed, settings, &settings.calibration_parameters())?
            }
            _ => entry.app(task, arenas, seed, DesignPattern::Supervised)?,
        };
        prepare(&mut app)?;
        let env = AppVecEnv::new(app);
        let (observation, action) = (env.observation_space(), env.action_space());
        match &self.controller {
            Controller::Run { model, .. } => model.check_spaces(observation, action)?,
            Controller::Onnx(policy) => anyhow::ensure!(
                &policy.metadata.observation_space == observation && &policy.metadata.action_space == action,
                "controller '{}': the policy's spaces do not match {}'s task",
                self.spec,
                entry.name
            ),
            Controller::Classic(_) => {}
        }
        Ok(env)
    }

    /// The actions for rows of observations (`dim` values each).
    pub fn act(&self, obs: &[f32], dim: usize) -> anyhow::Result<Vec<f32>> {
        match &self.controller {
            Controller::Classic(feedback) => Ok(obs.chunks(dim).flat_map(|o| feedback(o)).collect()),
            Controller::Run { model, .. } => model.predict_deterministic(obs),
            Controller::Onnx(policy) => policy.act(obs),
        }
    }
}

/// The controllers of a study: `cli`'s if any (paths from the working directory), else the
/// study file's `listed` (paths from its folder; errors name the file), with distinct labels.
pub fn open_all(
    entry: &RobotEntry,
    file: &Path,
    listed: &[String],
    cli: &[String],
) -> anyhow::Result<Vec<NamedController>> {
    let mut named = if cli.is_empty() {
        let base = file.parent().unwrap_or(Path::new("."));
        let open = |s: &String| {
            NamedController::open(s, base, entry).map_err(|e| anyhow::anyhow!("{}: {e:#}", file.display()))
        };
        listed.iter().map(open).collect::<anyhow::Result<Vec<_>>>()?
    } else {
        cli.iter().map(|s| NamedController::open(s, Path::new("."), entry)).collect::<anyhow::Result<Vec<_>>>()?
    };
    distinct_labels(&mut named);
    Ok(named)
}

/// Resets every arena so that arena i starts as the first arena would from `seeds[i]`: runs
/// that must begin alike whatever arena they occupy share a stream. Returns the observations.
pub fn reset_alike(env: &mut AppVecEnv, seeds: &[u64]) -> anyhow::Result<Vec<f32>> {
    env.reset(Some(seeds[0]))?;
    let arenas = env.arenas().to_vec();
    for (arena, &seed) in arenas.into_iter().zip(seeds) {
        if let Some(mut a) = env.app_mut().world_mut().get_mut::<twinbots_sim::Arena>(arena) {
            a.reseed_as(seed, 0);
        }
    }
    env.reset(None)
}

/// Directory-safe labels: a second controller with the same label gets `-2`, and so on.
fn distinct_labels(controllers: &mut [NamedController]) {
    let mut seen: Vec<String> = Vec::new();
    for c in controllers.iter_mut() {
        let mut label = c.label.clone();
        let mut n = 1;
        while seen.contains(&label) {
            n += 1;
            label = format!("{}-{n}", c.label);
        }
        seen.push(label.clone());
        c.label = label;
    }
}
