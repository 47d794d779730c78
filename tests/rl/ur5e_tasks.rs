//! The UR5e's tasks end to end: the reach and the pick-and-place are achievable (the classical
//! resolved-rate controller, acting on the observation alone, succeeds) and report the
//! digital-twin figures; collisions are counted; runs are deterministic; under design pattern
//! 3 the arm homes itself before every episode, with no Supervisor in the app.

use std::collections::BTreeMap;
use std::time::Duration;

use twinbots_api::{DesignPattern, EpisodeSummary, VecEnv};
use twinbots_learn::{Flow, Ppo};
use twinbots_link::robot::{Controller, Phase, RobotRunState, ServerAddress};
use twinbots_server::server::{RobotServer, ServerSettings};
use twinbots_task::AppVecEnv;

/// Steps `env` with `policy` until `episodes` episodes have ended; returns them.
fn run_episodes(env: &mut AppVecEnv, episodes: usize, policy: impl Fn(&[f32]) -> Vec<f32>) -> Vec<EpisodeSummary> {
    let dim = env.observation_space().dim();
    let mut obs = env.reset(Some(1)).unwrap();
    let mut done = Vec::new();
    while done.len() < episodes {
        let actions: Vec<f32> = obs.chunks(dim).flat_map(&policy).collect();
        let step = env.step(&actions).unwrap();
        done.extend(step.episodes.into_iter().flatten());
        obs = step.obs;
    }
    done
}

fn figure(ep: &EpisodeSummary, name: &str) -> f32 {
    *ep.metrics.get(name).unwrap_or_else(|| panic!("episode reports no {name}: {:?}", ep.metrics))
}

#[test]
fn the_resolved_rate_controller_solves_the_reach_and_episodes_report_twin_figures() {
    let mut env = AppVecEnv::new(ur5e::headless_app_with(4, 21, DesignPattern::Supervised));
    let episodes = run_episodes(&mut env, 20, ur5e::controller::act);
    for ep in &episodes {
        assert_eq!(ep.success, Some(true), "{ep:?}");
        assert!(figure(ep, "final_error_mm") < 10.0);
        let cycle = figure(ep, "cycle_time_s");
        assert!(cycle > 0.2 && cycle < 4.0, "cycle time {cycle}");
        assert!(figure(ep, "energy_j") > 0.0);
        assert_eq!(figure(ep, "collision_events"), 0.0);
        assert_eq!(figure(ep, "joint_limit_events"), 0.0);
    }
}

#[test]
fn holding_still_fails_the_reach_and_spends_almost_no_energy() {
    let mut env = AppVecEnv::new(ur5e::headless_app_with(2, 3, DesignPattern::Supervised));
    let episodes = run_episodes(&mut env, 2, |_| vec![0.0; ur5e::arm::ACTION_DIM]);
    for ep in &episodes {
        assert_eq!(ep.success, Some(false));
        assert_eq!(ep.length, ur5e::reach::EPISODE_STEPS);
        assert!(!ep.metrics.contains_key("cycle_time_s"), "no cycle time without success");
        assert!(figure(ep, "energy_j") < 1.0, "holding still does (almost) no work: {}", figure(ep, "energy_j"));
    }
}

#[test]
fn driving_the_arm_into_the_table_counts_a_collision_and_costs_energy() {
    let mut env = AppVecEnv::new(ur5e::headless_app_with(1, 4, DesignPattern::Supervised));
    // Shoulder lift forward and elbow folding: the tool comes down onto the table.
    let episodes = run_episodes(&mut env, 1, |_| vec![0.0, 1.0, 0.5, 0.0, 0.0]);
    assert!(figure(&episodes[0], "collision_events") >= 1.0, "{:?}", episodes[0].metrics);
    assert!(figure(&episodes[0], "energy_j") > 5.0, "{:?}", episodes[0].metrics);
}

