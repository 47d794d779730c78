//! Domain randomization: physical parameters per episode, d_randomize on actions, latency.

use twinbots_task::randomization::{FitSpread, Randomization, RandomizationPlugin};
use twinbots_api::VecEnv;
use twinbots_task::AppVecEnv;
use twinbots_sim::rapier::dynamics::RigidBodyAdditionalMassProps;
use twinbots_sim::{Arena, InArena, Joint, JointDynamics, JointState, Motor, MotorCommand, Parameters, PositionSensor};

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

/// Pole damping, armature and the command delay of every arena after each of `resets` resets,
/// with the pole body's added inertia (trace) beside its armature.
fn calibrated_draws(k: f32, seed: u64, resets: usize) -> Vec<Vec<[f64; 4]>> {
    let fitted = |pairs: &[(&str, f64)]| Parameters(pairs.iter().map(|(n, v)| (n.to_string(), *v)).collect());
    let mut app = cartpole::headless_app(3, seed);
    app.insert_resource(fitted(&[("pole_joint.damping", 0.01), ("pole_joint.armature", 0.002), ("command_delay", 0.004), ("pole_joint.bias", 0.1)]));
    app.insert_resource(FitSpread(fitted(&[("pole_joint.damping", 0.002), ("pole_joint.armature", 0.0005), ("command_delay", 0.001), ("pole_joint.bias", 0.01)])));
    app.add_plugins(RandomizationPlugin(Randomization { calibration_spread: k, ..Default::default() }));
    let mut env = AppVecEnv::new(app);
    (0..resets)
        .map(|i| {
            env.reset(Some(seed + i as u64)).unwrap();
            let world = env.app().world();
            env.arenas()
                .iter()
                .map(|&arena| {
                    let parts = world.get::<cartpole::CartPoleParts>(arena).unwrap();
                    let joint = world.get::<Joint>(parts.pole_joint).unwrap();
                    let dynamics = world.get::<JointDynamics>(parts.pole_joint).unwrap();
                    let delay = world.get::<Motor>(parts.wheels[0]).unwrap().delay;
                    assert_eq!(world.get::<InArena>(parts.wheels[0]).unwrap().0, arena);
                    let body = &world.get::<Arena>(arena).unwrap().world.bodies[joint.child_body];
                    let Some(RigidBodyAdditionalMassProps::MassProps(props)) = body.mass_properties().additional_local_mprops.as_deref() else { panic!("the pole carries its URDF inertial") };
                    let inertia = props.principal_inertia();
                    [dynamics.damping as f64, dynamics.armature() as f64, delay as f64, (inertia.x + inertia.y + inertia.z) as f64]
                })
                .collect()
        })
        .collect()
}

#[test]
fn randomization_centred_on_a_calibration_draws_per_arena_around_the_fit() {
    let centred = calibrated_draws(0.0, 5, 1);
    let [_, _, _, fitted_trace] = centred[0][0];
    assert!(centred[0].iter().all(|d| d[..3] == [0.01f32 as f64, 0.002f32 as f64, 0.004f32 as f64]), "k = 0: the fit as it is: {centred:?}");
    let draws = calibrated_draws(2.0, 5, 20);
    assert_eq!(draws, calibrated_draws(2.0, 5, 20), "the seed fixes the draws");
    let all: Vec<[f64; 4]> = draws.iter().flatten().copied().collect();
    for (i, (centre, sigma)) in [(0.01, 0.002), (0.002, 0.0005), (0.004, 0.001)].into_iter().enumerate() {
        let values: Vec<f64> = all.iter().map(|d| d[i]).collect();
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let sd = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt();
        assert!((mean - centre).abs() < 2.0 * sigma, "parameter {i}: mean {mean} around {centre}");
        assert!(sd > 1.2 * sigma && sd < 2.8 * sigma, "parameter {i}: spread {sd}, 2σ = {}", 2.0 * sigma);
        assert!(values.iter().all(|v| *v >= 0.0));
    }
    assert!(draws.iter().all(|arenas| arenas[0] != arenas[1] && arenas[1] != arenas[2]), "each arena draws its own");
    // The drawn armature replaces the fitted one on the body: resets never pile inertia up.
    for d in &all {
        assert!((d[3] - fitted_trace - (d[1] - 0.002)).abs() < 1e-6, "inertia {} for armature {} (fitted: {fitted_trace})", d[3], d[1]);
    }
}
