//! Every algorithm of the table that says it `serves` learns through the RobotServer: robots
//! on their own threads step the analytic Pendulum-v1 and talk the protocol over TCP, the
//! server trains SAC (or TD3) on what they send.

use std::net::SocketAddr;
use std::time::Instant;

use twinbots_api::{TaskSpec, VecEnv};
use twinbots_learn::classic::ClassicPendulum;
use twinbots_learn::{Agent, Flow, Learner, OffPolicyConfig, Sac, SacConfig, Td3, Td3Config, UpdateStats, algos};
use twinbots_link::protocol::{RobotMessage, ServerMessage, VERSION};
use twinbots_server::server::{RobotServer, ServerSettings};

use crate::server::Robot;

/// Pendulum-v1 as a task a server serves: its spaces, and its reward's range per step
/// (−(π² + 0.1·8² + 0.001·2²) to 0).
fn pendulum_task() -> TaskSpec {
    let env = ClassicPendulum::new(1);
    TaskSpec {
        name: "swing-up".into(),
        observation_space: env.observation_space().clone(),
        action_space: env.action_space().clone(),
        solved: None,
        observation_names: vec!["cos_theta".into(), "sin_theta".into(), "theta_dot".into()],
        reward_terms: vec!["cost".into()],
        termination_terms: vec![],
        reward_range: (-16.5, 0.0),
        observation_plausible: env.observation_space().clone(),
        goal: None,
    }
}

/// A pendulum robot: steps its own Pendulum-v1 (seeded by `seed`) with the server's actions
/// until the server says training is done; returns the episodes it finished.
fn pendulum_robot(addr: SocketAddr, seed: u64) -> u32 {
    let spec = pendulum_task();
    let mut robot = Robot::connect(addr);
    let hello = RobotMessage::Hello {
        version: VERSION,
        robot: "pendulum".into(),
        observation_space: spec.observation_space,
        action_space: spec.action_space,
        token: None,
    };
    assert!(matches!(robot.call(&hello), ServerMessage::Welcome { .. }));
    let mut env = ClassicPendulum::new(1);
    let mut obs = env.reset(Some(seed)).unwrap();
    let mut episodes = 0;
    let mut reply = robot.call(&RobotMessage::Start { obs: obs.clone() });
    loop {
        match reply {
            ServerMessage::Action { action } => {
                let out = env.step(&action).unwrap();
                let last = out.final_obs[0].clone();
                reply = robot.call(&RobotMessage::Step {
                    obs: last.clone().unwrap_or_else(|| out.obs.clone()),
                    reward: out.rewards[0],
                    terminated: out.terminated[0],
                    truncated: out.truncated[0],
                    success: None,
                    ended_by: None,
                });
                obs = out.obs;
                if last.is_some() {
                    episodes += 1;
                }
            }
            ServerMessage::Ack => reply = robot.call(&RobotMessage::Start { obs: obs.clone() }),
            ServerMessage::Done { .. } => return episodes,
            other => panic!("{other:?}"),
        }
    }
}

/// Serves `model` to two pendulum robots for `steps` steps; the mean of its last 10 training
/// episodes and its rows (steps, mean score, applied gradient steps).
fn serve_pendulum(model: Box<dyn Learner>, steps: u64) -> (f32, Vec<(u64, f32, usize)>) {
    let started = Instant::now();
    let rows = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let seen = rows.clone();
    let callback = move |s: &UpdateStats, _: &dyn Agent| {
        eprintln!("{} steps: mean {:.0} ({:.0} s)", s.timesteps, s.mean_reward, started.elapsed().as_secs_f32());
        seen.lock().unwrap().push((s.timesteps, s.mean_reward, s.applied_steps));
        Ok(Flow::Continue)
    };
    let settings = ServerSettings::new("pendulum", &pendulum_task(), 2, steps);
    let server = RobotServer::start("127.0.0.1:0".parse().unwrap(), model, settings, Box::new(callback)).unwrap();
    let addr = server.addr;
    let robots: Vec<_> = (0..2).map(|r| std::thread::spawn(move || pendulum_robot(addr, 10 + r))).collect();
    let (model, _) = server.wait().unwrap();
    let finished: u32 = robots.into_iter().map(|r| r.join().unwrap()).sum();
    assert_eq!(model.timesteps(), steps, "every step of a finished episode is learnt from");
    assert_eq!(model.episodes(), steps / 200);
    assert!(finished as u64 >= steps / 200, "{finished} episodes finished by the robots");
    let recent: Vec<f32> = model.history().recent_scores.iter().rev().take(10).copied().collect();
    let rows = rows.lock().unwrap().clone();
    (recent.iter().sum::<f32>() / recent.len() as f32, rows)
}

