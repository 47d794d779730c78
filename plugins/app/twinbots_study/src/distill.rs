//! A pixel policy taught by a teacher that sees the state (`twinbots distill`): DAgger (Ross,
//! Gordon and Bagnell 2011), the "learning by cheating" route of privileged teachers. Every
//! round the student (a PPO run's CNN policy) drives the arenas on the images, deterministic as it
//! will be judged; the teacher (the robot's classical controller, a state run or an ONNX policy)
//! says what it would have done in each state the student reached; and the student's policy is
//! fitted to all the teacher's answers so far by cross-entropy (−log π(a_teacher | o)). So it
//! learns to recover from its own mistakes, which imitating the teacher's own episodes never
//! shows it.
//!
//! The convolutions stay as they are: what they make of the images is kept with each answer,
//! not the images, so a round costs its rollout's rendering. [`Tune::Actor`] fits the policy
//! MLP (and a Gaussian's log σ) on the encoder's features; [`Tune::Dense`] fits the encoder's
//! dense layer too, at a tenth of the learning rate, so that the features come to hold what the
//! teacher's answers turn on (it keeps the convolutions' output instead: 4,096 values an answer
//! at 96×96).

use std::path::Path;

use candle_core::{D, DType, Device, Tensor, Var};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use twinbots_api::{EpisodeSummary, Space, VecEnv};
use twinbots_learn::RunDir;
use twinbots_learn::nn::{Adam, AdamConfig, Encoder, NatureCnn};
use twinbots_learn::ppo::{Head, Ppo};
use twinbots_render::pixels::TaskObservation;
use twinbots_task::AppVecEnv;
use twinbots_task::randomization::RandomizationPlugin;

use crate::controller::NamedController;
use twinbots_run::registry::RobotEntry;
use twinbots_run::settings::TrainSettings;

/// Answers per gradient step.
const BATCH: usize = 256;

/// What a round fits besides the policy MLP.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Tune {
    /// The policy MLP alone, on the frozen encoder's features.
    Actor,
    /// The encoder's dense layer too (its convolutions stay frozen).
    Dense,
}

/// How a student is taught.
#[derive(Clone, Debug, Serialize)]
pub struct DistillOptions {
    /// `classic`, a state run's directory or an `.onnx` policy (as `twinbots study` names them).
    pub teacher: String,
    pub rounds: usize,
    /// Control steps of every arena per round.
    pub steps: usize,
    /// Passes over all the answers so far after each round.
    pub epochs: usize,
    pub tune: Tune,
    /// Adam's, for the policy MLP (the dense layer's is a tenth of it).
    pub learning_rate: f64,
}

/// One round (a row of `distill.csv`).
#[derive(Clone, Debug, Serialize)]
pub struct Round {
    pub round: usize,
    /// Episodes the student finished in the round, their mean score and (a task with a goal)
    /// the share that succeeded.
    pub episodes: usize,
    pub mean_score: f64,
    pub success_rate: Option<f64>,
    /// How far the student's actions were from the teacher's, before the round's fit: the
    /// share of differing actions (discrete) or their RMS difference (boxes).
    pub disagreement: f64,
    /// The answers fitted to, all rounds so far, and the last epoch's mean −log π (of a
    /// density for boxes: it can be negative).
    pub answers: usize,
    pub cross_entropy: f64,
    pub seconds: f64,
}

