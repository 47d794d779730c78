//! `twinbots export <run-dir> --onnx FILE`: the run's trained policy (any algorithm's) as an ONNX graph, with
//! what a robot's program needs to know about it (docs/export.md); `--bundle DIR`: the deploy
//! bundle a robot's controller link runs (docs/deploy.md).

use std::path::Path;

use twinbots_learn::RunDir;
use twinbots_onnx::PolicyMetadata;
use twinbots_sim::SimSettings;

use twinbots_run::registry;
use twinbots_run::settings::TrainSettings;

/// The command's arguments.
#[derive(clap::Args)]
#[command(group = clap::ArgGroup::new("what").required(true).multiple(true).args(["onnx", "bundle"]))]
pub struct Args {
    /// Run directory of `twinbots train` or `twinbots serve`.
    pub run: std::path::PathBuf,
    /// The ONNX file to write.
    #[arg(long)]
    pub onnx: Option<std::path::PathBuf>,
    /// The deploy bundle to write (a directory: policy, manifest, calibration).
    #[arg(long)]
    pub bundle: Option<std::path::PathBuf>,
}

/// `twinbots export`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if let Some(onnx) = &args.onnx {
        export_run(&args.run, onnx)?;
    }
    if let Some(dir) = &args.bundle {
        export_bundle(&args.run, dir)?;
    }
    Ok(())
}

/// Writes the run's deploy bundle to `dir`.
pub fn export_bundle(run: &Path, dir: &Path) -> anyhow::Result<twinbots_ops::bundle::Manifest> {
    let run_dir = RunDir::new(run);
    let settings = TrainSettings::of_run(&run_dir)?;
    let model = twinbots_learn::algos::load_run(&run_dir)?;
    let metadata = describe(&settings, model.as_ref())?;
    let calibration = settings.calibration.as_ref().map(|c| {
        #[derive(serde::Serialize)]
        struct File<'a> {
            parameters: &'a std::collections::BTreeMap<String, f64>,
        }
        let body = toml::to_string(&File { parameters: &c.parameters }).expect("parameters serialise");
        format!("# The calibration the policy was trained on (from {}).\n{body}", c.file)
    });
    let cell = settings.cell.as_ref().map(|c| {
        format!(
            "# The cell the policy was trained in (the run's [cell]).\n{}",
            toml::to_string(c).expect("a cell table serialises")
        )
    });
    let named = |text: &Option<String>, file: &str| text.as_ref().map(|_| file.to_string());
    let robot = twinbots_ops::linked_arm::LinkedArm::of(&settings.robot)?;
    let manifest = twinbots_ops::bundle::manifest_for(
        &robot,
        &metadata,
        named(&calibration, twinbots_ops::bundle::CALIBRATION),
        named(&cell, twinbots_ops::bundle::CELL),
    )?;
    let bytes = twinbots_onnx::policy_bytes(model.as_ref(), &metadata)?;
    twinbots_ops::bundle::write(dir, &manifest, &bytes, calibration.as_deref(), cell.as_deref())?;
    println!(
        "{}: {} bundle ({} joints, action x {} rad/s, every {} s{}) to {}",
        manifest.robot,
        manifest.task,
        manifest.joints.len(),
        manifest.action.scale,
        manifest.control_period_s,
        match (&manifest.calibration, &manifest.cell) {
            (Some(_), Some(_)) => ", calibrated, its cell",
            (Some(_), None) => ", calibrated",
            (None, Some(_)) => ", its cell",
            (None, None) => "",
        },
        dir.display()
    );
    Ok(manifest)
}

/// Writes the run's model (its final one, else its newest checkpoint) to `onnx` and returns the
/// description written with it.
pub fn export_run(run: &Path, onnx: &Path) -> anyhow::Result<PolicyMetadata> {
    let run_dir = RunDir::new(run);
    let settings = TrainSettings::of_run(&run_dir)?;
    let model = twinbots_learn::algos::load_run(&run_dir)?;
    let metadata = describe(&settings, model.as_ref())?;
    twinbots_onnx::write_policy(onnx, model.as_ref(), &metadata)?;
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

/// What the run's policy is: its robot and task, spaces, control period and training.
fn describe(settings: &TrainSettings, model: &dyn twinbots_learn::Agent) -> anyhow::Result<PolicyMetadata> {
    let entry = registry::find(&settings.robot)?;
    // First whether the policy can be written at all.
    let policy = model.policy_net()?;
    // The robot's own timing, as an app of it declares it; the task as the run observed it
    // (a camera image with `[pixels]`).
    let app = entry.app(settings.task.as_deref(), 1, settings.seed, settings.in_process_pattern()?)?;
    let control_period_s = app.world().resource::<SimSettings>().control_dt();
    let spec = &settings.task(&entry)?;
    model.check_spaces(&spec.observation_space, &spec.action_space)?;
    let metadata = PolicyMetadata {
        twinbots_version: env!("CARGO_PKG_VERSION").into(),
        robot: settings.robot.clone(),
        task: settings.task_name(&entry)?.into(),
        design_pattern: settings.pattern,
        observation_space: spec.observation_space.clone(),
        observation_names: spec.observation_names.clone(),
        action_space: spec.action_space.clone(),
        control_period_s,
        normalizes_observations: policy.obs_rms.is_some(),
        timesteps: model.timesteps(),
    };
    Ok(metadata)
}
