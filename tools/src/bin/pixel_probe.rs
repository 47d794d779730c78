//! Do camera images carry what a policy needs? Collects pixel observations labelled with what
//! they should show, fits a NatureCNN with a linear head to them by regression, and prints R²
//! per label on held-out images: a probe of the observation, apart from any RL. `--encoder
//! keypoints` fits the keypoints encoder (`policy = "keypoints"`) instead.
//! - `--robot cartpole`: the side camera, `--size`² pixels, `--frames` frames, under the classical
//!   controller with a random action a quarter of the time; labels the cart's place and speed and the
//!   pole's angle and rate (the state a policy needs); then closes the loop: the classical
//!   controller acting on the states the fitted encoder reads (mean episode length).
//! - `--robot ur5e`: the camera reach's iso camera, one frame, whole reaches: the classical
//!   controller drives every arena, jittered and with a random action a quarter of the time, an
//!   image every third step; labels the target's place (base frame), and the held-out error in
//!   millimetres. Under randomized looks every image shows a look of its own (drawn just before
//!   it), not one look per reach: with one per reach the encoder learns which look goes with
//!   which target instead of reading the target off the picture. `--held-out` (looks `.toml`
//!   files, joined by commas) also measures the fitted encoder on 2,400 images of reaches under
//!   each file's looks.
//!
//! `--looks randomized` draws a new look per arena at every reset (`[randomization.visual]`'s
//! defaults), as training with visual randomization does; a `.toml` file instead draws them from
//! its `[randomization.visual]` table (e.g. without camera jitter). `--save FILE` saves the fitted
//! encoder (`features.*`): `[ppo] features_from` starts a policy from it (docs/pixels.md).
//!
//! `--from FILE` (a `.safetensors` the probe saved) starts the encoder from a fit, to fit it
//! longer; `--annealed` fits in shuffled batches with the learning rate falling linearly to 0
//! over the epochs (without it: the collection order and 3e-4 throughout).
//!
//! `--more-cameras front` (or several, comma-separated) sees each image through those cameras
//! too, their pictures beside the first's along the width (`[pixels] more_cameras`).
//!
//! `--jitter` fits on every image under a colour jitter of its own, drawn each time it is read
//! (brightness, contrast and saturation ±40 %, each channel ±10 %), as RAD (Laskin et al. 2020)
//! augments pixel observations; the held-out images are read as rendered.
//!
//! `cargo run --release -p twinbots_tools --bin pixel_probe -- --robot ur5e --images 24000 --epochs 10 --fov 30
//! --size 96 --looks assets/looks/textures-and-lights.toml --annealed --jitter --save encoder.safetensors`
//! (`--help` lists every option with its default).

use std::path::PathBuf;

use candle_core::{Device, Tensor, Var};
use clap::Parser;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_learn::nn::{Adam, AdamConfig, Encoder, PolicyKind};
use twinbots_render::PixelSettings;
use twinbots_render::pixels::TaskObservation;
use twinbots_task::AppVecEnv;
use twinbots_task::randomization::visual::{VisualRandomization, redraw_looks};
use twinbots_task::randomization::{Randomization, RandomizationPlugin};