/// SAC as `sac_reaches_minus_200_on_pendulum_within_20k_steps` trains it, served: two robots
/// and two gradient steps per step of both (one per transition, as there).
#[test]
fn sac_served_to_two_robots_reaches_minus_200_on_pendulum_within_20k_steps() {
    let spec = pendulum_task();
    let config = SacConfig {
        off_policy: OffPolicyConfig { gradient_steps: 2, ..Default::default() },
        hidden: vec![64, 64],
        ..SacConfig::default()
    };
    let model = Sac::new(config, spec.observation_space, spec.action_space, 0).unwrap();
    let (mean, rows) = serve_pendulum(Box::new(model), 20_000);
    assert!(mean >= -200.0, "mean of the last 10 episodes {mean}; rows {rows:?}");
    // Gradient steps: one per transition from `learning_starts` (100) on.
    let applied: usize = rows.iter().map(|r| r.2).sum();
    assert!((19_000..=20_000).contains(&applied), "{applied} gradient steps");
}

/// TD3 serves too: a short run learns from every step and logs its rows.
#[test]
fn td3_is_served_and_learns_from_every_step() {
    let spec = pendulum_task();
    let config = Td3Config {
        off_policy: OffPolicyConfig { learning_starts: 200, batch_size: 32, ..Td3Config::default().off_policy },
        hidden: vec![16, 16],
        log_interval: 100,
        ..Td3Config::default()
    };
    let model = Td3::new(config, spec.observation_space, spec.action_space, 0).unwrap();
    let (mean, rows) = serve_pendulum(Box::new(model), 2_000);
    assert!(mean.is_finite());
    // A row per 100 iterations of two robots (200 steps), each a finished episode's end.
    assert_eq!(rows.iter().map(|r| r.0).collect::<Vec<_>>(), (1..=10).map(|k| k * 200).collect::<Vec<_>>());
    assert!(rows.iter().skip(1).all(|r| r.2 > 0), "gradient steps in every row after learning starts: {rows:?}");
}

