//! The measurements of `twinbots bench`: physics steps per second and the schedule's cost per
//! step, the learner's update and the bridge, the RobotServer's round trip, off-screen capture
//! and camera sensors, RTDE latency against the UR stand-in, and what a live viewer costs
//! training ([`print_live`]). Each `print_*` prints a table
//! (docs/benchmarks.md keeps the figures); the command only picks one. Arenas step side by side
//! on the worker pool (see `twinbots_learn::threads`); `RAYON_NUM_THREADS=1` measures them on
//! one thread.

mod live;

use std::time::Instant;

use twinbots_api::{DesignPattern, VecEnv};
use twinbots_learn::classic::ClassicCartPole;
use twinbots_learn::{Flow, Ppo, PpoConfig};
use twinbots_sim::SimSettings;
use twinbots_task::{AppVecEnv, bridge, env};

use twinbots_run::registry;

pub use live::print_live;

pub fn print_rtde(bundle: Option<&std::path::Path>, seconds: f64, rt_priority: Option<i32>) -> anyhow::Result<()> {
    let dir = bundle
        .ok_or_else(|| anyhow::anyhow!("bench rtde needs --bundle DIR (`twinbots export <ur5e run> --bundle DIR`)"))?;
    anyhow::ensure!(seconds > 0.0 && seconds.is_finite(), "--seconds must be positive");
    let bundle = twinbots_ops::bundle::Bundle::read_for(dir, "ur5e")?;
    let scheduling =
        rt_priority.map_or("default scheduling".to_string(), |p| format!("SCHED_FIFO {p}, the stand-in {}", p - 1));
    println!(
        "bench rtde: a UR stand-in at 500 Hz on loopback, every report answered by {} ({seconds} s, {scheduling})",
        dir.display()
    );
    let show = |r: &twinbots_ops::deploy::latency::LatencyReport| {
        println!(
            "  {:6.1} s: {} commands, report in -> command out p50 {:.0} us, p99 {:.0} us, p99.9 {:.0} us, max {:.0} us; longest between commands {:.1} ms ({} of 20 ms or more); {} later than 2 ms, {} reports missed, stand-in missed {} cycles",
            r.seconds,
            r.commands,
            r.p50_us,
            r.p99_us,
            r.p999_us,
            r.max_us,
            r.longest_gap_ms,
            r.stopping_gaps,
            r.late_commands,
            r.missed_reports,
            r.standin_missed_cycles
        )
    };
    let report = twinbots_ops::deploy::latency::measure(&bundle, seconds, rt_priority, show)?;
    show(&report);
    // What a robot needs: never 20 ms without a command (a UR stops the arm then).
    anyhow::ensure!(
        report.stopping_gaps == 0,
        "{} gap(s) of 20 ms or more between commands (longest {:.1} ms): a UR would have stopped the arm",
        report.stopping_gaps,
        report.longest_gap_ms
    );
    Ok(())
}

pub struct PhysicsBench {
    pub arenas: usize,
    /// Vectorised steps per second (each advances every arena by one control step).
    pub vec_steps_per_s: f64,
    /// Arena control steps per second: `arenas * vec_steps_per_s`.
    pub arena_steps_per_s: f64,
    /// Microseconds per vectorised step spent in physics (the total less `overhead_us`).
    pub physics_us: f64,
    /// Microseconds per vectorised step spent around the physics (schedule, motors, sensors, task).
    pub overhead_us: f64,
}