/// Teaches the policy of the pixel run `student` (a PPO CNN policy) with `options` into the new
/// run directory `out` (its `config.toml`, the taught `model/`, `distill.csv`, `distill.png`,
/// `distill.json`),
/// which `twinbots eval` judges as any run. `report` sees every round.
pub fn distill(
    entry: &RobotEntry,
    student: &Path,
    out: &Path,
    options: &DistillOptions,
    mut report: impl FnMut(&Round),
) -> anyhow::Result<Vec<Round>> {
    anyhow::ensure!(
        options.rounds > 0 && options.steps > 0 && options.epochs > 0,
        "--rounds, --steps and --epochs must each be at least 1"
    );
    let run = RunDir::new(student);
    let settings = TrainSettings::of_run(&run)?;
    anyhow::ensure!(
        settings.robot == entry.name,
        "{}: a run of {}, not of {}",
        student.display(),
        settings.robot,
        entry.name
    );
    anyhow::ensure!(
        settings.pixels.is_some(),
        "{}: not a pixel run (no [pixels]): its policy already sees the state",
        student.display()
    );
    let (from, mut ppo) =
        run.trained_with(|dir| Ppo::load(dir)).map_err(|e| anyhow::anyhow!("{e:#} (the student must be a PPO run)"))?;
    let teacher = NamedController::open(&options.teacher, Path::new("."), entry)?;
    // The teacher's spaces against the task's own (as it observes the state).
    teacher.env(entry, settings.task.as_deref(), 1, 0, |_| Ok(()))?;

    let mut app = twinbots_run::run::evaluation_app(
        entry,
        None,
        settings.arenas,
        settings.seed,
        &settings,
        &settings.calibration_parameters(),
    )?;
    if !settings.randomization.is_off() {
        app.add_plugins(RandomizationPlugin(settings.randomization.clone()));
    }
    let mut env = AppVecEnv::new(app);
    ppo.check_spaces(env.observation_space(), env.action_space())?;
    let mut fit = StudentFit::new(&ppo, options)?;
    let out_run = RunDir::new(out);
    anyhow::ensure!(
        !out_run.holds_run() && !out_run.file(twinbots_learn::run_dir::CONFIG).exists(),
        "{} already holds a run: choose another --out",
        out.display()
    );
    out_run.create()?;
    out_run.write_config(&settings)?;
    println!(
        "teaching {} (from {}) by {} for {} rounds of {} steps × {} arenas",
        student.display(),
        from.display(),
        teacher.label,
        options.rounds,
        options.steps,
        env.num_envs()
    );

    let mut answers = Answers::default();
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut rounds = Vec::new();
    for round in 0..options.rounds {
        let started = std::time::Instant::now();
        let (episodes, disagreement) = roll_out(
            &mut env,
            &ppo,
            &fit,
            &teacher,
            options.steps,
            settings.seed.wrapping_add(twinbots_api::seeds::DISTILL_ROUND + round as u64),
            &mut answers,
        )?;
        let cross_entropy = fit.fit(&ppo, &answers, options.epochs, &mut rng)?;
        let mean = |values: &[f64]| {
            if values.is_empty() { f64::NAN } else { values.iter().sum::<f64>() / values.len() as f64 }
        };
        let scores: Vec<f64> = episodes.iter().map(|e| e.score as f64).collect();
        let successes: Vec<f64> = episodes.iter().filter_map(|e| e.success).map(|s| f64::from(u8::from(s))).collect();
        let row = Round {
            round,
            episodes: scores.len(),
            mean_score: mean(&scores),
            success_rate: (!successes.is_empty()).then(|| mean(&successes)),
            disagreement,
            answers: answers.count(),
            cross_entropy,
            seconds: started.elapsed().as_secs_f64(),
        };
        report(&row);
        rounds.push(row);
        write_csv(&out_run.file(DISTILL_CSV), &rounds)?;
        plot_rounds(&out_run.file(DISTILL_PNG), &format!("{} taught by {}", entry.name, teacher.label), &rounds)?;
    }
    // The episodes the student's training left running are not these rounds': a `train
    // --resume` of the taught run starts its envs afresh.
    ppo.state.env_state = None;
    out_run.save_model(&ppo)?;
    out_run
        .write_json("distill.json", &serde_json::json!({ "student": student, "options": options, "rounds": rounds }))?;
    Ok(rounds)
}

/// The rounds' figures, one row a round, and their plot.
pub const DISTILL_CSV: &str = "distill.csv";
pub const DISTILL_PNG: &str = "distill.png";

/// `distill.png`: the student's mean score (top) and its disagreement with the teacher
/// (bottom) round by round.
fn plot_rounds(path: &Path, title: &str, rounds: &[Round]) -> anyhow::Result<()> {
    use plotters::prelude::*;
    twinbots_learn::plot::png(path, (900, 700), |root| {
        let root = root.titled(title, ("sans-serif", 22))?;
        let panels = root.split_evenly((2, 1));
        let last = rounds.len().saturating_sub(1).max(1) as f64;
        let series: [(&str, Box<dyn Fn(&Round) -> f64>); 2] = [
            ("mean score of the round's episodes", Box::new(|r| r.mean_score)),
            ("disagreement with the teacher", Box::new(|r| r.disagreement)),
        ];
        for (panel, (label, value)) in panels.iter().zip(series) {
            let points: Vec<(f64, f64)> =
                rounds.iter().map(|r| (r.round as f64, value(r))).filter(|p| p.1.is_finite()).collect();
            let (low, high) = points.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| (lo.min(p.1), hi.max(p.1)));
            let (low, high) = if low > high { (0.0, 1.0) } else { (low, high) };
            let pad = (high - low).max(1e-3) * 0.08;
            let mut chart = ChartBuilder::on(panel)
                .margin(12)
                .x_label_area_size(36)
                .y_label_area_size(70)
                .build_cartesian_2d(0f64..last, low - pad..high + pad)?;
            let whole = |x: &f64| format!("{x:.0}");
            chart
                .configure_mesh()
                .x_labels((last as usize + 1).min(21))
                .x_label_formatter(&whole)
                .x_desc("round")
                .y_desc(label)
                .label_style(("sans-serif", 14))
                .draw()?;
            chart.draw_series(LineSeries::new(points.iter().copied(), BLUE.stroke_width(2)))?;
            chart.draw_series(points.iter().map(|&p| Circle::new(p, 3, BLUE.filled())))?;
        }
        Ok(())
    })
}