const ARENAS: usize = 8;

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Robot {
    Cartpole,
    Ur5e,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum EncoderKind {
    Cnn,
    Keypoints,
}

/// Fits an encoder to labelled camera images and reports how well it reads them.
#[derive(Parser)]
struct Args {
    #[arg(long, value_enum, default_value_t = Robot::Cartpole)]
    robot: Robot,
    /// Labelled images collected; a fifth of them (at most 4,800) held out.
    #[arg(long, default_value_t = 4000)]
    images: usize,
    #[arg(long, default_value_t = 10)]
    epochs: usize,
    /// The camera's vertical field of view, degrees.
    #[arg(long, default_value_t = 26.0)]
    fov: f32,
    #[arg(long, value_enum, default_value_t = EncoderKind::Cnn)]
    encoder: EncoderKind,
    /// `plain` (the twin's one look), `randomized` (`[randomization.visual]`'s defaults) or a
    /// `.toml` file with a `[randomization.visual]` table.
    #[arg(long, default_value = "plain")]
    looks: String,
    /// Where the fitted encoder is saved (safetensors).
    #[arg(long)]
    save: Option<PathBuf>,
    /// Frames stacked per observation (cart-pole; the reach sees one).
    #[arg(long, default_value_t = 2)]
    frames: u32,
    /// Image width and height, pixels.
    #[arg(long, default_value_t = 64)]
    size: u32,
    /// An encoder the probe saved, to fit further.
    #[arg(long)]
    from: Option<PathBuf>,
    /// Shuffled batches, the learning rate falling linearly to 0.
    #[arg(long)]
    annealed: bool,
    /// Looks `.toml` files (comma-separated) the fitted encoder is also measured under (ur5e).
    #[arg(long, value_delimiter = ',')]
    held_out: Vec<PathBuf>,
    /// A colour jitter of its own on every fitted image.
    #[arg(long)]
    jitter: bool,
    /// The seed of the reaches the images come from (ur5e): another seed, other images, e.g.
    /// to fit an encoder further (`--from`) on images it has not seen. The `--held-out` looks'
    /// reaches are seed 1000's.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Cameras (comma-separated) whose images follow the robot's camera's along the width
    /// (`[pixels] more_cameras`), e.g. `front`.
    #[arg(long, value_delimiter = ',')]
    more_cameras: Vec<String>,
}

fn main() -> anyhow::Result<()> {
    twinbots_learn::threads::configure();
    let Args {
        robot,
        images: samples,
        epochs,
        fov,
        encoder: kind,
        looks,
        save,
        frames,
        size,
        from,
        annealed,
        held_out,
        jitter: jittered,
        seed,
        more_cameras,
    } = Args::parse();
    let kind = match kind {
        EncoderKind::Cnn => PolicyKind::Cnn,
        EncoderKind::Keypoints => PolicyKind::Keypoints,
    };
    let randomized = match looks.as_str() {
        "plain" => None,
        "randomized" => Some(VisualRandomization::default()),
        file if file.ends_with(".toml") => {
            Some(Randomization::looks_of(std::path::Path::new(file)).map_err(|e| anyhow::anyhow!("--looks {e}"))?)
        }
        other => {
            anyhow::bail!("--looks '{other}': plain, randomized or a .toml file with a [randomization.visual] table")
        }
    };
    let held_out_looks: Vec<(String, VisualRandomization)> = held_out
        .iter()
        .map(|file| {
            Ok((
                file.display().to_string(),
                Randomization::looks_of(file).map_err(|e| anyhow::anyhow!("--held-out {e}"))?,
            ))
        })
        .collect::<anyhow::Result<_>>()?;
    anyhow::ensure!(samples >= 5, "--images {samples}: at least 5 (a fifth of them are held out)");
    anyhow::ensure!(seed == 0 || robot == Robot::Ur5e, "--seed: the ur5e probe's");
    anyhow::ensure!(
        held_out_looks.is_empty() || robot == Robot::Ur5e,
        "--held-out: the ur5e probe's (the cart-pole has no held-out looks)"
    );
    // The camera: the cart-pole's side one (`frames` frames), the reach's iso one (one frame).
    let camera = match robot {
        Robot::Cartpole => {
            PixelSettings { fov, frames, width: size, height: size, more_cameras, ..PixelSettings::default() }
        }
        Robot::Ur5e => PixelSettings {
            camera: "iso".into(),
            fov,
            width: size,
            height: size,
            more_cameras,
            ..PixelSettings::default()
        },
    };
    let (env, names, scale, images, labels) = match robot {
        Robot::Cartpole => cartpole_samples(samples, &camera, randomized)?,
        Robot::Ur5e => ur5e_samples(samples, &camera, randomized, seed)?,
    };
    let (dim, k) = (env.observation_space().dim(), names.len());
    // A fifth held out, at most 4,800 images (one tensor, read after every epoch).
    let held_out = (samples / 5).min(4800);
    let train = samples - held_out;
    let name = if robot == Robot::Ur5e { "ur5e" } else { "cartpole" };
    let seen_by = camera.cameras().collect::<Vec<_>>().join(" + ");
    println!(
        "{name}: {samples} images ({train} to fit, {held_out} held out), {seen_by} camera, field of view {fov}°{}",
        if jittered { ", colour-jittered fit" } else { "" }
    );

    let dev = Device::Cpu;
    let encoder = Encoder::new(kind, env.observation_space(), 64, "probe", &mut ChaCha8Rng::seed_from_u64(2), &dev)?;
    if let Some(path) = &from {
        twinbots_learn::model_io::set_encoder_from_file(&encoder, path)?;
    }
    let head_w = Var::from_tensor(&(Tensor::randn(0f32, 0.1, (k, encoder.dim()), &dev)?))?;
    // The head starts at the labels' mean: what is left to fit is what the images show.
    let mean: Vec<f32> =
        (0..k).map(|i| labels[..train * k].iter().skip(i).step_by(k).sum::<f32>() / train as f32).collect();
    let head_b = Var::from_tensor(&Tensor::from_vec(mean, k, &dev)?)?;
    let mut vars: Vec<Var> = encoder.named_vars().into_iter().map(|(_, v)| v).collect();
    vars.extend([head_w.clone(), head_b.clone()]);
    let mut adam = Adam::new(vars, AdamConfig { learning_rate: 3e-4, ..AdamConfig::default() });
    let predict = |x: &Tensor| -> candle_core::Result<Tensor> {
        encoder.forward(x)?.matmul(&head_w.as_tensor().t()?)?.broadcast_add(head_b.as_tensor())
    };
    // Batches gathered by index: in collection order, or shuffled every epoch (`annealed`).
    let gathered = |picked: &[usize], jitter: Option<&mut ChaCha8Rng>| -> candle_core::Result<(Tensor, Tensor)> {
        let mut x: Vec<f32> =
            picked.iter().flat_map(|&i| images[i * dim..(i + 1) * dim].iter().map(|&v| v as f32)).collect();
        if let Some(rng) = jitter {
            x.chunks_mut(dim).for_each(|image| colour_jitter(image, rng));
        }
        let y: Vec<f32> = picked.iter().flat_map(|&i| labels[i * k..(i + 1) * k].iter().copied()).collect();
        Ok((Tensor::from_vec(x, (picked.len(), dim), &dev)?, Tensor::from_vec(y, (picked.len(), k), &dev)?))
    };
    // The held-out images, made a tensor once: read after every epoch and at the end.
    let held: Vec<f32> = images[train * dim..(train + held_out) * dim].iter().map(|&v| v as f32).collect();
    let held_x = Tensor::from_vec(held, (held_out, dim), &dev)?;
    let held_y = Tensor::from_slice(&labels[train * k..(train + held_out) * k], (held_out, k), &dev)?;
    let mut order: Vec<usize> = (0..train).collect();
    let mut shuffler = ChaCha8Rng::seed_from_u64(3);
    let mut jitter = ChaCha8Rng::seed_from_u64(4);
    let batch = 128;
    for epoch in 1..=epochs {
        let started = std::time::Instant::now();
        let mut loss_sum = 0.0;
        if annealed {
            use rand::seq::SliceRandom;
            order.shuffle(&mut shuffler);
            adam.set_learning_rate(3e-4 * (1.0 - (epoch - 1) as f64 / epochs as f64));
        }
        for start in (0..train).step_by(batch) {
            let n = batch.min(train - start);
            let (x, y) = gathered(&order[start..start + n], jittered.then_some(&mut jitter))?;
            let loss = (predict(&x)? - y)?.sqr()?.mean_all()?;
            loss_sum += loss.to_scalar::<f32>()? * n as f32;
            adam.step(&loss.backward()?, Some(10.0))?;
        }
        // R² per label on the held-out images: 1 − residual variance / label variance.
        let residual = (predict(&held_x)? - &held_y)?.sqr()?.mean(0)?.to_vec1::<f32>()?;
        let variance = held_y.broadcast_sub(&held_y.mean(0)?)?.sqr()?.mean(0)?.to_vec1::<f32>()?;
        let r2: Vec<String> = (0..k).map(|i| format!("{} {:.3}", names[i], 1.0 - residual[i] / variance[i])).collect();
        let mut line = format!("epoch {epoch}: fit loss {:.3}, held-out R² {}", loss_sum / train as f32, r2.join(", "));
        if robot == Robot::Ur5e {
            line += &format!("; RMS error {}", rms_mm(&residual, scale));
        }
        println!("{line} ({:.1} s)", started.elapsed().as_secs_f64());
    }
    if robot == Robot::Ur5e {
        println!("the target's place on the held-out images: {}", distances(&predict(&held_x)?, &held_y, scale)?);
    }
    for (file, looks) in held_out_looks {
        // Reaches under looks the fit never drew from: what the encoder still reads there.
        let (_, _, _, images, labels) = ur5e_samples(2400, &camera, Some(looks), 1000)?;
        let x = Tensor::from_vec(images.iter().map(|&v| v as f32).collect::<Vec<f32>>(), (2400, dim), &dev)?;
        let (read, truth) = (predict(&x)?, Tensor::from_vec(labels, (2400, k), &dev)?);
        let residual = (&read - &truth)?.sqr()?.mean(0)?.to_vec1::<f32>()?;
        println!(
            "on 2,400 images under held-out looks ({file}): RMS error {}; {}",
            rms_mm(&residual, scale),
            distances(&read, &truth, scale)?
        );
    }
    // The scale of what the encoder hands an MLP (a frozen encoder's features go in as they are).
    let features = encoder.forward(&held_x)?;
    let (mean, spread) = (
        features.mean_all()?.to_scalar::<f32>()?,
        features.flatten_all()?.sqr()?.mean_all()?.sqrt()?.to_scalar::<f32>()?,
    );
    println!(
        "features on the held-out images: mean {mean:.3}, RMS {spread:.3}, largest {:.3}",
        features.flatten_all()?.max(0)?.to_scalar::<f32>()?
    );
    if robot == Robot::Cartpole {
        // Closed loop: the classical controller acting on the states the fitted encoder reads
        // from the images, as a policy on its features would at best.
        let mut env = env;
        let mut obs = env.reset(Some(1000))?;
        let (mut lengths, mut ends) = (Vec::new(), std::collections::BTreeMap::<String, usize>::new());
        for _ in 0..2000 {
            let read = predict(&Tensor::from_slice(&obs, (ARENAS, dim), &dev)?)?.to_vec2::<f32>()?;
            let state =
                |r: &[f32]| -> Vec<f32> { r.iter().zip(CARTPOLE_UNITS).map(|(label, unit)| label * unit).collect() };
            let actions: Vec<f32> = read.iter().map(|r| cartpole::feedback(&state(r))[0]).collect();
            let step = env.step(&actions)?;
            for i in 0..ARENAS {
                if let Some(e) = &step.episodes[i] {
                    lengths.push(e.length);
                    *ends.entry(step.way_ended(i).unwrap_or_else(|| "unsaid".into())).or_default() += 1;
                }
            }
            obs = step.obs;
        }
        let mean = lengths.iter().map(|&l| l as f64).sum::<f64>() / lengths.len().max(1) as f64;
        println!(
            "closed loop, the classical controller on the read states: {} episodes ended in 2,000 steps × {ARENAS}, mean length {mean:.0}, ended by {ends:?}",
            lengths.len()
        );
    }
    if let Some(path) = save {
        let tensors = twinbots_learn::model_io::var_tensors(&encoder.named_vars());
        twinbots_learn::model_io::save_tensors(&tensors, &path)?;
        println!("the encoder ({} tensors) saved to {}", tensors.len(), path.display());
    }
    Ok(())
}

/// Per-axis RMS errors in millimetres from mean squared residuals in label units.
fn rms_mm(residual: &[f32], scale: f32) -> String {
    let mm: Vec<String> = residual.iter().map(|r| format!("{:.0}", 1000.0 * r.sqrt() / scale)).collect();
    format!("{} mm", mm.join(" / "))
}

/// How far the read places are from the true ones in three dimensions (the reach arrives within
/// 10 mm): the median, the 90th percentile and the share within 10 mm.
fn distances(read: &Tensor, truth: &Tensor, scale: f32) -> candle_core::Result<String> {
    let mut mm: Vec<f32> =
        (read - truth)?.sqr()?.sum(1)?.sqrt()?.to_vec1::<f32>()?.iter().map(|d| 1000.0 * d / scale).collect();
    mm.sort_by(f32::total_cmp);
    let within = mm.iter().filter(|&&d| d <= 10.0).count() as f32 / mm.len() as f32;
    Ok(format!(
        "3-D error median {:.0} mm, 90th percentile {:.0} mm, {:.0} % within 10 mm",
        mm[mm.len() / 2],
        mm[mm.len() * 9 / 10],
        100.0 * within
    ))
}

/// Colour jitter on one image (RGB, channels last, values 0–255): torchvision's
/// `ColorJitter(brightness=0.4, contrast=0.4, saturation=0.4)`, with which RAD (Laskin et al.
/// 2020) augments pixel observations, and a gain per channel of ±10 % (a tinted light). The
/// image's colours change, never where anything is in it, so the target's place stays its label.
fn colour_jitter(image: &mut [f32], rng: &mut ChaCha8Rng) {
    let [brightness, contrast, saturation] = [0; 3].map(|_| rng.random_range(0.6f32..=1.4));
    let gain = [0; 3].map(|_| rng.random_range(0.9f32..=1.1));
    let grey = |p: &[f32]| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2];
    let mean = image.chunks(3).map(grey).sum::<f32>() / (image.len() / 3) as f32 * brightness;
    for pixel in image.chunks_mut(3) {
        let g = grey(pixel);
        for (c, v) in pixel.iter_mut().enumerate() {
            let saturated = g + saturation * (*v - g);
            let contrasted = mean + contrast * (saturated * brightness - mean);
            *v = (contrasted * gain[c]).clamp(0.0, 255.0);
        }
    }
}

