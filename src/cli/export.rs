//! `twinbots export <run-dir> --onnx FILE`: the run's trained policy (any algorithm's) as an ONNX graph, with
//! what a robot's program needs to know about it (docs/export.md).

use std::path::Path;

use twinbots_onnx::PolicyMetadata;
use twinbots_task::ActiveTask;
use twinbots_learn::RunDir;
use twinbots_sim::SimSettings;

use twinbots::settings::TrainSettings;
use crate::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// Run directory of `twinbots train` or `twinbots serve`.
    pub run: std::path::PathBuf,
    /// The ONNX file to write.
    #[arg(long)]
    pub onnx: std::path::PathBuf,
}

/// `twinbots export`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    export_run(&args.run, &args.onnx).map(|_| ())
}

/// Writes the run's model (its final one, else its newest checkpoint) to `onnx` and returns the
/// description written with it.
pub fn export_run(run: &Path, onnx: &Path) -> anyhow::Result<PolicyMetadata> {
    let run_dir = RunDir::new(run);
    let settings = TrainSettings::of_run(&run_dir)?;
    let entry = registry::find(&settings.robot)?;
    let model = twinbots_learn::algos::load_run(&run_dir)?;
    let model: &dyn twinbots_learn::Agent = model.as_ref();
    // The robot's own description of its task and timing, as an app of it declares them.
    let app = entry.app(None, 1, settings.seed, settings.in_process_pattern()?)?;
    let spec = &**app.world().resource::<ActiveTask>();
    let control_period_s = app.world().resource::<SimSettings>().control_dt();
    model.check_spaces(&spec.observation_space, &spec.action_space)?;
    let metadata = PolicyMetadata {
        twinbots_version: env!("CARGO_PKG_VERSION").into(),
        robot: settings.robot.clone(),
        task: entry.main_task().name.into(),
        design_pattern: settings.pattern,
        observation_space: spec.observation_space.clone(),
        observation_names: spec.observation_names.clone(),
        action_space: spec.action_space.clone(),
        control_period_s,
        normalizes_observations: model.policy_net()?.obs_rms.is_some(),
        timesteps: model.timesteps(),
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