/// `distill.csv`: a header, then a row a round (rewritten after each, atomically).
fn write_csv(path: &Path, rounds: &[Round]) -> anyhow::Result<()> {
    let mut text = String::from("round,episodes,mean_score,success_rate,disagreement,answers,cross_entropy,seconds\n");
    for r in rounds {
        let success = r.success_rate.map_or(String::new(), |s| s.to_string());
        text += &format!(
            "{},{},{},{success},{},{},{},{:.1}\n",
            r.round, r.episodes, r.mean_score, r.disagreement, r.answers, r.cross_entropy, r.seconds
        );
    }
    twinbots_api::files::write_atomic(path, text.as_bytes()).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// The teacher's answers: what the student kept of each observation, and the teacher's action.
#[derive(Default)]
struct Answers {
    kept: Vec<f32>,
    actions: Vec<f32>,
    kept_dim: usize,
    action_dim: usize,
}

impl Answers {
    fn count(&self) -> usize {
        self.actions.len() / self.action_dim.max(1)
    }
}

/// One round: the student drives every arena for `steps` steps from `seed`; every observation's
/// kept values and the teacher's action there are added to `answers`. Returns the episodes that
/// ended and the disagreement.
fn roll_out(
    env: &mut AppVecEnv,
    ppo: &Ppo,
    fit: &StudentFit,
    teacher: &NamedController,
    steps: usize,
    seed: u64,
    answers: &mut Answers,
) -> anyhow::Result<(Vec<EpisodeSummary>, f64)> {
    let n = env.num_envs();
    let dim = ppo.state.observation_space.dim();
    let mut obs = env.reset(Some(seed))?;
    let (mut ended, mut gap, mut compared) = (Vec::new(), 0.0, 0usize);
    // Deterministic actions draw nothing from it.
    let mut unused = ChaCha8Rng::seed_from_u64(0);
    for _ in 0..steps {
        let x = Tensor::from_vec(ppo.normalize(&obs), (n, dim), &Device::Cpu)?;
        let kept = fit.kept(&x)?;
        let (actions, _, _) = ppo.policy.act_from(&fit.features(&kept)?, None, true, &mut unused)?;
        let actions = ppo.clip_to_space(actions);
        let mut state = Vec::new();
        for &arena in env.arenas() {
            let observed = env
                .app()
                .world()
                .get::<TaskObservation>(arena)
                .ok_or_else(|| anyhow::anyhow!("the pixel env keeps no task observation"))?;
            state.extend_from_slice(&observed.0);
        }
        // What the env would do with the teacher's actions: a box's clipped to its bounds.
        let told = ppo.clip_to_space(teacher.act(&state, state.len() / n)?);
        anyhow::ensure!(
            told.len() == actions.len(),
            "the teacher gives {} actions for {n} arenas, the student {}",
            told.len(),
            actions.len()
        );
        (gap, compared) = match ppo.state.action_space {
            Space::Discrete { .. } => {
                (gap + told.iter().zip(&actions).filter(|(t, a)| t != a).count() as f64, compared + n)
            }
            _ => (
                gap + told.iter().zip(&actions).map(|(t, a)| ((t - a) as f64).powi(2)).sum::<f64>(),
                compared + told.len(),
            ),
        };
        answers.kept_dim = kept.dim(1)?;
        answers.action_dim = told.len() / n;
        answers.kept.extend(kept.flatten_all()?.to_vec1::<f32>()?);
        answers.actions.extend(told);
        let step = env.step(&actions)?;
        ended.extend(step.episodes.into_iter().flatten());
        obs = step.obs;
    }
    let disagreement = match ppo.state.action_space {
        Space::Discrete { .. } => gap / compared.max(1) as f64,
        _ => (gap / compared.max(1) as f64).sqrt(),
    };
    Ok((ended, disagreement))
}

/// The student's fitting: its CNN split at the dense layer, and the optimisers.
struct StudentFit<'a> {
    cnn: &'a NatureCnn,
    /// The state values after the image (`pixels.state`).
    state: usize,
    tune: Tune,
    actor: Adam,
    dense: Adam,
}