/// A new look per arena at every reset, drawn from `looks`.
fn randomize_looks(app: &mut bevy::prelude::App, looks: Option<VisualRandomization>) {
    if looks.is_some() {
        app.add_plugins(RandomizationPlugin(Randomization { visual: looks, ..Default::default() }));
    }
}

/// The env, the labels' names, their scale, the images (pixel values as bytes: a quarter of the
/// floats' memory, so that ≈ 100,000 96×96 images fit) and the labels.
type Samples = (AppVecEnv, Vec<&'static str>, f32, Vec<u8>, Vec<f32>);

/// Pixel values (whole numbers 0–255 in the observation) as bytes.
fn as_bytes(pixels: &[f32]) -> impl Iterator<Item = u8> + '_ {
    pixels.iter().map(|&v| v as u8)
}

/// The units of the cart-pole's labels x, v, angle, rate: 0.1 m, 0.1 m/s, 0.1 rad, 1 rad/s.
const CARTPOLE_UNITS: [f32; 4] = [0.1, 0.1, 0.1, 1.0];
const CARTPOLE_LABELS: usize = CARTPOLE_UNITS.len();

/// The classical controller with random actions mixed in; each image labelled with the state
/// it shows (the arena's state after the step, before an ended episode's reset: skipped where
/// one ended).
fn cartpole_samples(
    samples: usize,
    settings: &PixelSettings,
    randomized: Option<VisualRandomization>,
) -> anyhow::Result<Samples> {
    let mut app = cartpole::headless_app(ARENAS, 0);
    settings.install(&mut app, &cartpole::robot().framing, ARENAS)?;
    randomize_looks(&mut app, randomized);
    let mut env = AppVecEnv::new(app);
    let dim = env.observation_space().dim();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (mut images, mut labels) = (Vec::with_capacity(samples * dim), Vec::with_capacity(samples * CARTPOLE_LABELS));
    env.reset(Some(0))?;
    while labels.len() < samples * CARTPOLE_LABELS {
        // The classical controller, with a random action a quarter of the time: long episodes
        // over the track, as a balancing policy's, and the falls between.
        let actions: Vec<f32> = env
            .arenas()
            .iter()
            .map(|&arena| {
                let s = *env.app().world().get::<cartpole::CartPoleState>(arena).expect("every arena has a state");
                if rng.random_bool(0.25) {
                    rng.random_range(0..2) as f32
                } else {
                    cartpole::feedback(&[s.x, s.v, s.angle, s.rate])[0]
                }
            })
            .collect();
        let step = env.step(&actions)?;
        for (i, &arena) in env.arenas().iter().enumerate() {
            if step.final_obs[i].is_some() {
                continue; // the state is already the next episode's
            }
            let s = *env.app().world().get::<cartpole::CartPoleState>(arena).expect("every arena has a state");
            images.extend(as_bytes(&step.obs[i * dim..(i + 1) * dim]));
            labels.extend([s.x, s.v, s.angle, s.rate].iter().zip(CARTPOLE_UNITS).map(|(value, unit)| value / unit));
        }
    }
    images.truncate(samples * dim);
    labels.truncate(samples * CARTPOLE_LABELS);
    Ok((env, vec!["x", "v", "angle", "rate"], 1.0, images, labels))
}