#[test]
fn pick_and_place_moves_the_part_from_fixture_a_to_fixture_b() {
    let mut env = AppVecEnv::new(ur5e::pick_place_app(2, 8, DesignPattern::Supervised));
    let episodes = run_episodes(&mut env, 2, ur5e::controller::act);
    for ep in &episodes {
        assert_eq!(ep.success, Some(true), "{ep:?}");
        let cycle = figure(ep, "cycle_time_s");
        assert!(cycle > 2.0 && cycle < 16.0, "cycle time {cycle}");
        assert!(figure(ep, "energy_j") > 0.0);
        assert_eq!(figure(ep, "collision_events"), 0.0);
        assert_eq!(figure(ep, "outcome_placed"), 1.0, "{:?}", ep.metrics);
    }
    // Holding still, the program never gets the part: no success, for want of time.
    let mut env = AppVecEnv::new(ur5e::pick_place_app(1, 8, DesignPattern::Supervised));
    let ep = &run_episodes(&mut env, 1, |_| vec![0.0; ur5e::arm::ACTION_DIM])[0];
    assert_eq!(ep.success, Some(false));
    assert_eq!(ep.length, ur5e::pick_place::EPISODE_STEPS);
    assert_eq!((figure(ep, "outcome_time_limit"), figure(ep, "outcome_placed")), (1.0, 0.0), "{:?}", ep.metrics);
}

#[test]
fn each_arena_builds_its_own_layout_and_the_program_follows_its_fixtures() {
    use ur5e::layout::{CellLayout, CellLayouts};
    let default = ur5e::layout::DEFAULT;
    let moved =
        default.replace("position = [-0.45, -0.35]", "position = [-0.30, -0.50]").replace("yaw = 0.0", "yaw = 30.0");
    // Beyond the arm's 0.85 m reach from the base, still on the table.
    let far = default.replace("position = [-0.45, -0.35]", "position = [-0.93, -0.50]");
    let layouts: Vec<CellLayout> = [("default", default.to_string()), ("moved", moved), ("far", far)]
        .iter()
        .map(|(name, text)| CellLayout::parse(text, name).unwrap())
        .collect();
    let mut app = ur5e::pick_place_app(3, 8, DesignPattern::Supervised);
    app.insert_resource(CellLayouts(layouts.clone()));
    let mut env = AppVecEnv::new(app);
    // Each arena's fixtures stand where its layout says, in the arena.
    let world = env.app_mut().world_mut();
    let nests: Vec<(bevy::prelude::Entity, bevy::math::Vec3)> = world
        .query::<(&twinbots_sim::Link, &twinbots_sim::InArena)>()
        .iter(world)
        .filter(|(l, _)| l.name == "nest")
        .map(|(l, a)| (a.0, twinbots_sim::physics_in(world, a.0).unwrap().bodies[l.body].translation()))
        .collect();
    let far_arena = env.arenas()[2];
    let far_nests: Vec<_> = nests.iter().filter(|(a, _)| *a == far_arena).map(|(_, p)| p.truncate()).collect();
    assert_eq!(far_nests.len(), 2);
    assert!(far_nests.iter().any(|p| (*p - bevy::math::Vec2::new(-0.93, -0.50)).length() < 1e-4), "{far_nests:?}");
    let dim = env.observation_space().dim();
    let mut obs = env.reset(Some(1)).unwrap();
    let mut ended: Vec<Option<EpisodeSummary>> = vec![None; 3];
    while ended.iter().any(Option::is_none) {
        let actions: Vec<f32> = obs.chunks(dim).flat_map(ur5e::controller::act).collect();
        let step = env.step(&actions).unwrap();
        for (i, ep) in step.episodes.into_iter().enumerate() {
            if ended[i].is_none() {
                ended[i] = ep;
            }
        }
        obs = step.obs;
    }
    let outcome = |i: usize| ended[i].as_ref().unwrap();
    assert_eq!(outcome(0).success, Some(true), "default cell: {:?}", outcome(0).metrics);
    assert_eq!(outcome(1).success, Some(true), "fixture moved, robot turned 30°: {:?}", outcome(1).metrics);
    assert_eq!(outcome(2).success, Some(false), "place fixture out of reach: {:?}", outcome(2).metrics);
}

