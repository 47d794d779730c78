//! Pixel observations (`[pixels]`): the arenas' images, stacked, with the final frame of an
//! ended episode, the same for the same seed, and bad settings named.

use twinbots_api::{Space, VecEnv};
use twinbots_render::PixelSettings;
use twinbots_task::AppVecEnv;

fn pixel_env(seed: u64, settings: &PixelSettings) -> AppVecEnv {
    let mut app = cartpole::headless_app(2, seed);
    settings.install(&mut app, &cartpole::robot().framing, 2).unwrap();
    AppVecEnv::new(app)
}

/// Every observation of `steps` bang-bang steps, and each ended episode's (final, next first).
fn run(seed: u64, settings: &PixelSettings, steps: usize) -> (Vec<Vec<f32>>, Vec<(Vec<f32>, Vec<f32>)>) {
    let mut env = pixel_env(seed, settings);
    let dim = env.observation_space().dim();
    let mut seen = vec![env.reset(Some(seed)).unwrap()];
    let mut ends = Vec::new();
    for t in 0..steps {
        let r = env.step(&[(t % 2) as f32, ((t / 3) % 2) as f32]).unwrap();
        for (i, last) in r.final_obs.iter().enumerate() {
            if let Some(last) = last {
                ends.push((last.clone(), r.obs[i * dim..(i + 1) * dim].to_vec()));
            }
        }
        seen.push(r.obs);
    }
    (seen, ends)
}

#[test]
fn pixel_observations_stack_the_arenas_images_keep_the_final_frame_and_repeat_with_the_seed() {
    if crate::renderer("pixel_observations_stack_the_arenas_images_keep_the_final_frame_and_repeat_with_the_seed", 8, 8)
        .is_none()
    {
        return;
    }
    let settings = PixelSettings { width: 48, height: 40, frames: 2, ..PixelSettings::default() };
    let env = pixel_env(3, &settings);
    let space = env.observation_space().clone();
    assert_eq!(space, Space::Image { height: 40, width: 48, channels: 6 });
    drop(env);

    let (seen, ends) = run(3, &settings, 60);
    assert!(seen.iter().all(|obs| obs.len() == 2 * space.dim() && obs.chunks(space.dim()).all(|o| space.contains(o))));
    // The newest image of one step is the older one of the next (pixel by pixel: RGB old, RGB new).
    let older = |obs: &[f32]| -> (Vec<f32>, Vec<f32>) {
        let (mut old, mut new) = (Vec::new(), Vec::new());
        for px in obs[..space.dim()].chunks(6) {
            old.extend_from_slice(&px[..3]);
            new.extend_from_slice(&px[3..]);
        }
        (old, new)
    };
    let moving = (1..seen.len()).filter(|&t| older(&seen[t - 1]).1 != older(&seen[t]).1).count();
    assert!(moving > 10, "the side camera sees the pole move: {moving} of 60 steps changed the image");
    for t in 1..20 {
        assert_eq!(older(&seen[t]).1, older(&seen[t + 1]).0, "step {t}");
    }
    assert!(!ends.is_empty(), "an episode ended in 60 steps");
    for (last, first) in &ends {
        assert_ne!(last, first, "the final observation is the ended episode's");
        let (old, new) = older(first);
        assert_eq!(old, new, "a new episode's first image is repeated");
    }
    let (again, _) = run(3, &settings, 60);
    assert!(seen == again, "the same seed gives the same images");
    let (other, _) = run(4, &settings, 60);
    assert!(seen != other, "another seed, other episodes");
}

#[test]
fn bad_pixel_settings_are_errors_naming_the_key() {
    let cases = [
        (
            PixelSettings { camera: "ceiling".into(), ..PixelSettings::default() },
            "pixels.camera = \"ceiling\": must be one of side, front, iso, top",
        ),
        (
            PixelSettings { more_cameras: vec!["ceiling".into()], ..PixelSettings::default() },
            "pixels.more_cameras: \"ceiling\" must be one of side, front, iso, top",
        ),
        (
            PixelSettings { more_cameras: vec!["front".into(), "side".into()], ..PixelSettings::default() },
            "pixels.more_cameras: \"side\" is named twice (with camera = \"side\")",
        ),
        (PixelSettings { fov: 0.0, ..PixelSettings::default() }, "pixels.fov = 0: must be in (0, 180) degrees"),
        (PixelSettings { fov: 180.0, ..PixelSettings::default() }, "pixels.fov = 180: must be in (0, 180) degrees"),
        (PixelSettings { fov: f32::NAN, ..PixelSettings::default() }, "pixels.fov = NaN"),
        (
            PixelSettings { width: 0, ..PixelSettings::default() },
            "pixels.width = 0: must be a whole number in 8..=1024",
        ),
        (PixelSettings { frames: 0, ..PixelSettings::default() }, "pixels.frames = 0: must be a whole number in 1..=8"),
    ];
    for (settings, message) in cases {
        let e = settings.validate().unwrap_err().to_string();
        assert!(e.starts_with(message), "{e:?} does not start with {message:?}");
    }
    let e = toml::from_str::<PixelSettings>("colour = 3").unwrap_err().to_string();
    assert!(e.contains("unknown field `colour`"), "{e}");
}