/// Steps `robot` with `arenas` arenas for `steps` control steps (alternating actions).
pub fn physics(robot: &str, arenas: usize, steps: usize) -> anyhow::Result<PhysicsBench> {
    let entry = registry::find(robot)?;
    let mut env = AppVecEnv::new(entry.app(None, arenas, 0, DesignPattern::Supervised)?);
    env.reset(Some(0))?;
    let dim = env.action_space().dim();
    let actions: Vec<Vec<f32>> = (0..2).map(|k| vec![k as f32; arenas * dim]).collect();
    // Warm up (allocations, contact graphs), then time the whole control step.
    for i in 0..20 {
        env.step(&actions[(i / 4) % 2])?;
    }
    let start = Instant::now();
    for i in 0..steps {
        env.step(&actions[(i / 4) % 2])?;
    }
    let full = start.elapsed().as_secs_f64();

    // The same control steps with zero physics substeps: what the schedule, motors, sensors,
    // task terms and resets cost around rapier.
    env.app_mut().world_mut().resource_mut::<SimSettings>().substeps = 0;
    let start = Instant::now();
    for i in 0..steps {
        env.step(&actions[(i / 4) % 2])?;
    }
    let around = start.elapsed().as_secs_f64();
    let per = |t: f64| t / steps as f64 * 1e6;
    Ok(PhysicsBench {
        arenas,
        vec_steps_per_s: steps as f64 / full,
        arena_steps_per_s: (steps * arenas) as f64 / full,
        physics_us: per((full - around).max(0.0)),
        overhead_us: per(around),
    })
}

pub fn print_physics(robot: &str, arena_counts: &[usize], steps: usize) -> anyhow::Result<()> {
    registry::find(robot)?;
    let threads = twinbots_learn::threads::configure();
    println!(
        "physics benchmark: {robot}, {steps} control steps per row (one process; arenas step on {threads} threads)"
    );
    println!(
        "{:>7} {:>14} {:>18} {:>16} {:>18}",
        "arenas", "vec steps/s", "arena steps/s", "rapier µs/step", "schedule µs/step"
    );
    for &n in arena_counts {
        let b = physics(robot, n, steps)?;
        println!(
            "{:>7} {:>14.0} {:>18.0} {:>16.1} {:>18.1}",
            b.arenas, b.vec_steps_per_s, b.arena_steps_per_s, b.physics_us, b.overhead_us
        );
    }
    Ok(())
}

/// Seconds of one `learn` call of `steps` steps with `config` on CartPole-v1 (1 env).
fn time_learn(config: PpoConfig, steps: u64) -> anyhow::Result<f64> {
    let mut env = ClassicCartPole::new(1);
    let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 0)?;
    let start = Instant::now();
    model.learn(&mut env, steps, &mut |_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue))?;
    Ok(start.elapsed().as_secs_f64())
}

/// Steps/s of `robot` with `arenas` arenas stepped directly, then through the channel bridge
/// from another thread.
fn direct_vs_bridge(robot: &str, arenas: usize, steps: usize) -> anyhow::Result<(f64, f64)> {
    let entry = registry::find(robot)?;
    let actions = move |env: &dyn VecEnv, i: usize| vec![((i / 4) % 2) as f32; arenas * env.action_space().dim()];
    let mut direct = AppVecEnv::new(entry.app(None, arenas, 0, DesignPattern::Supervised)?);
    direct.reset(Some(0))?;
    let start = Instant::now();
    for i in 0..steps {
        let a = actions(&direct, i);
        direct.step(&a)?;
    }
    let direct_rate = (steps * arenas) as f64 / start.elapsed().as_secs_f64();

    let mut app = entry.app(None, arenas, 0, DesignPattern::Supervised)?;
    app.add_plugins(bridge::BridgePlugin);
    env::start(&mut app)?;
    let mut channel = bridge::connect(app.world_mut())?;
    let trainer = std::thread::spawn(move || -> anyhow::Result<f64> {
        channel.reset(Some(0))?;
        let start = Instant::now();
        for i in 0..steps {
            let a = actions(&channel, i);
            channel.step(&a)?;
        }
        Ok((steps * arenas) as f64 / start.elapsed().as_secs_f64())
    });
    bridge::run_until_closed(&mut app);
    let bridged_rate = trainer.join().map_err(|_| anyhow::anyhow!("bench trainer panicked"))??;
    Ok((direct_rate, bridged_rate))
}

