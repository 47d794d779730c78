//! `twinbots distill <pixel-run> --out DIR`: teaches a pixel run's policy by a teacher that sees
//! the state (DAgger, docs/pixels.md); `twinbots eval DIR` judges the result.

use std::path::PathBuf;

use twinbots_study::distill::{DistillOptions, Tune, distill};

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// Run directory of `twinbots train` with pixel observations and a PPO `cnn` policy: the
    /// student, started from its model.
    pub run: PathBuf,
    /// Where the taught run goes (a new directory).
    #[arg(long)]
    pub out: PathBuf,
    /// Who answers: `classic` (the robot's classical controller), a state run's directory, or
    /// an `.onnx` policy of the robot.
    #[arg(long, default_value = "classic")]
    pub teacher: String,
    #[arg(long, default_value_t = 14)]
    pub rounds: usize,
    /// Control steps of every arena in a round.
    #[arg(long, default_value_t = 2000)]
    pub steps: usize,
    /// Passes over all the answers so far after each round.
    #[arg(long, default_value_t = 4)]
    pub epochs: usize,
    /// What is fitted: `actor` (the policy MLP on the frozen encoder's features) or `dense`
    /// (the encoder's dense layer too; its convolutions stay frozen).
    #[arg(long, value_enum, default_value_t = Tune::Dense)]
    pub tune: Tune,
    /// Adam's learning rate for the policy MLP (the dense layer's: a tenth of it).
    #[arg(long, default_value_t = 1e-3)]
    pub learning_rate: f64,
}

/// `twinbots distill`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let settings = twinbots_run::settings::TrainSettings::of_run(&twinbots_learn::RunDir::new(&args.run))?;
    let entry = registry::find(&settings.robot)?;
    let options = DistillOptions {
        teacher: args.teacher,
        rounds: args.rounds,
        steps: args.steps,
        epochs: args.epochs,
        tune: args.tune,
        learning_rate: args.learning_rate,
    };
    let rounds = distill(&entry, &args.run, &args.out, &options, |r| {
        println!(
            "round {}: {} episodes ended, mean score {:.1}{}; disagreement with the teacher {:.4}; {} answers, cross-entropy {:.4} ({:.0} s)",
            r.round,
            r.episodes,
            r.mean_score,
            r.success_rate.map_or(String::new(), |s| format!(", {:.0} % succeeded", 100.0 * s)),
            r.disagreement,
            r.answers,
            r.cross_entropy,
            r.seconds
        );
    })?;
    println!(
        "{} rounds; the taught run is {}: judge it with `twinbots eval {} --episodes 100`",
        rounds.len(),
        args.out.display(),
        args.out.display()
    );
    Ok(())
}