#[test]
fn the_same_seed_gives_the_same_reach_trajectory() {
    let run = || {
        let mut env = AppVecEnv::new(ur5e::headless_app_with(2, 9, DesignPattern::Supervised));
        let episodes = run_episodes(&mut env, 4, ur5e::controller::act);
        let state: Vec<u64> = env
            .arenas()
            .iter()
            .map(|&a| env.app().world().get::<twinbots_sim::Arena>(a).unwrap().state_hash())
            .collect();
        (episodes.iter().map(|e| (e.score.to_bits(), e.length)).collect::<Vec<_>>(), state)
    };
    assert_eq!(run(), run());
}

#[test]
fn an_evaluation_that_can_no_longer_pass_stops_on_the_failure_that_rules_it_out() {
    use twinbots_learn::evaluation::{evaluate_against, evaluate_policy};
    let spec = ur5e::task_spec();
    let criterion = spec.solved.expect("the reach has a solved criterion");
    // An untrained policy: no reach succeeds, so 98 % of 200 is out of reach at the fifth failure.
    let model =
        Ppo::new(ur5e::robot().defaults.of("ppo").config().unwrap(), spec.observation_space, spec.action_space, 0)
            .unwrap();
    let env = || AppVecEnv::new(ur5e::headless_app_with(4, 11, DesignPattern::Supervised));
    let judged = evaluate_against("reach", &model, &mut env(), 200, 11, &criterion).unwrap();
    assert!(
        (5..=8).contains(&judged.episodes),
        "stopped after {} episodes (5 failures, up to 3 more ending in the same step)",
        judged.episodes
    );
    assert_eq!(judged.success_rate, Some(0.0));
    assert!(!judged.meets(&criterion));
    // Each episode says how it ended: a termination term of the task, or its time limit.
    assert_eq!(judged.ended_by.values().sum::<usize>(), judged.episodes, "{:?}", judged.ended_by);
    let ways: Vec<String> =
        spec.termination_terms.iter().cloned().chain([twinbots_learn::evaluation::TIME_LIMIT.to_string()]).collect();
    assert!(judged.ended_by.keys().all(|way| ways.contains(way)), "{:?} not among {ways:?}", judged.ended_by);
    // The episodes it ran are the first of the full evaluation, bit for bit.
    let full = evaluate_policy("reach", &model, &mut env(), judged.episodes, 11).unwrap();
    assert_eq!(
        full.scores.iter().map(|s| s.to_bits()).collect::<Vec<_>>(),
        judged.scores.iter().map(|s| s.to_bits()).collect::<Vec<_>>()
    );
}