pub fn print_rl(robot: &str, arenas: usize, steps: usize) -> anyhow::Result<()> {
    registry::find(robot)?;
    // SB3's defaults: 2048 samples, 10 epochs of minibatches of 64. The same rollout with one
    // epoch tells an epoch's cost (a config needs one epoch at least), and so the rollout's.
    let full = time_learn(PpoConfig::default(), 2048)?;
    let one_epoch = time_learn(PpoConfig { n_epochs: 1, ..Default::default() }, 2048)?;
    let epoch = ((full - one_epoch) / 9.0).max(0.0);
    let rollout = one_epoch - epoch;
    println!("PPO update of 2048 samples (10 epochs × 32 minibatches of 64, MLP 64-64): {:.0} ms", 10.0 * epoch * 1e3);
    println!("PPO rollout of 2048 CartPole-v1 steps with policy inference: {:.0} ms", rollout * 1e3);
    let (direct, bridged) = direct_vs_bridge(robot, arenas, steps)?;
    println!(
        "{robot}, {arenas} arenas: {direct:.0} arena-steps/s stepped directly, {bridged:.0} through the channel bridge ({:.1}% overhead)",
        (direct / bridged - 1.0) * 100.0
    );
    Ok(())
}

/// Steps/s one RobotServer sustains with `robots` concurrent robot connections (each a thread
/// doing `steps` request–reply steps as fast as it can), and the mean round trip.
fn server_throughput(robots: usize, steps: usize) -> anyhow::Result<(f64, f64)> {
    use twinbots_link::client::Communicator;
    use twinbots_link::protocol::{RobotMessage, ServerMessage};
    use twinbots_server::server::{RobotServer, ServerSettings};
    let spec = cartpole::task_spec();
    let id = twinbots_link::client::Identity {
        robot: "cartpole".into(),
        observation_space: spec.observation_space.clone(),
        action_space: spec.action_space.clone(),
        token: None,
    };
    let model = Ppo::new(PpoConfig::zoo_cartpole(), id.observation_space.clone(), id.action_space.clone(), 0)?;
    // A rollout never filled: this measures the protocol and the policy's inference only.
    let mut settings = ServerSettings::new("cartpole", &spec, usize::MAX, u64::MAX);
    settings.limits.max_robots = robots.max(1);
    let server = RobotServer::start(
        "127.0.0.1:0".parse()?,
        Box::new(model),
        settings,
        Box::new(|_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)),
    )?;
    let addr = server.addr;
    let start = Instant::now();
    let threads: Vec<_> = (0..robots)
        .map(|_| {
            let id = id.clone();
            std::thread::spawn(move || -> anyhow::Result<f64> {
                let mut c = Communicator::new(addr, id, std::time::Duration::from_secs(5));
                c.connect()?;
                c.send(&RobotMessage::Start { obs: vec![0.0; 4] })?;
                c.receive()?;
                let t = Instant::now();
                for _ in 0..steps {
                    c.send(&RobotMessage::Step {
                        obs: vec![0.0; 4],
                        reward: 1.0,
                        terminated: false,
                        truncated: false,
                        success: None,
                        ended_by: None,
                    })?;
                    anyhow::ensure!(matches!(c.receive()?, ServerMessage::Action { .. }), "unexpected reply");
                }
                Ok(t.elapsed().as_secs_f64() / steps as f64)
            })
        })
        .collect();
    let mut round_trips = Vec::new();
    for t in threads {
        round_trips.push(t.join().map_err(|_| anyhow::anyhow!("robot thread panicked"))??);
    }
    let total = start.elapsed().as_secs_f64();
    Ok(((robots * steps) as f64 / total, round_trips.iter().sum::<f64>() / robots as f64 * 1e6))
}

