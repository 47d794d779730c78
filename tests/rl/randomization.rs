//! Domain randomization: physical parameters per episode, d_randomize on actions, latency.

use rand::SeedableRng;
use twinbots_api::VecEnv;
use twinbots_sim::Look;
use twinbots_sim::rapier::dynamics::RigidBodyAdditionalMassProps;
use twinbots_sim::{InArena, Joint, JointDynamics, JointState, Motor, MotorCommand, Parameters, PositionSensor};
use twinbots_task::AppVecEnv;
use twinbots_task::randomization::visual::{VisualRandomization, redraw_looks};
use twinbots_task::randomization::{FitSpread, Randomization, RandomizationPlugin};

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
    let arena = twinbots_sim::physics_in(world, env.arenas()[0]).unwrap();
    let cart_body = world.get::<twinbots_sim::Link>(parts.cart).unwrap().body;
    assert!((arena.bodies[cart_body].mass() - 4.0).abs() < 1e-4, "the 2 kg cart weighs double");
    assert!(arena.colliders.iter().all(|(_, c)| c.friction() == 0.3));
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
    app.insert_resource(fitted(&[
        ("pole_joint.damping", 0.01),
        ("pole_joint.armature", 0.002),
        ("command_delay", 0.004),
        ("pole_joint.bias", 0.1),
    ]));
    app.insert_resource(FitSpread(fitted(&[
        ("pole_joint.damping", 0.002),
        ("pole_joint.armature", 0.0005),
        ("command_delay", 0.001),
        ("pole_joint.bias", 0.01),
    ])));
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
                    let body = &twinbots_sim::physics_in(world, arena).unwrap().bodies[joint.child_body];
                    let Some(RigidBodyAdditionalMassProps::MassProps(props)) =
                        body.mass_properties().additional_local_mprops.as_deref()
                    else {
                        panic!("the pole carries its URDF inertial")
                    };
                    let inertia = props.principal_inertia();
                    [
                        dynamics.damping as f64,
                        dynamics.armature() as f64,
                        delay as f64,
                        (inertia.x + inertia.y + inertia.z) as f64,
                    ]
                })
                .collect()
        })
        .collect()
}

#[test]
fn randomization_centred_on_a_calibration_draws_per_arena_around_the_fit() {
    let centred = calibrated_draws(0.0, 5, 1);
    let [_, _, _, fitted_trace] = centred[0][0];
    assert!(
        centred[0].iter().all(|d| d[..3] == [0.01f32 as f64, 0.002f32 as f64, 0.004f32 as f64]),
        "k = 0: the fit as it is: {centred:?}"
    );
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
        assert!(
            (d[3] - fitted_trace - (d[1] - 0.002)).abs() < 1e-6,
            "inertia {} for armature {} (fitted: {fitted_trace})",
            d[3],
            d[1]
        );
    }
}

/// Each arena's look after each of `resets` resets, with arena 0's observations.
fn looks(visual: Option<VisualRandomization>, seed: u64, resets: usize) -> (Vec<Vec<Option<Look>>>, Vec<Vec<f32>>) {
    let mut app = cartpole::headless_app(2, seed);
    app.add_plugins(RandomizationPlugin(Randomization { visual, sensor_noise: 0.01, ..Default::default() }));
    let mut env = AppVecEnv::new(app);
    let mut obs = Vec::new();
    let looks = (0..resets)
        .map(|i| {
            obs.push(env.reset(Some(seed + i as u64)).unwrap());
            for _ in 0..5 {
                obs.push(env.step(&[1.0, 0.0]).unwrap().obs);
            }
            env.arenas().iter().map(|&a| env.app().world().get::<Look>(a).cloned()).collect()
        })
        .collect();
    (looks, obs)
}

#[test]
fn visual_randomization_draws_a_look_per_arena_and_episode_from_the_seed_alone() {
    let visual = VisualRandomization::default();
    let (draws, obs) = looks(Some(visual.clone()), 4, 3);
    assert_eq!(draws, looks(Some(visual.clone()), 4, 3).0, "the same seed draws the same looks");
    let all: Vec<Look> = draws.iter().flatten().map(|l| l.clone().expect("every arena has a look")).collect();
    for (i, a) in all.iter().enumerate() {
        for b in &all[i + 1..] {
            assert_ne!(a, b, "each arena and episode looks different");
        }
    }
    let look = &all[0];
    let names: Vec<&str> = look.surfaces.keys().map(String::as_str).collect();
    assert!(names.contains(&"floor") && names.iter().any(|n| n.starts_with("pole/")), "{names:?}");
    assert!((1..=3).contains(&look.lights.len()), "{:?}", look.lights);
    assert!(
        look.lights.iter().all(|l| (0.3..=0.9).contains(&l.intensity) && l.direction[2] < 0.0),
        "lights shine down: {:?}",
        look.lights
    );
    assert!(look.camera.offset.iter().all(|d| d.abs() <= 0.01) && look.camera.fov.abs() <= 5f32.to_radians());
    // The look comes from a stream of its own: switching it on changes no trajectory.
    let (none, plain) = looks(None, 4, 3);
    assert!(none.iter().flatten().all(Option::is_none));
    assert_eq!(obs, plain, "the physics (with sensor noise) draws the same with and without looks");
    // reset(seed) restarts the looks as it restarts the physics; a reset without one goes on.
    let mut app = cartpole::headless_app(1, 0);
    app.add_plugins(RandomizationPlugin(Randomization { visual: Some(visual.clone()), ..Default::default() }));
    let mut env = AppVecEnv::new(app);
    let mut look_after = |seed: Option<u64>| {
        env.reset(seed).unwrap();
        env.app().world().get::<Look>(env.arenas()[0]).cloned().unwrap()
    };
    let first = look_after(Some(9));
    assert_ne!(look_after(None), first);
    assert_eq!(look_after(Some(9)), first);
    assert!(look.distractors.is_empty(), "no distractors unless asked for");
    let cluttered = VisualRandomization { distractors: [2, 2], ..visual.clone() };
    let (draws, _) = looks(Some(cluttered), 4, 1);
    let boxes = &draws[0][0].as_ref().unwrap().distractors;
    assert_eq!(boxes.len(), 2);
    assert!(
        boxes
            .iter()
            .all(|d| d.half_extents.iter().all(|h| (0.015..=0.05).contains(h)) && d.centre[2] >= d.half_extents[2]),
        "{boxes:?}"
    );
    // Only the surfaces asked for change.
    let floor_only = VisualRandomization { surfaces: vec!["floor".into()], ..visual };
    let (draws, _) = looks(Some(floor_only), 4, 1);
    assert_eq!(draws[0][0].as_ref().unwrap().surfaces.keys().collect::<Vec<_>>(), ["floor"]);
}