#[test]
fn under_pattern_3_the_arm_drives_itself_to_its_drawn_start_before_every_episode() {
    let id = ur5e::task_spec();
    let model = Box::new(
        Ppo::new(ur5e::robot().defaults.of("ppo").config().unwrap(), id.observation_space, id.action_space, 0).unwrap(),
    );
    let settings = ServerSettings::new("ur5e", &ur5e::task_spec(), 2, 1_000_000);
    let server = RobotServer::start(
        "127.0.0.1:0".parse().unwrap(),
        model,
        settings,
        Box::new(|_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)),
    )
    .unwrap();
    let address = ServerAddress { addr: server.addr, patience: Duration::from_secs(5) };
    let mut app = ur5e::headless_app_with(2, 5, DesignPattern::Server);
    app.insert_resource(address);
    app.finish();
    app.cleanup();
    app.update();
    assert!(!app.world().contains_resource::<twinbots_sim::SupervisorAccess>(), "pattern 3 has no Supervisor");
    let mut robots = app.world_mut().query::<(bevy::prelude::Entity, &Controller, &ur5e::CellState)>();
    // Per robot: its phase and reading after the previous step.
    let mut previous: BTreeMap<bevy::prelude::Entity, (Phase, Option<ur5e::arm::ArmState>)> = BTreeMap::new();
    let (mut starts, mut away_from_home) = (0, 0);
    let mut steps = 0;
    while app.world().resource::<RobotRunState>().episodes < 4 {
        app.update();
        steps += 1;
        assert!(steps < 2000, "only {} episodes in {steps} steps", app.world().resource::<RobotRunState>().episodes);
        assert!(
            app.world().resource::<RobotRunState>().stop.is_none(),
            "{:?}",
            app.world().resource::<RobotRunState>().stop
        );
        for (entity, robot, state) in robots.iter(app.world()) {
            // Homed, announced and answered within one step: the reading it started on, the
            // previous step's, was the start its task drew (near home, as under pattern 1).
            let was = previous.insert(entity, (robot.phase(), state.read.then(|| state.arm.clone())));
            if let Some((Phase::Homing, reading)) = was
                && robot.phase() == Phase::Running
            {
                starts += 1;
                let arm = reading.expect("a robot starts only once it has read its encoders");
                assert!(
                    arm.is_at(&state.start_pose),
                    "an episode started away from its drawn start {:?}: {:?} at {:?}",
                    state.start_pose,
                    arm.q,
                    arm.qd
                );
                away_from_home += usize::from(!arm.is_home());
            }
        }
    }
    assert!(starts >= 4, "{starts} episodes started");
    assert!(away_from_home > 0, "every episode started at home: the drawn starts were not driven to");
}

fn twinbots() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_twinbots"))
}

#[test]
fn train_and_eval_ur5e_from_the_cli_report_success_and_twin_figures() {
    let out = std::env::temp_dir().join(format!("twinbots-ur5e-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    let config = out.join("short.toml");
    std::fs::write(&config, "timesteps = 2048\narenas = 2\neval_every = 2\neval_episodes = 4\n[ppo]\nn_steps = 256\n")
        .unwrap();
    // In a cell of its own: the place fixture moved (docs/cells.md).
    let cell = out.join("cell.toml");
    std::fs::write(&cell, ur5e::layout::DEFAULT.replace("position = [-0.45, -0.35]", "position = [-0.30, -0.45]"))
        .unwrap();
    let run = out.join("run");
    let status = twinbots()
        .args(["train", "ur5e", "--config"])
        .arg(&config)
        .arg("--cell")
        .arg(&cell)
        .arg("--out")
        .arg(&run)
        .status()
        .unwrap();
    assert!(status.success());
    let recorded: toml::Table = toml::from_str(&std::fs::read_to_string(run.join("config.toml")).unwrap()).unwrap();
    assert_eq!(
        recorded["cell"]["place"]["position"].as_array().unwrap()[1].as_float(),
        Some(-0.45),
        "the run keeps its cell: {recorded:?}"
    );
    // A cell that cannot stand, or a robot without a cell file, is a clear error.
    let bad = out.join("bad-cell.toml");
    std::fs::write(&bad, ur5e::layout::DEFAULT.replace("position = [-0.45, -0.35]", "position = [-0.45, -0.95]"))
        .unwrap();
    let output = twinbots().args(["train", "ur5e", "--print-config", "--cell"]).arg(&bad).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success()
            && err.contains(
                "bad-cell.toml: place.position = [-0.45, -0.95]: the fixture's 12 cm plate leaves the table top"
            ),
        "{err}"
    );
    let output = twinbots().args(["train", "cartpole", "--print-config", "--cell"]).arg(&cell).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && err.contains("cartpole's cell is not laid out by a file"), "{err}");
    let progress = std::fs::read_to_string(run.join("progress.csv")).unwrap();
    assert!(progress.lines().next().unwrap().split(',').any(|c| c == "success_rate"), "{progress}");
    let evaluations = std::fs::read_to_string(run.join("evaluations.csv")).unwrap();
    let rows: Vec<&str> = evaluations.lines().collect();
    assert_eq!(rows.len(), 1 + 2, "evaluations after updates 2 and 4: {evaluations}");
    let rate: f32 = rows[1].rsplit(',').next().unwrap().parse().expect("a success rate");
    assert!((0.0..=1.0).contains(&rate));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap();
    assert!(summary["evaluation"]["success_rate"].is_number(), "{summary}");

    // The reach model runs pick-and-place: its own figures, in their own file.
    let output =
        twinbots().args(["eval"]).arg(&run).args(["--episodes", "2", "--task", "pick-place"]).output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(
        text.contains("pick-place: 2 episodes") && text.contains("success rate") && text.contains("energy_j"),
        "{text}"
    );
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval-pick-place.json")).unwrap()).unwrap();
    assert_eq!(eval["task"], "pick-place");
    assert!(eval["metrics"]["energy_j"].as_f64().unwrap() > 0.0);

    // An unknown task names the known ones.
    let output = twinbots().args(["eval"]).arg(&run).args(["--task", "weld"]).output().unwrap();
    assert!(!output.status.success());
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(err.contains("ur5e has no task 'weld'; its tasks: reach, pick-place"), "{err}");
    std::fs::remove_dir_all(&out).ok();
}