pub fn print_server(robot_counts: &[usize], steps: usize) -> anyhow::Result<()> {
    println!("RobotServer over loopback TCP (protocol + policy inference, no updates), {steps} steps per robot");
    println!("{:>7} {:>16} {:>20}", "robots", "steps/s (all)", "round trip µs/step");
    for &n in robot_counts {
        let (rate, rtt) = server_throughput(n, steps)?;
        println!("{n:>7} {rate:>16.0} {rtt:>20.1}");
    }
    Ok(())
}

/// Frames/s of off-screen capture of `robot` at each size: sync + render + readback + PNG
/// encoding, one physics step per frame (the step's own cost is excluded).
pub fn print_capture(robot: &str, sizes: &[(u32, u32)], frames: usize) -> anyhow::Result<()> {
    let entry = registry::find(robot)?;
    println!("off-screen capture of {robot}, {frames} frames per size (renderer: whatever adapter wgpu picks)");
    println!("{:>10} {:>12} {:>16}", "size", "frames/s", "ms/frame");
    for &(w, h) in sizes {
        let mut env = AppVecEnv::new(entry.app(None, 1, 0, DesignPattern::Supervised)?);
        env.reset(Some(0))?;
        let dir = std::env::temp_dir().join(format!("twinbots-bench-capture-{}", std::process::id()));
        let mut recorder = twinbots_render::recorder::Recorder::new(
            (w, h),
            twinbots_render::recorder::camera(&entry.framing, "side")?,
            &dir,
        )?;
        recorder.frame(&mut env, 0)?; // warm-up: pipelines compile
        let mut spent = 0.0;
        for i in 1..=frames {
            env.step(&vec![(i % 2) as f32; env.action_space().dim()])?;
            let t = Instant::now();
            recorder.frame(&mut env, i as u64)?;
            spent += t.elapsed().as_secs_f64();
        }
        let _ = std::fs::remove_dir_all(&dir);
        println!("{:>10} {:>12.1} {:>16.1}", format!("{w}x{h}"), frames as f64 / spent, spent / frames as f64 * 1e3);
    }
    Ok(())
}

/// Camera-sensor frames/s of `robot` with `arenas` arenas, each with a 64×64 camera on its
/// robot's root link looking at the cell from the iso view, over `steps` control steps:
/// aggregate frames/s of `CameraRig::sample` (the physics step excluded) drawing one camera a
/// frame, all in one frame, and all in one frame with `[randomization.visual]` (a new look per
/// arena every 10 steps). The three live side by side and take turns in blocks of
/// [`CAMERA_BLOCK`] steps, the order rotating each round: this VM's speed drifts by ±15 % within
/// a minute, and one setup measured after another compared the drift, not the setups.
pub fn print_cameras(robot: &str, arenas: usize, steps: usize) -> anyhow::Result<()> {
    let entry = registry::find(robot)?;
    println!(
        "camera sensors of {robot}: {arenas} arenas x 64x64, {steps} control steps each, in turns of {CAMERA_BLOCK} (renderer: whatever adapter wgpu picks)"
    );
    println!("{:>26} {:>12} {:>16}", "looks, frames", "frames/s", "ms/step");
    let mut setups = [(false, 1), (false, 0), (true, 0)]
        .into_iter()
        .map(|(randomized, max_tiles)| CameraSetup::new(&entry, arenas, randomized, max_tiles))
        .collect::<anyhow::Result<Vec<_>>>()?;
    for round in 0..steps.div_ceil(CAMERA_BLOCK) {
        for k in 0..setups.len() {
            let n = setups.len();
            let setup = &mut setups[(round + k) % n];
            for _ in 0..CAMERA_BLOCK.min(steps - round * CAMERA_BLOCK) {
                setup.step()?;
            }
        }
    }
    for setup in &setups {
        let label = match (setup.randomized, setup.rig.max_tiles) {
            (true, _) => "randomized, one frame",
            (false, 1) => "plain, one camera a frame",
            _ => "plain, one frame",
        };
        println!(
            "{label:>26} {:>12.0} {:>16.2}",
            (setup.steps * arenas) as f64 / setup.spent,
            setup.spent / setup.steps as f64 * 1e3
        );
    }
    Ok(())
}