impl<'a> StudentFit<'a> {
    fn new(ppo: &'a Ppo, options: &DistillOptions) -> anyhow::Result<Self> {
        let Encoder::Cnn { cnn, state } = &ppo.policy.encoder else {
            anyhow::bail!("the student's policy must be \"cnn\" (NatureCNN) on the image");
        };
        anyhow::ensure!(
            ppo.policy.value_encoder.is_none() || options.tune == Tune::Actor,
            "--tune dense needs a student whose features are shared (share_features_extractor = true)"
        );
        let mut actor: Vec<Var> =
            ppo.policy.pi.layers.iter().flat_map(|l| [l.weight.clone(), l.bias.clone()]).collect();
        if let Head::Gaussian { log_std, .. } = &ppo.policy.head {
            actor.push(log_std.clone());
        }
        let adam = |vars, learning_rate| Adam::new(vars, AdamConfig { learning_rate, ..AdamConfig::default() });
        Ok(Self {
            cnn,
            state: *state,
            tune: options.tune,
            actor: adam(actor, options.learning_rate),
            dense: adam(vec![cnn.fc.weight.clone(), cnn.fc.bias.clone()], options.learning_rate / 10.0),
        })
    }

    /// What an answer keeps of a batch of observations: the features and state values, or
    /// (tuning the dense layer) the convolutions' output and state values.
    fn kept(&self, obs: &Tensor) -> candle_core::Result<Tensor> {
        let image_dim = obs.dim(1)? - self.state;
        let h = self.cnn.convolutions(&obs.narrow(1, 0, image_dim)?)?.detach();
        let h = if self.tune == Tune::Dense { h } else { self.cnn.dense(&h)?.detach() };
        if self.state == 0 { Ok(h) } else { Tensor::cat(&[h, obs.narrow(1, image_dim, self.state)?], 1) }
    }

    /// The policy MLP's input from kept values.
    fn features(&self, kept: &Tensor) -> candle_core::Result<Tensor> {
        if self.tune == Tune::Actor {
            return Ok(kept.clone());
        }
        let trunk = kept.dim(1)? - self.state;
        let features = self.cnn.dense(&kept.narrow(1, 0, trunk)?)?;
        if self.state == 0 { Ok(features) } else { Tensor::cat(&[features, kept.narrow(1, trunk, self.state)?], 1) }
    }

    /// `epochs` shuffled passes of −log π(a_teacher | o) over every answer; the last pass's mean.
    fn fit(&mut self, ppo: &Ppo, answers: &Answers, epochs: usize, rng: &mut ChaCha8Rng) -> anyhow::Result<f64> {
        let (k, a) = (answers.kept_dim, answers.action_dim);
        let mut order: Vec<usize> = (0..answers.count()).collect();
        let mut mean = f64::NAN;
        for _ in 0..epochs {
            order.shuffle(rng);
            let mut sum = 0.0;
            for chunk in order.chunks(BATCH) {
                let x: Vec<f32> =
                    chunk.iter().flat_map(|&i| answers.kept[i * k..(i + 1) * k].iter().copied()).collect();
                let y: Vec<f32> =
                    chunk.iter().flat_map(|&i| answers.actions[i * a..(i + 1) * a].iter().copied()).collect();
                let x = Tensor::from_vec(x, (chunk.len(), k), &Device::Cpu)?;
                let y = Tensor::from_vec(y, (chunk.len(), a), &Device::Cpu)?;
                // A categorical head takes one action index a row.
                let y =
                    if matches!(ppo.state.action_space, Space::Discrete { .. }) { y.squeeze(D::Minus1)? } else { y };
                let loss = ppo
                    .policy
                    .evaluate_features(&self.features(&x)?, None, &y.to_dtype(DType::F32)?)?
                    .log_prob
                    .mean_all()?
                    .neg()?;
                sum += loss.to_scalar::<f32>()? as f64 * chunk.len() as f64;
                let grads = loss.backward()?;
                self.actor.step(&grads, Some(0.5))?;
                if self.tune == Tune::Dense {
                    self.dense.step(&grads, Some(0.5))?;
                }
            }
            mean = sum / order.len().max(1) as f64;
        }
        Ok(mean)
    }
}