/// Success needs all three conditions (issue 15.5): the TCP within 1 cm, the tool pointing
/// down (tilt < 0.1 rad) and at rest (slower than 5 cm/s). A state that breaks one of them
/// alone, the other two clearly met, is not a success.
#[test]
fn a_reach_succeeds_only_within_a_centimetre_pointing_down_and_at_rest() {
    use ur5e::arm::{ArmState, REACH_TOLERANCE, SETTLED_SPEED, TILT_TOLERANCE};
    use ur5e::kinematics::{HOME, tilt};
    let still = [0.0; 6];
    let at = |arm: &ArmState| arm.tcp.translation;
    let conditions = |arm: &ArmState, target| {
        (
            arm.distance_to(target) < REACH_TOLERANCE,
            tilt(&arm.tcp) < TILT_TOLERANCE,
            arm.tcp_velocity.length() < SETTLED_SPEED,
        )
    };

    // All three met: home points straight down, at rest, on its target.
    let home = ArmState::from_joints(HOME, still);
    assert_eq!(conditions(&home, at(&home)), (true, true, true));
    assert!(home.has_reached(at(&home)));

    // 1.5 cm off, pointing down, at rest.
    let off = at(&home) + bevy::math::Vec3::X * 0.015;
    assert_eq!(conditions(&home, off), (false, true, true));
    assert!(!home.has_reached(off), "1.5 cm away counted as arrived");

    // On the target, at rest, but tilted by 0.2 rad (wrist 2 turned).
    let mut q = HOME;
    q[4] += 0.2;
    let tilted = ArmState::from_joints(q, still);
    assert_eq!(conditions(&tilted, at(&tilted)), (true, false, true));
    assert!(!tilted.has_reached(at(&tilted)), "a tilted tool counted as arrived");

    // On the target, pointing down, but passing through at 0.2 rad/s of the base (≈ 8 cm/s).
    let mut qd = still;
    qd[0] = 0.2;
    let moving = ArmState::from_joints(HOME, qd);
    assert_eq!(conditions(&moving, at(&moving)), (true, true, false));
    assert!(!moving.has_reached(at(&moving)), "a moving tool counted as arrived");
}