/// Labels in units of 10 cm: the target's x, y, z in the robot's base frame.
const UR5E_SCALE: f32 = 10.0;

/// An image every this many control steps of the reaches.
const UR5E_STRIDE: usize = 3;

/// Whole reaches, so that the images show what a reaching policy sees: the arm on its way and
/// over the target, where the target's place must be read most precisely (within the 1 cm an
/// arrival takes). The classical controller drives every arena, its action jittered by ±0.3 and
/// replaced by a random one a quarter of the time (a learning policy's strays); an arrival
/// resets the arena, and the image and the target after it are the next episode's alike.
fn ur5e_samples(
    samples: usize,
    settings: &PixelSettings,
    randomized: Option<VisualRandomization>,
    seed: u64,
) -> anyhow::Result<Samples> {
    let mut app = ur5e::headless_app_with(ARENAS, 0, DesignPattern::Supervised);
    settings.install(&mut app, &ur5e::robot().framing, ARENAS)?;
    randomize_looks(&mut app, randomized);
    let mut env = AppVecEnv::new(app);
    let dim = env.observation_space().dim();
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 1);
    let mut looks = ChaCha8Rng::seed_from_u64(seed + 2);
    let (mut images, mut labels) = (Vec::with_capacity(samples * dim), Vec::with_capacity(samples * 3));
    let mut obs = env.reset(Some(seed))?;
    for step in 0.. {
        if labels.len() >= samples * 3 {
            break;
        }
        let world = env.app().world();
        if step % UR5E_STRIDE == 0 {
            for (i, &arena) in env.arenas().iter().enumerate() {
                let target = world.get::<ur5e::CellState>(arena).expect("every arena has a state").target;
                images.extend(as_bytes(&obs[i * dim..(i + 1) * dim]));
                labels.extend((target * UR5E_SCALE).to_array());
            }
        }
        let mut actions = Vec::with_capacity(ARENAS * 5);
        for &arena in env.arenas() {
            let observed = world.get::<TaskObservation>(arena).expect("a pixel env keeps the task's observation");
            if rng.random_bool(0.25) {
                actions.extend((0..5).map(|_| rng.random_range(-1.0f32..1.0)));
            } else {
                actions.extend(
                    ur5e::controller::act(&observed.0)
                        .into_iter()
                        .map(|a| (a + rng.random_range(-0.3..0.3)).clamp(-1.0, 1.0)),
                );
            }
        }
        if (step + 1) % UR5E_STRIDE == 0 {
            // The next image's look (an arena that ends its episode draws one at its reset).
            redraw_looks(env.app_mut().world_mut(), &mut looks);
        }
        obs = env.step(&actions)?.obs;
    }
    images.truncate(samples * dim);
    labels.truncate(samples * 3);
    Ok((env, vec!["x", "y", "z"], UR5E_SCALE, images, labels))
}
