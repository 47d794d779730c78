//! Domain randomization: physical parameters per episode, d_randomize on actions, latency.

use twinbots_task::randomization::{Randomization, RandomizationPlugin};
use twinbots_api::VecEnv;
use twinbots_task::AppVecEnv;
use twinbots_sim::{Arena, JointState, Motor, MotorCommand, PositionSensor};

fn env(r: Randomization) -> (AppVecEnv, cartpole::CartPoleParts) {
    let mut app = cartpole::headless_app(1, 3);
    app.add_plugins(RandomizationPlugin(r));
    let mut env = AppVecEnv::new(app);
    env.reset(Some(3)).unwrap();
    let parts = *env.app().world().get::<cartpole::CartPoleParts>(env.arenas()[0]).unwrap();
    (env, parts)
}

fn wheel(env: &AppVecEnv, parts: &cartpole::CartPoleParts) -> MotorCommand {
    env.app().world().get::<Motor>(parts.wheels[0]).unwrap().command
}

#[test]
fn masses_friction_motor_strength_and_sensor_noise_are_randomized_at_reset() {
    let (mut env, parts) = env(Randomization {
        mass_scale: [2.0, 2.0],
        friction: Some([0.3, 0.3]),
        motor_strength: [0.5, 0.5],
        sensor_noise: 0.01,
        ..Default::default()
    });
    env.step(&[1.0]).unwrap();
    let world = env.app().world();
    let arena = world.get::<Arena>(env.arenas()[0]).unwrap();
    let cart_body = world.get::<twinbots_sim::Link>(parts.cart).unwrap().body;
    assert!((arena.world.bodies[cart_body].mass() - 4.0).abs() < 1e-4, "the 2 kg cart weighs double");
    assert!(arena.world.colliders.iter().all(|(_, c)| c.friction() == 0.3));
    assert_eq!(world.get::<Motor>(parts.wheels[0]).unwrap().strength, 0.5);
    let reading = world.get::<PositionSensor>(parts.pole_joint).unwrap();
    let truth = world.get::<JointState>(parts.pole_joint).unwrap().position;
    assert_eq!(reading.noise, 0.01);
    assert_ne!(reading.value, truth, "the sensor reads with noise");
    assert!((reading.value - truth).abs() < 0.06);
}

#[test]
fn action_latency_delays_every_action_by_that_many_steps() {
    let (mut env, parts) = env(Randomization { action_latency: 2, ..Default::default() });
    let mut commands = Vec::new();
    for a in [1.0, 0.0, 0.0, 1.0, 1.0] {
        env.step(&[a]).unwrap();
        commands.push(wheel(&env, &parts));
    }
    let v = |a: f32| MotorCommand::Velocity(if a > 0.5 { 5.0 } else { -5.0 });
    assert_eq!(commands, vec![MotorCommand::Off, MotorCommand::Off, v(1.0), v(0.0), v(0.0)]);
}

#[test]
fn d_randomize_overrides_the_first_steps_and_injects_random_actions() {
    let follow = |r: Randomization, steps: usize| {
        let (mut env, parts) = env(r);
        (0..steps)
            .map(|_| {
                env.step(&[1.0]).unwrap();
                wheel(&env, &parts) == MotorCommand::Velocity(5.0)
            })
            .collect::<Vec<bool>>()
    };
    let start = follow(Randomization { start_window: [6, 6], ..Default::default() }, 12);
    assert!(start[..6].iter().any(|f| !f), "random actions in the start window: {start:?}");
    assert!(start[6..].iter().all(|f| *f), "the agent's actions after it: {start:?}");
    let injected = follow(Randomization { action_probability: 1.0, ..Default::default() }, 20);
    assert!(injected.iter().filter(|f| !**f).count() >= 5, "{injected:?}");
    assert_eq!(follow(Randomization::default(), 10), vec![true; 10]);
}

#[test]
fn backwards_ranges_are_a_clear_error() {
    let err = Randomization { mass_scale: [1.2, 0.8], ..Default::default() }.validate().unwrap_err().to_string();
    assert!(err.contains("mass_scale"), "{err}");
    let err = toml::from_str::<Randomization>("mass_scal = [1, 2]").unwrap_err().to_string();
    assert!(err.contains("mass_scal"), "{err}");
}