#[test]
fn the_learned_pick_and_place_is_achievable_from_its_observation_and_reports_its_figures() {
    use ur5e::pick_place_learned::{EPISODE_STEPS, scripted};
    let app = || ur5e::robot().app(Some("pick-place-learned"), 4, 5, DesignPattern::Supervised).unwrap();
    let mut env = AppVecEnv::new(app());
    let episodes = run_episodes(&mut env, 24, scripted);
    let successes = episodes.iter().filter(|e| e.success == Some(true)).count();
    let lifted = episodes.iter().filter(|e| figure(e, "goal_in_air") == 1.0).count();
    for ep in episodes.iter().filter(|e| e.success == Some(true)) {
        assert!(figure(ep, "final_distance_mm") < 20.0, "{ep:?}");
        assert!(figure(ep, "cycle_time_s") > 0.0 && ep.length < EPISODE_STEPS, "{ep:?}");
        assert_eq!(figure(ep, "protective_stops"), 0.0, "{ep:?}");
    }
    assert!(successes >= 22, "the scripted pick-and-place met {successes} of 24 goals: {episodes:?}");
    assert!((4..=20).contains(&lifted), "{lifted} of 24 goals in the air");
    // Holding still meets no goal but the ones the part already stands on (none here).
    let mut env = AppVecEnv::new(app());
    let still = run_episodes(&mut env, 4, |_| vec![0.0; 4]);
    for ep in &still {
        assert_eq!((ep.success, ep.length), (Some(false), EPISODE_STEPS), "{ep:?}");
        assert_eq!(figure(ep, "part_lifted"), 0.0);
    }
}

/// `train --task` learns a task with spaces of its own, with that task's defaults (the learned
/// pick-and-place: SAC + HER); the run remembers its task, so `eval` judges its model on it; a
/// task that runs the main task's model is no task to train.
#[test]
fn train_learns_the_pick_and_place_task_by_name_and_eval_judges_the_run_on_it() {
    let out = std::env::temp_dir().join(format!("twinbots-ur5e-learned-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let output = twinbots().args(["train", "ur5e", "--task", "pick-place-learned", "--print-config"]).output().unwrap();
    let config = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success()
            && config.contains("task = \"pick-place-learned\"")
            && config.contains("algo = \"sac\""),
        "{config}"
    );
    assert!(
        config.contains("her_goals = 4") && config.contains("hidden = [\n    128,\n    128,\n]"),
        "the task's own SAC defaults: {config}"
    );
    let output = twinbots().args(["train", "ur5e", "--task", "pick-place", "--print-config"]).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success()
            && err.contains("task 'pick-place' runs a model of its task 'reach'")
            && err.contains("tasks that train: reach, pick-place-learned"),
        "{err}"
    );

    let run = out.join("run");
    let status = twinbots()
        .args(["train", "ur5e", "--task", "pick-place-learned", "--timesteps", "1200", "--arenas", "2", "--out"])
        .arg(&run)
        .status()
        .unwrap();
    assert!(status.success());
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval.json")).unwrap()).unwrap();
    assert_eq!(eval["task"], "pick-place-learned", "{eval}");
    assert!(eval["metrics"]["final_distance_mm"].as_f64().unwrap() > 0.0, "{eval}");
    let output = twinbots().args(["eval"]).arg(&run).args(["--episodes", "2"]).output().unwrap();
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success() && text.contains("pick-place-learned: 2 episodes"),
        "{text}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // Its policy exports as ONNX; a deploy bundle (the reach's joint-speed program) refuses it.
    let output = twinbots().args(["export", "--onnx"]).arg(out.join("policy.onnx")).arg(&run).output().unwrap();
    assert!(
        output.status.success()
            && String::from_utf8_lossy(&output.stdout).contains("pick-place-learned (26 observations → Box(4))"),
        "{output:?}"
    );
    let output = twinbots().args(["export", "--bundle"]).arg(out.join("bundle")).arg(&run).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && err.contains("task 'pick-place-learned' has no deployment yet"), "{err}");
    // Its model has other spaces than the reach's: the reach's tasks refuse it.
    let output = twinbots().args(["eval"]).arg(&run).args(["--episodes", "1", "--task", "reach"]).output().unwrap();
    assert!(!output.status.success(), "{}", String::from_utf8_lossy(&output.stdout));
    std::fs::remove_dir_all(&out).ok();
}