/// Arena 0's observations over a few steps, with every arena's look redrawn (`redraw_looks`,
/// from `seed`) before each, and the looks after every step.
fn redrawn(visual: Option<VisualRandomization>, seed: u64) -> (Vec<Vec<f32>>, Vec<Vec<Option<Look>>>) {
    let mut app = cartpole::headless_app(2, 3);
    app.add_plugins(RandomizationPlugin(Randomization { visual, ..Default::default() }));
    let mut env = AppVecEnv::new(app);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut obs = vec![env.reset(Some(3)).unwrap()];
    let mut drawn = Vec::new();
    for _ in 0..4 {
        redraw_looks(env.app_mut().world_mut(), &mut rng);
        obs.push(env.step(&[1.0, 0.0]).unwrap().obs);
        drawn.push(env.arenas().iter().map(|&a| env.app().world().get::<Look>(a).cloned()).collect());
    }
    (obs, drawn)
}

#[test]
fn redrawn_looks_change_every_arena_mid_episode_and_nothing_else() {
    let visual = Some(VisualRandomization::default());
    let (obs, drawn) = redrawn(visual.clone(), 7);
    let all: Vec<Look> = drawn.iter().flatten().map(|l| l.clone().expect("every arena has a look")).collect();
    for (i, a) in all.iter().enumerate() {
        for b in &all[i + 1..] {
            assert_ne!(a, b, "each arena and step looks different");
        }
    }
    assert_eq!(redrawn(visual.clone(), 7).1, drawn, "the same stream draws the same looks");
    assert_ne!(redrawn(visual, 8).1, drawn);
    let (plain_obs, none) = redrawn(None, 7);
    assert!(none.iter().flatten().all(Option::is_none), "no looks without [randomization.visual]");
    assert_eq!(obs, plain_obs, "the physics goes on as without looks");
}

#[test]
fn bad_visual_randomization_is_a_clear_error_naming_the_key() {
    let dir = std::env::temp_dir().join(format!("twinbots-visual-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let not_png = dir.join("notes.png");
    std::fs::write(&not_png, "not an image").unwrap();
    let good = dir.join("good.png");
    image::RgbImage::from_pixel(4, 4, image::Rgb([10, 200, 30])).save(&good).unwrap();
    let check = |text: String| Randomization::from_config(&text).map(|_| ()).map_err(|e| format!("{e:#}"));
    let images = |paths: &[&std::path::Path]| {
        let list: Vec<String> = paths.iter().map(|p| format!("{:?}", p.display().to_string())).collect();
        format!("[randomization.visual]\ntextures = [\"image\"]\nimages = [{}]\n", list.join(", "))
    };
    assert_eq!(check(images(&[&good])), Ok(()));
    let err = check(images(&[&good, &dir.join("missing.png")])).unwrap_err();
    assert!(err.contains("randomization.visual.images[1]") && err.contains("missing.png"), "{err}");
    let err = check(images(&[&not_png])).unwrap_err();
    assert!(err.contains("randomization.visual.images[0]") && err.contains("not a PNG"), "{err}");
    for (text, key) in [
        ("light_intensity = [-1.0, 0.5]", "randomization.visual.light_intensity"),
        ("field_of_view = 95.0", "randomization.visual.field_of_view"),
        ("field_of_view = -1.0", "randomization.visual.field_of_view"),
        ("lights = [2, 11]", "randomization.visual.lights"),
        ("distractors = [3, 1]", "randomization.visual.distractors"),
        ("specular = [0.0, 2.0]", "randomization.visual.specular"),
        ("distractor_size = [0.0, 0.1]", "randomization.visual.distractor_size"),
        ("surfaces = [\"ceiling\"]", "ceiling"),
        ("textures = [\"marble\"]", "marble"),
        ("textures = [\"image\"]", "randomization.visual.images"),
        ("ambiance = [0.1, 0.2]", "ambiance"),
    ] {
        let err = check(format!("[randomization.visual]\n{text}\n")).unwrap_err();
        assert!(err.contains(key), "{text}: {err}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