/// Control steps each setup of `bench cameras` takes in a turn.
const CAMERA_BLOCK: usize = 5;

/// One setup of `bench cameras`: its arenas, their cameras and the time spent drawing them.
struct CameraSetup {
    env: AppVecEnv,
    /// Every arena's action: none.
    zero: Vec<f32>,
    rig: twinbots_render::CameraRig,
    randomized: bool,
    steps: usize,
    spent: f64,
}

impl CameraSetup {
    fn new(entry: &registry::RobotEntry, arenas: usize, randomized: bool, max_tiles: usize) -> anyhow::Result<Self> {
        use twinbots_task::randomization::{Randomization, RandomizationPlugin, visual::VisualRandomization};
        let mut app = entry.app(None, arenas, 0, DesignPattern::Supervised)?;
        if randomized {
            app.add_plugins(RandomizationPlugin(Randomization {
                visual: Some(VisualRandomization::default()),
                ..Default::default()
            }));
        }
        let mut env = AppVecEnv::new(app);
        env.reset(Some(0))?;
        mount_cameras(env.app_mut().world_mut(), &entry.framing, (64, 64));
        let mut rig = twinbots_render::CameraRig::default();
        rig.max_tiles = max_tiles;
        rig.sample(env.app_mut().world_mut())?; // warm-up: pipelines compile
        let zero = vec![0.0; env.action_space().dim() * arenas];
        Ok(Self { env, zero, rig, randomized, steps: 0, spent: 0.0 })
    }

    /// One control step (a reset every 10th with new looks), then its frames, timed.
    fn step(&mut self) -> anyhow::Result<()> {
        self.steps += 1;
        if self.randomized && self.steps.is_multiple_of(10) {
            self.env.reset(None)?;
        } else {
            self.env.step(&self.zero)?;
        }
        let t = Instant::now();
        let frames = self.rig.sample(self.env.app_mut().world_mut())?;
        self.spent += t.elapsed().as_secs_f64();
        let arenas = self.env.arenas().len();
        anyhow::ensure!(frames == arenas, "{frames} cameras rendered, {arenas} expected");
        Ok(())
    }
}

/// A camera sensor per arena on its first link (in entity order), placed at the framing's iso
/// eye looking at its target.
fn mount_cameras(world: &mut bevy::prelude::World, framing: &twinbots_sim::Framing, (width, height): (u32, u32)) {
    use bevy::prelude::*;
    use twinbots_sim::rapier::math::Pose;
    use twinbots_sim::{CameraSensor, InArena, Link, Mount};
    let eye = framing.eye("iso").expect("the iso view");
    let forward = (framing.target - eye).normalize();
    let left = Vec3::Z.cross(forward).normalize();
    let camera = Pose::from_parts(eye, Quat::from_mat3(&Mat3::from_cols(forward, left, forward.cross(left))));
    let mut links = world.query::<(Entity, &Link, &InArena)>();
    let mut first: std::collections::BTreeMap<Entity, (Entity, Link)> = Default::default();
    for (e, link, arena) in links.iter(world) {
        let entry = first.entry(arena.0).or_insert((e, link.clone()));
        if e < entry.0 {
            *entry = (e, link.clone());
        }
    }
    for (arena, (entity, link)) in first {
        let Some(body) = twinbots_sim::physics_in(world, arena)
            .and_then(|w| w.bodies.get(link.body).map(|b| *b.position() * link.offset))
        else {
            continue;
        };
        let offset = body.inverse() * camera;
        world.spawn((
            CameraSensor::new(45f32.to_radians(), width, height),
            Mount { link: entity, offset },
            InArena(arena),
        ));
    }
}
