//! `twinbots export <run-dir> --onnx FILE`: the run's trained policy (PPO or SAC) as an ONNX graph, with
//! what a robot's program needs to know about it (docs/export.md).

use std::path::Path;

use twinbots::settings::Algo;
use twinbots_onnx::{PolicyMetadata, Trained};
use twinbots_task::ActiveTask;
use twinbots_learn::{RunDir, Sac};
use twinbots_sim::SimSettings;

use crate::cli::runs::TrainSettings;
use crate::registry;

/// Writes the run's model (its final one, else its newest checkpoint) to `onnx` and returns the
/// description written with it.
pub fn export_run(run: &Path, onnx: &Path) -> anyhow::Result<PolicyMetadata> {
    let run_dir = RunDir::new(run);
    let settings = TrainSettings::of_run(&run_dir)?;
    let entry = registry::find(&settings.robot)?;
    let (ppo, sac);
    let model: Trained = match settings.algo {
        Algo::Ppo => {
            ppo = run_dir.load_model()?;
            (&ppo).into()
        }
        Algo::Sac => {
            sac = run_dir.load_trained::<Sac>()?;
            (&sac).into()
        }
    };
    // The robot's own description of its task and timing, as an app of it declares them.
    let app = entry.app(None, 1, settings.seed, settings.in_process_pattern()?)?;
    let spec = &**app.world().resource::<ActiveTask>();
    let control_period_s = app.world().resource::<SimSettings>().control_dt();
    model.agent().check_spaces(&spec.observation_space, &spec.action_space)?;
    let metadata = PolicyMetadata {
        twinbots_version: env!("CARGO_PKG_VERSION").into(),
        robot: settings.robot.clone(),
        task: entry.main_task().name.into(),
        design_pattern: settings.pattern,
        observation_space: spec.observation_space.clone(),
        observation_names: spec.observation_names.clone(),
        action_space: spec.action_space.clone(),
        control_period_s,
        normalizes_observations: model.obs_rms().is_some(),
        timesteps: model.agent().timesteps(),
    };
    twinbots_onnx::write_policy(onnx, model, &metadata)?;
    println!(
        "{}: {} ({} observations → {}), {} steps of training, to {}",
        settings.robot,
        metadata.task,
        metadata.observation_space.dim(),
        metadata.action_space,
        metadata.timesteps,
        onnx.display()
    );
    Ok(metadata)
}
