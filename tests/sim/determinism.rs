//! Same seed and actions, same trajectory, bit for bit; another seed, another trajectory.

use rand::{Rng, SeedableRng};
use twinbots_api::VecEnv;
use twinbots_sim::Arena;
use twinbots_task::AppVecEnv;
use twinbots_task::randomization::{Randomization, RandomizationPlugin};

fn run(seed: u64, steps: usize) -> Vec<u64> {
    let arenas = 3;
    let mut env = AppVecEnv::new(cartpole::headless_app(arenas, seed));
    env.reset(Some(seed)).unwrap();
    let mut actions = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    for _ in 0..steps {
        let a: Vec<f32> = (0..arenas).map(|_| actions.random_range(0..2) as f32).collect();
        env.step(&a).unwrap();
    }
    env.arenas().iter().map(|&e| env.app().world().get::<Arena>(e).unwrap().state_hash()).collect()
}

#[test]
fn same_seed_gives_identical_state_after_1000_steps() {
    let a = run(7, 1000);
    assert_eq!(a, run(7, 1000));
    assert_ne!(a, run(8, 1000), "a different seed starts the poles differently");
}

/// Arena 0's state hash and observation (as bits) after each of `steps` steps, with `others`
/// more arenas stepping beside it on their own random actions.
fn arena_0_beside(others: usize, steps: usize) -> Vec<(u64, Vec<u32>)> {
    let mut app = cartpole::headless_app(1 + others, 11);
    // Noisy sensors and injected actions draw from the arena's stream every step and at every
    // reset: a draw made for another arena's reset would show in arena 0's readings.
    app.add_plugins(RandomizationPlugin(Randomization {
        sensor_noise: 0.01,
        action_probability: 0.1,
        ..Default::default()
    }));
    let mut env = AppVecEnv::new(app);
    env.reset(Some(11)).unwrap();
    let mut ours = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let mut theirs = rand_chacha::ChaCha8Rng::seed_from_u64(6);
    let arena_0 = env.arenas()[0];
    (0..steps)
        .map(|_| {
            let mut a = vec![ours.random_range(0..2) as f32];
            a.extend((0..others).map(|_| theirs.random_range(0..2) as f32));
            let step = env.step(&a).unwrap();
            let observation = step.obs[..4].iter().map(|x| x.to_bits()).collect();
            (env.app().world().get::<Arena>(arena_0).unwrap().state_hash(), observation)
        })
        .collect()
}

#[test]
fn an_arena_steps_the_same_alone_or_beside_others_in_parallel() {
    // Alone, the arena steps inline; beside 7 others, on the worker pool, and the others'
    // episodes end and reset at other times than its own.
    let alone = arena_0_beside(0, 300);
    assert_eq!(alone, arena_0_beside(7, 300));
}