/// The table says which algorithms a RobotServer trains, and each of them can be served.
#[test]
fn every_algorithm_the_table_says_serves_can_be_served() {
    let spec = pendulum_task();
    // Behaviour cloning is made from demonstrations: two frames of the pendulum's.
    let demos = std::env::temp_dir().join(format!("twinbots-served-demos-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&demos);
    let names = |n: usize| (0..n).map(|i| i.to_string()).collect::<Vec<_>>();
    let dataset = twinbots_dataset::DatasetSpec {
        robot: "pendulum".into(),
        fps: 20.0,
        state_names: names(3),
        action_names: names(1),
        cameras: Vec::new(),
    };
    let mut writer = twinbots_dataset::DatasetWriter::new(&demos, dataset).unwrap();
    let frame = |done| twinbots_dataset::Frame {
        state: vec![1.0, 0.0, 0.5],
        action: vec![-1.0],
        reward: -0.1,
        done,
        success: false,
        images: Vec::new(),
    };
    writer
        .add(twinbots_dataset::Episode { task: "swing-up".into(), seed: 0, frames: vec![frame(false), frame(true)] })
        .unwrap();
    writer.finish().unwrap();
    for algorithm in algos::ALGOS {
        let mut keys = toml::Table::new();
        if algorithm.name == twinbots_learn::bc::NAME {
            keys.insert("demos".into(), demos.display().to_string().into());
        }
        let config = (algorithm.config)(&keys, 1).unwrap();
        let model = (algorithm.new)(&config, &spec, 0).unwrap();
        let served = model.serve(2, 1000);
        assert_eq!(served.is_ok(), algorithm.serves, "{}: {:?}", algorithm.name, served.err());
    }
    std::fs::remove_dir_all(&demos).unwrap();
}

/// The UR5e's reach served with SAC and HER (the robot's own SAC settings) to two simulated
/// robots under pattern 3: every finished episode lies whole in the replay buffer, its steps
/// one after another, and the steps a termination term ended carry its name (`ended_by`, sent
/// by the robots), which HER recomputes rewards with.
#[test]
fn sac_with_her_served_to_ur5e_robots_stores_whole_episodes_with_their_ending_terms() {
    use twinbots_api::DesignPattern;
    use twinbots_link::robot::ServerAddress;
    let spec = ur5e::task_spec();
    // 800 steps of random exploration, then 800 learning: with 400 and 400, 1 to 8 of a run's 9
    // to 13 episodes tripped the stop (eight runs), and one run in the full suite none (robots
    // over TCP take turns as they come, so runs differ).
    let tuned: SacConfig = ur5e::robot().defaults.of("sac").config().unwrap();
    let config =
        SacConfig { off_policy: OffPolicyConfig { learning_starts: 800, ..tuned.off_policy.clone() }, ..tuned };
    assert!(config.her_goals > 0);
    let model = Sac::new(config, spec.observation_space.clone(), spec.action_space.clone(), 0)
        .unwrap()
        .with_goal(spec.goal)
        .unwrap();
    let settings = ServerSettings::new("ur5e", &spec, 2, 1600);
    let server = RobotServer::start(
        "127.0.0.1:0".parse().unwrap(),
        Box::new(model),
        settings,
        Box::new(|_: &_, _: &dyn Agent| Ok(Flow::Continue)),
    )
    .unwrap();
    let mut app = ur5e::headless_app_with(2, 4, DesignPattern::Server);
    app.insert_resource(ServerAddress { addr: server.addr, patience: std::time::Duration::from_secs(10) });
    app.finish();
    app.cleanup();
    crate::server::run_robots_until_done(&mut app, 5_000);
    let (model, _) = server.wait().unwrap();
    let dir = crate::model::temp_dir("served-sac");
    model.save(&dir).unwrap();
    let sac = Sac::load(&dir).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let buffer = sac.buffer.as_ref().expect("the served model keeps its replay buffer");
    assert_eq!(
        (buffer.n_envs, buffer.len() as u64),
        (1, sac.state.timesteps),
        "one lane, every step learnt from stored"
    );
    assert!(
        sac.state.timesteps >= 1600 && sac.gradient_steps > 0,
        "{} steps, {} gradient steps",
        sac.state.timesteps,
        sac.gradient_steps
    );
    // Whole episodes: each ends where its `remaining` count reaches 0, one after another.
    let ends = buffer.remaining.iter().filter(|&&r| r == 0).count() as u64;
    assert_eq!(ends, sac.state.episodes, "an episode's steps are stored together");
    for i in 1..buffer.len() {
        let (before, now) = (buffer.remaining[i - 1], buffer.remaining[i]);
        assert!(before == 0 || before == now + 1, "step {i}: remaining {before} then {now}");
    }
    // Random exploration trips the protective stop (`ended_by` "protective_stop").
    let stops = buffer.ended_by.iter().filter(|&&code| code > 0).count();
    assert!(
        stops > 0 && buffer.terminations.iter().all(|t| spec.termination_terms.contains(t)),
        "{stops} {:?}",
        buffer.terminations
    );
}
