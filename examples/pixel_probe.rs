//! Do the cart-pole's camera images carry what a policy needs? Collects pixel observations
//! (`[pixels]`: side camera, 64×64, 2 frames) under random actions, labelled with the pole's
//! angle and rate, fits a NatureCNN with a linear head to them by regression, and prints R² on
//! held-out images. A probe of the observation, apart from any RL.
//!
//! `cargo run --release --example pixel_probe -- [SAMPLES] [EPOCHS] [FOV]`

use candle_core::{Device, Tensor, Var};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use twinbots_api::VecEnv;
use twinbots_learn::nn::{Adam, AdamConfig, Encoder, PolicyKind};
use twinbots_render::PixelSettings;
use twinbots_task::AppVecEnv;

fn main() -> anyhow::Result<()> {
    twinbots_learn::threads::configure();
    let args: Vec<String> = std::env::args().collect();
    let samples: usize = args.get(1).map_or(Ok(4000), |s| s.parse())?;
    let epochs: usize = args.get(2).map_or(Ok(10), |s| s.parse())?;
    let fov: f32 = args.get(3).map_or(Ok(26.0), |s| s.parse())?;
    let settings = PixelSettings { fov, frames: 2, ..PixelSettings::default() };
    let arenas = 8;
    let mut app = cartpole::headless_app(arenas, 0);
    settings.install(&mut app, &cartpole::robot().framing, arenas)?;
    let mut env = AppVecEnv::new(app);
    let dim = env.observation_space().dim();

    // Random actions; each image labelled with the state it shows (the arena's state after the
    // step, before an ended episode's reset: the final observation where one ended).
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (mut images, mut labels) = (Vec::with_capacity(samples * dim), Vec::with_capacity(samples * 2));
    env.reset(Some(0))?;
    while labels.len() < samples * 2 {
        let actions: Vec<f32> = (0..arenas).map(|_| rng.random_range(0..2) as f32).collect();
        let step = env.step(&actions)?;
        for (i, &arena) in env.arenas().iter().enumerate() {
            if step.final_obs[i].is_some() {
                continue; // the state is already the next episode's
            }
            let s = *env.app().world().get::<cartpole::CartPoleState>(arena).expect("every arena has a state");
            images.extend_from_slice(&step.obs[i * dim..(i + 1) * dim]);
            labels.extend([s.angle / 0.1, s.rate / 1.0]);
        }
    }
    images.truncate(samples * dim);
    labels.truncate(samples * 2);
    let held_out = samples / 5;
    let train = samples - held_out;
    println!("{samples} images ({train} to fit, {held_out} held out), field of view {fov}°");

    let dev = Device::Cpu;
    let encoder = Encoder::new(PolicyKind::Cnn, env.observation_space(), 64, "probe", &mut ChaCha8Rng::seed_from_u64(2), &dev)?;
    let head_w = Var::from_tensor(&(Tensor::randn(0f32, 0.1, (2, 64), &dev)?))?;
    let head_b = Var::zeros(2, candle_core::DType::F32, &dev)?;
    let mut vars: Vec<Var> = encoder.named_vars().into_iter().map(|(_, v)| v).collect();
    vars.extend([head_w.clone(), head_b.clone()]);
    let mut adam = Adam::new(vars, AdamConfig { learning_rate: 3e-4, ..AdamConfig::default() });
    let predict = |x: &Tensor| -> candle_core::Result<Tensor> { encoder.forward(x)?.matmul(&head_w.as_tensor().t()?)?.broadcast_add(head_b.as_tensor()) };
    let rows = |from: usize, n: usize| -> candle_core::Result<(Tensor, Tensor)> {
        Ok((Tensor::from_slice(&images[from * dim..(from + n) * dim], (n, dim), &dev)?, Tensor::from_slice(&labels[from * 2..(from + n) * 2], (n, 2), &dev)?))
    };
    let batch = 128;
    for epoch in 1..=epochs {
        let started = std::time::Instant::now();
        let mut loss_sum = 0.0;
        for start in (0..train).step_by(batch) {
            let n = batch.min(train - start);
            let (x, y) = rows(start, n)?;
            let loss = (predict(&x)? - y)?.sqr()?.mean_all()?;
            loss_sum += loss.to_scalar::<f32>()? * n as f32;
            adam.step(&loss.backward()?, Some(10.0))?;
        }
        // R² per label on the held-out images: 1 − residual variance / label variance.
        let (x, y) = rows(train, held_out)?;
        let residual = (predict(&x)? - &y)?.sqr()?.mean(0)?.to_vec1::<f32>()?;
        let variance = y.broadcast_sub(&y.mean(0)?)?.sqr()?.mean(0)?.to_vec1::<f32>()?;
        println!(
            "epoch {epoch}: fit loss {:.3}, held-out R² angle {:.3}, rate {:.3} ({:.1} s)",
            loss_sum / train as f32,
            1.0 - residual[0] / variance[0],
            1.0 - residual[1] / variance[1],
            started.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