#[test]
fn a_pixel_run_trains_evaluates_captures_with_its_camera_and_exports_its_cnn_policy() {
    if crate::renderer("a_pixel_run_trains_evaluates_captures_with_its_camera_and_says_it_cannot_be_exported", 8, 8)
        .is_none()
    {
        return;
    }
    let dir = std::env::temp_dir().join(format!("twinbots-pixel-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("pixels.toml");
    std::fs::write(
        &config,
        "timesteps = 256\narenas = 2\neval_episodes = 2\n[pixels]\nwidth = 40\nheight = 40\nframes = 2\n\
         [ppo]\nn_steps = 64\nbatch_size = 64\nn_epochs = 1\nfeatures_dim = 16\n",
    )
    .unwrap();
    let run = dir.join("run");
    let twinbots =
        |args: &[&str]| std::process::Command::new(env!("CARGO_BIN_EXE_twinbots")).args(args).output().unwrap();
    let path = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let out = twinbots(&["train", "cartpole", "--config", &path(&config), "--out", &path(&run)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let model = std::fs::read_to_string(run.join("model/model.json")).unwrap();
    assert!(model.contains("\"Image\"") && model.contains("\"channels\": 6"), "{model}");
    let out = twinbots(&["eval", &path(&run), "--episodes", "2"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // Under looks it never saw (held-out textures and lights), beside its own evaluation.
    let out = twinbots(&["eval", &path(&run), "--episodes", "2", "--looks", "assets/looks/held-out.toml"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let held_out: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval-balance-in-held-out.json")).unwrap()).unwrap();
    assert_eq!(held_out["episodes"], 2, "{held_out}");
    let out = twinbots(&["eval", &path(&run), "--episodes", "2", "--looks", &path(&config)]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("pixels.toml: has no [randomization.visual] table"), "{e}");
    let frames = dir.join("frames");
    let out = twinbots(&[
        "capture",
        "cartpole",
        "--model",
        &path(&run),
        "--frames",
        "2",
        "--size",
        "64x48",
        "--out",
        &path(&frames),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(std::fs::read_dir(&frames).unwrap().count() >= 2);
    // The CNN policy leaves as ONNX: it reads camera images and chooses as the model does.
    let onnx = dir.join("p.onnx");
    let out = twinbots(&["export", &path(&run), "--onnx", &path(&onnx)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let policy = twinbots_onnx::OnnxPolicy::load(&onnx).unwrap();
    assert_eq!(policy.metadata.observation_space, twinbots_api::Space::Image { height: 40, width: 40, channels: 6 });
    let model = twinbots_learn::algos::load_run(&twinbots_learn::RunDir::new(&run)).unwrap();
    let images: Vec<f32> = (0..4 * 40 * 40 * 6).map(|i| ((i * 37) % 256) as f32).collect();
    assert_eq!(policy.act(&images).unwrap(), model.predict_deterministic(&images).unwrap());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn with_visual_randomization_each_arena_sees_its_own_look_and_the_seed_repeats_them() {
    use twinbots_task::randomization::{Randomization, RandomizationPlugin, visual::VisualRandomization};
    if crate::renderer("with_visual_randomization_each_arena_sees_its_own_look_and_the_seed_repeats_them", 8, 8)
        .is_none()
    {
        return;
    }
    let settings = PixelSettings { width: 40, height: 40, ..PixelSettings::default() };
    let images = |seed: u64| -> Vec<Vec<f32>> {
        let mut app = cartpole::headless_app(2, seed);
        app.add_plugins(RandomizationPlugin(Randomization {
            visual: Some(VisualRandomization::default()),
            ..Default::default()
        }));
        settings.install(&mut app, &cartpole::robot().framing, 2).unwrap();
        let mut env = AppVecEnv::new(app);
        let mut seen = vec![env.reset(Some(seed)).unwrap()];
        for t in 0..30 {
            seen.push(env.step(&[(t % 2) as f32, 1.0]).unwrap().obs);
        }
        seen
    };
    let first = images(7);
    let dim = settings.space().dim();
    assert_ne!(first[0][..dim], first[0][dim..], "two arenas, two looks");
    assert!(first == images(7), "the same seed, the same looks and frames");
    assert!(first[0] != images(8)[0], "another seed, other looks");
}

#[test]
fn more_cameras_see_each_arena_at_the_same_instant_under_its_one_look() {
    use twinbots_task::randomization::{Randomization, RandomizationPlugin, visual::VisualRandomization};
    if crate::renderer("more_cameras_see_each_arena_at_the_same_instant_under_its_one_look", 8, 8).is_none() {
        return;
    }
    let seen = |camera: &str, more: &[&str]| -> (Space, Vec<Vec<f32>>) {
        let settings = PixelSettings {
            camera: camera.into(),
            more_cameras: more.iter().map(|c| c.to_string()).collect(),
            width: 24,
            height: 16,
            frames: 2,
            ..PixelSettings::default()
        };
        let mut app = cartpole::headless_app(2, 5);
        app.add_plugins(RandomizationPlugin(Randomization {
            visual: Some(VisualRandomization::default()),
            ..Default::default()
        }));
        settings.install(&mut app, &cartpole::robot().framing, 2).unwrap();
        let mut env = AppVecEnv::new(app);
        let mut seen = vec![env.reset(Some(5)).unwrap()];
        for t in 0..12 {
            seen.push(env.step(&[(t % 2) as f32, 1.0]).unwrap().obs);
        }
        (env.observation_space().clone(), seen)
    };
    let (space, both) = seen("side", &["front"]);
    assert_eq!(space, Space::Image { height: 16, width: 48, channels: 6 });
    let (_, side) = seen("side", &[]);
    let (_, front) = seen("front", &[]);
    // Row by row: the side camera's 24 pixels (two frames' RGB each), then the front camera's.
    let camera = |obs: &[f32], c: usize| -> Vec<f32> {
        obs.chunks(48 * 6).flat_map(|row| row[c * 24 * 6..(c + 1) * 24 * 6].to_vec()).collect()
    };
    for t in 0..both.len() {
        assert_eq!(camera(&both[t], 0), side[t], "step {t}: the first camera's images are its alone");
        assert_eq!(camera(&both[t], 1), front[t], "step {t}: the second camera's too");
    }
    assert_ne!(side[3], front[3], "two cameras, two views");
}

/// Pixels of a signal-green surface (the reach's target marker) in an RGB image.
fn green(image: &[f32]) -> Vec<usize> {
    image
        .chunks(3)
        .enumerate()
        .filter(|(_, p)| p[1] > 100.0 && p[0] < 0.6 * p[1] && p[2] < 0.6 * p[1])
        .map(|(i, _)| i)
        .collect()
}

#[test]
fn the_camera_reach_shows_its_target_and_gets_the_arms_own_state_beside_the_image() {
    if crate::renderer("the_camera_reach_shows_its_target_and_gets_the_arms_own_state_beside_the_image", 8, 8).is_none()
    {
        return;
    }
    let state = vec!["joint_positions".to_string(), "joint_velocities".to_string()];
    let settings = PixelSettings { camera: "iso".into(), fov: 30.0, state, ..PixelSettings::default() };
    let env_of = |pixels: Option<&PixelSettings>| {
        let mut app = ur5e::headless_app_with(2, 5, twinbots_task::DesignPattern::Supervised);
        if let Some(p) = pixels {
            p.install(&mut app, &ur5e::robot().framing, 2).unwrap();
        }
        AppVecEnv::new(app)
    };
    let mut camera = env_of(Some(&settings));
    let mut plain = env_of(None);
    let space = camera.observation_space().clone();
    let image = 64 * 64 * 3;
    assert_eq!((space.image_shape(), space.state_dim(), space.dim()), (Some((64, 64, 3)), 12, image + 12), "{space}");
    assert_eq!(
        camera.task().observation_names[1..3],
        ["joint_positions[0]".to_string(), "joint_positions[1]".to_string()]
    );
    assert!(camera.task().goal.is_none(), "a goal seen by a camera is not relabelled");
    let (dim, full) = (space.dim(), plain.observation_space().dim());
    let mut seen = (camera.reset(Some(5)).unwrap(), plain.reset(Some(5)).unwrap());
    let mut spots = Vec::new();
    for t in 0..40 {
        for arena in 0..2 {
            let (c, p) = (&seen.0[arena * dim..(arena + 1) * dim], &seen.1[arena * full..(arena + 1) * full]);
            assert!(space.contains(c), "step {t}");
            assert_eq!(
                c[image..],
                p[..12],
                "step {t}, arena {arena}: the arm's angles and speeds, as the task observes them"
            );
            let marker = green(&c[..image]);
            assert!(
                marker.len() >= 2,
                "step {t}, arena {arena}: the target's marker in view ({} green pixels)",
                marker.len()
            );
            spots.push(marker);
        }
        let action: Vec<f32> = (0..10).map(|i| if (t / 5 + i) % 3 == 0 { 0.6 } else { -0.3 }).collect();
        let (c, p) = (camera.step(&action).unwrap(), plain.step(&action).unwrap());
        assert_eq!(c.rewards, p.rewards, "the same task underneath");
        seen = (c.obs, p.obs);
    }
    assert_ne!(spots[0], spots[1], "each arena's target where it is");

    let wrong = PixelSettings { state: vec!["target_offset".into(), "wrist".into()], ..PixelSettings::default() };
    let mut app = ur5e::headless_app_with(1, 5, twinbots_task::DesignPattern::Supervised);
    let e = wrong.install(&mut app, &ur5e::robot().framing, 1).unwrap_err().to_string();
    assert!(e.starts_with("pixels.state: the task ur5e observes no 'wrist'; its terms: joint_positions, joint_velocities, tcp_position"), "{e}");
}

#[test]
fn distill_teaches_a_pixel_run_by_the_classical_controller_and_the_taught_run_evaluates() {
    if crate::renderer("distill_teaches_a_pixel_run_by_the_classical_controller_and_the_taught_run_evaluates", 8, 8)
        .is_none()
    {
        return;
    }
    let dir = std::env::temp_dir().join(format!("twinbots-distill-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("pixels.toml");
    std::fs::write(&config, "timesteps = 128\narenas = 4\neval_episodes = 2\n[pixels]\nwidth = 40\nheight = 40\nframes = 2\n[ppo]\nn_steps = 32\nbatch_size = 64\nn_epochs = 1\nfeatures_dim = 16\n").unwrap();
    let twinbots =
        |args: &[&str]| std::process::Command::new(env!("CARGO_BIN_EXE_twinbots")).args(args).output().unwrap();
    let path = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let (student, taught) = (dir.join("student"), dir.join("taught"));
    let out = twinbots(&["train", "cartpole", "--config", &path(&config), "--out", &path(&student)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let distill = |out: &std::path::Path, more: &[&str]| {
        let mut args = vec![
            "distill".to_string(),
            path(&student),
            "--out".into(),
            path(out),
            "--rounds".into(),
            "5".into(),
            "--steps".into(),
            "150".into(),
        ];
        args.extend(["--epochs", "30", "--learning-rate", "3e-3"].map(String::from));
        args.extend(more.iter().map(|s| s.to_string()));
        twinbots(&args.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let out = distill(&taught, &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // The barely trained student mostly disagrees with the controller, and falls in 18 steps
    // or so; fitted to its answers (DAgger: the first fit only swings it to the other side),
    // it disagrees far less and balances longer.
    let csv = std::fs::read_to_string(taught.join("distill.csv")).unwrap();
    let column =
        |i: usize| -> Vec<f64> { csv.lines().skip(1).map(|l| l.split(',').nth(i).unwrap().parse().unwrap()).collect() };
    let (score, disagreement, answers) = (column(2), column(4), column(5));
    assert_eq!(answers, [600.0, 1200.0, 1800.0, 2400.0, 3000.0], "{csv}");
    assert!(disagreement[0] > 0.5 && disagreement[2..].iter().any(|&d| d < 0.6 * disagreement[0]), "{csv}");
    assert!(score[4] > 1.2 * score[0], "{csv}");
    let png = image::open(taught.join("distill.png")).unwrap();
    assert_eq!((png.width(), png.height()), (900, 700));
    let out = twinbots(&["eval", &path(&taught), "--episodes", "2"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // The same rounds again give the same student.
    let again = dir.join("again");
    assert!(distill(&again, &[]).status.success());
    assert_eq!(
        std::fs::read(taught.join("model/model.safetensors")).unwrap(),
        std::fs::read(again.join("model/model.safetensors")).unwrap()
    );
    // Errors name what is wrong: a taken --out, a teacher that is not there, a state run as the student.
    let e = String::from_utf8_lossy(&distill(&taught, &[]).stderr).to_string();
    assert!(e.contains("already holds a run"), "{e}");
    let e = String::from_utf8_lossy(&distill(&dir.join("x"), &["--teacher", "nowhere"]).stderr).to_string();
    assert!(e.contains("controller 'nowhere'"), "{e}");
    let state = dir.join("state");
    assert!(twinbots(&["train", "cartpole", "--timesteps", "64", "--out", &path(&state)]).status.success());
    let out = twinbots(&["distill", &path(&state), "--out", &path(&dir.join("y"))]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("not a pixel run"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}
