//! `twinbots ur-sim`: a UR controller stand-in. The UR5e twin (on its test stand, optionally
//! with a truth file's hidden physics, sensor noise and command delay) runs the emulated control
//! program ([`program`]) every 2 ms, as an e-Series controller's 500 Hz loop, and serves RTDE:
//! every output variable the twin can compute from it, fixed documented values for the rest.

pub mod program;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bevy::math::{DVec3, Vec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use twinbots_rtde::server::{ControllerInfo, InputState, OutputState, RtdeServer};
use twinbots_rtde::{ControllerVersion, Value};
use twinbots_sim::urdf::chain::Chain;
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_sim::{MotorCommand, Parameters};
use twinbots_sysid::{Rig, SensorNoise, Stand};
use twinbots_task::RobotDescription;
use ur5e::kinematics::{self, HOME, JOINT_RANGES, JOINTS, MAX_JOINT_SPEED};

use self::program::{APPLIED, ControlProgram, Limits, Note, STATE};

/// The controller's cycle (s): an e-Series' 500 Hz.
pub const CYCLE: f64 = 0.002;

/// The software version the stand-in reports: PolyScope 5.11 (the payload and force-torque
/// variables exist from it on; clients such as ur_rtde ask for them by version).
pub const VERSION: ControllerVersion = ControllerVersion { major: 5, minor: 11, bugfix: 0, build: 0 };

/// The arm a stand-in serves: six joints in the controller's order, where they start, their
/// ranges and top speeds, and how the controller computes the tool's pose and the elbow's
/// position from them. The built-in UR5e (its DH table), or a robot file's six-joint arm (its
/// URDF chain: poses in the file's base link's frame).
#[derive(Clone)]
pub struct ServedArm {
    pub robot: RobotDescription,
    /// The joints in the controller's order (RTDE's `_0` … `_5`).
    pub joints: Vec<String>,
    pub home: [f64; 6],
    /// Per joint: the position range (rad, ±) and the fastest speed (rad/s).
    pub range: [f64; 6],
    pub speed: [f64; 6],
    /// The link a payload hangs on.
    pub flange: String,
    chain: Option<Chain>,
}

impl std::fmt::Debug for ServedArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServedArm")
            .field("robot", &self.robot.name)
            .field("joints", &self.joints)
            .finish_non_exhaustive()
    }
}

impl ServedArm {
    pub fn ur5e() -> Self {
        Self {
            robot: ur5e::robot(),
            joints: JOINTS.map(String::from).to_vec(),
            home: HOME.map(|v| v as f64),
            range: JOINT_RANGES.map(|r| r as f64),
            speed: [MAX_JOINT_SPEED as f64; 6],
            flange: FLANGE.into(),
            chain: None,
        }
    }

    /// A robot file's arm (`robot`, the file's description): six controlled joints, home from
    /// the file, ranges and speeds from its URDF's limits (a range the widest side of its stops);
    /// anything else is an error naming the file.
    pub fn of_file(file: &RobotFile, robot: RobotDescription) -> anyhow::Result<Self> {
        let at = file.path.display();
        anyhow::ensure!(
            file.joints.len() == 6 && file.chain.dof() == 6,
            "{at}: a UR controller serves six joints; the file controls {} ({} in its chain)",
            file.joints.len(),
            file.chain.dof()
        );
        let model = (robot.rig.as_ref().expect("a robot file's arm has a test stand").model)();
        let limits = |k: usize| {
            let joint = model.joint(&file.joints[k]).expect("the robot file's joints are the URDF's");
            let range = joint.limits.position.map_or(std::f64::consts::TAU, |[lo, hi]| lo.abs().max(hi.abs()) as f64);
            (range, joint.limits.velocity as f64)
        };
        Ok(Self {
            robot,
            joints: file.joints.clone(),
            home: std::array::from_fn(|k| file.home[k]),
            range: std::array::from_fn(|k| limits(k).0),
            speed: std::array::from_fn(|k| limits(k).1),
            flange: file.chain.tool.clone(),
            chain: Some(file.chain.clone()),
        })
    }

    /// The TCP pose as the controller reports it: position (m) and rotation vector (rad) in
    /// the base frame.
    pub fn tcp_pose(&self, q: &[f64; 6]) -> [f64; 6] {
        let Some(chain) = &self.chain else { return tcp_pose(q) };
        let frame = chain.forward(q);
        let mut rotation = frame.rotation;
        // The rotation vector of the shorter way round: angle in [0, π].
        if rotation.w < 0.0 {
            rotation = -rotation;
        }
        let (axis, angle) = rotation.to_axis_angle();
        let (t, r) = (frame.translation, axis * angle);
        [t.x, t.y, t.z, r.x, r.y, r.z]
    }

    /// The TCP's linear and angular speed (J(q)·q̇).
    pub fn tcp_speed(&self, q: &[f64; 6], qd: &[f64; 6]) -> [f64; 6] {
        // A column per joint: (vx, vy, vz, ωx, ωy, ωz).
        let j = match &self.chain {
            Some(chain) => chain.jacobian(q),
            None => kinematics::jacobian(&q.map(|v| v as f32)).to_vec(),
        };
        std::array::from_fn(|k| (0..6).map(|i| j[i][k] * qd[i]).sum())
    }

    /// The elbow's position: the origin of the frame the third joint (a UR's elbow) turns in.
    fn elbow(&self, q: &[f64; 6]) -> DVec3 {
        match &self.chain {
            Some(chain) => chain.joint_origins(q)[2],
            None => elbow(q),
        }
    }
}

/// How the stand-in is built.
#[derive(Clone)]
pub struct UrSimOptions {
    /// The arm it serves.
    pub arm: ServedArm,
    /// The robot's true parameters over the twin's nominal ones (a calibration file's).
    pub truth: Parameters,
    pub noise: SensorNoise,
    pub seed: u64,
    /// The longest the control program's counter may stand still while moving (s).
    pub watchdog: f64,
    /// A payload on the flange (kg), 5 cm out along the tool axis: a load the twin's model does
    /// not know (the monitor's test of a divergence).
    pub payload: Option<f32>,
}

impl Default for UrSimOptions {
    fn default() -> Self {
        Self {
            arm: ServedArm::ur5e(),
            truth: Parameters::default(),
            noise: SensorNoise { position: 0.0, velocity: 0.0, effort: 0.0 },
            seed: 0,
            watchdog: 0.1,
            payload: None,
        }
    }
}

/// The UR5e's flange, the link a payload hangs on.
pub const FLANGE: &str = "tool0";

/// `arm` on its test stand at the controller's 2 ms step, with `truth` over its nominal
/// parameters, its joints where encoders reading `q` say they are; and the encoders' biases.
/// What the stand-in runs as the robot and the monitor as the robot's twin.
pub fn controller_stand(arm: &ServedArm, truth: &Parameters, q: &[f64; 6]) -> anyhow::Result<(Stand, Vec<f64>)> {
    let mut rig = Rig::of(&arm.robot)?;
    // The program's vectors are in the controller's order, the stand's joints in its model's.
    anyhow::ensure!(
        rig.joints == arm.joints,
        "{}: the test stand's joints ({}) are not the controller's six in its order ({})",
        arm.robot.name,
        rig.joints.join(", "),
        arm.joints.join(", ")
    );
    anyhow::ensure!(q.iter().all(|v| v.is_finite()), "a start pose of {q:?} is not one");
    rig.settings.dt = CYCLE as f32;
    let params = rig.parameters(truth)?;
    let bias = rig.biases(&params);
    // The encoders read the joint plus its bias: the joint stands at the reading less it.
    let at: Vec<(String, f32)> =
        rig.joints.iter().zip(q).zip(&bias).map(|((n, v), b)| (n.clone(), (v - b) as f32)).collect();
    Ok((Stand::new(&rig, &at, std::slice::from_ref(&params)), bias))
}

/// The stand-in: the twin, the program, and the cycle count.
pub struct UrSim {
    stand: Stand,
    bias: Vec<f64>,
    noise: SensorNoise,
    rng: ChaCha8Rng,
    pub program: ControlProgram,
    cycles: u64,
    /// The joint positions the encoders last read (what the program works from next cycle).
    measured_q: [f64; 6],
    elbow: DVec3,
    slots: Slots,
    arm: ServedArm,
}

impl UrSim {
    pub fn new(options: &UrSimOptions) -> anyhow::Result<Self> {
        Self::with_start(options, None)
    }

    /// The stand-in with the arm at `start` (joint angles, rad; default: home).
    pub fn with_start(options: &UrSimOptions, start: Option<[f64; 6]>) -> anyhow::Result<Self> {
        anyhow::ensure!(
            options.watchdog > 0.0 && options.watchdog.is_finite(),
            "--watchdog must be positive, not {}",
            options.watchdog
        );
        let arm = &options.arm;
        let q = start.unwrap_or(arm.home);
        let (mut stand, bias) = controller_stand(arm, &options.truth, &q)?;
        if let Some(mass) = options.payload {
            anyhow::ensure!(mass.is_finite() && mass > 0.0, "a payload of {mass} kg is not one");
            stand.add_payload(0, &arm.flange, mass, Vec3::new(0.0, 0.0, 0.05))?;
        }
        let limits = Limits { range: arm.range, speed: arm.speed, watchdog: options.watchdog };
        Ok(Self {
            stand,
            bias,
            noise: options.noise,
            rng: ChaCha8Rng::seed_from_u64(options.seed),
            program: ControlProgram::new(limits, q),
            cycles: 0,
            measured_q: q,
            elbow: arm.elbow(&q),
            arm: arm.clone(),
            slots: Slots::new(),
        })
    }

    /// Seconds since the stand-in started.
    pub fn time(&self) -> f64 {
        self.cycles as f64 * CYCLE
    }

    /// One controller cycle: the program reads `inputs` (and the joints as last measured), the
    /// twin takes its command for 2 ms, and the outputs are what the controller measures after
    /// it (once per cycle, as a controller does). Returns them and anything the clients should
    /// be told.
    pub fn cycle(&mut self, inputs: &InputState) -> (OutputState, Option<Note>) {
        let note = self.program.cycle(inputs, &self.measured_q, CYCLE);
        for (j, v) in self.program.target_qd.iter().enumerate() {
            self.stand.command(0, j, MotorCommand::Velocity(*v as f32));
        }
        self.stand.step();
        self.cycles += 1;
        (self.outputs(inputs), note)
    }

    /// What the encoders read now: positions (with their bias and noise), speeds, efforts.
    fn measure(&mut self) -> ([f64; 6], [f64; 6], [f64; 6]) {
        let r = self.stand.reading(0);
        let mut noisy = |sigma: f64| {
            if sigma > 0.0 { Normal::new(0.0, sigma).expect("finite noise").sample(&mut self.rng) } else { 0.0 }
        };
        let q = std::array::from_fn(|j| r.position[j] as f64 + self.bias[j] + noisy(self.noise.position));
        let qd = std::array::from_fn(|j| r.velocity[j] as f64 + noisy(self.noise.velocity));
        let effort = std::array::from_fn(|j| r.effort[j] as f64 + noisy(self.noise.effort));
        (q, qd, effort)
    }

    fn outputs(&mut self, inputs: &InputState) -> OutputState {
        let (q, qd, effort) = self.measure();
        self.measured_q = q;
        let p = &self.program;
        let s = &self.slots;
        let mut out = OutputState::default();
        let v6 = Value::Vector6d;
        out.set(s.timestamp, Value::Double(self.time()));
        out.set(s.actual_q, v6(q));
        out.set(s.actual_qd, v6(qd));
        out.set(s.target_q, v6(p.target_q));
        out.set(s.target_qd, v6(p.target_qd));
        out.set(s.target_qdd, v6(p.target_qdd));
        out.set(s.target_moment, v6(effort));
        out.set(s.actual_tcp_pose, v6(self.arm.tcp_pose(&q)));
        out.set(s.actual_tcp_speed, v6(self.arm.tcp_speed(&q, &qd)));
        out.set(s.target_tcp_pose, v6(self.arm.tcp_pose(&p.target_q)));
        out.set(s.target_tcp_speed, v6(self.arm.tcp_speed(&p.target_q, &p.target_qd)));
        let elbow_now = self.arm.elbow(&q);
        out.set(s.elbow_position, Value::Vector3d(elbow_now.to_array()));
        out.set(s.elbow_velocity, Value::Vector3d(((elbow_now - self.elbow) / CYCLE).to_array()));
        self.elbow = elbow_now;
        let stopped = p.state == program::ProgramState::ProtectiveStop;
        // Robot mode RUNNING (7), joints RUNNING (253), safety NORMAL (1) or PROTECTIVE_STOP (3).
        out.set(s.robot_mode, Value::Int32(7));
        out.set(s.joint_mode, Value::Vector6Int32([253; 6]));
        out.set(s.safety_mode, Value::Int32(if stopped { 3 } else { 1 }));
        out.set(s.safety_status, Value::Int32(if stopped { 3 } else { 1 }));
        // Bits: power on, program running; safety: normal mode, or protective stopped (bit 2).
        out.set(s.robot_status_bits, Value::Uint32(0b11));
        out.set(s.safety_status_bits, Value::Uint32(if stopped { 0b100 } else { 0b1 }));
        out.set(s.runtime_state, Value::Uint32(2));
        out.set(s.speed_scaling, Value::Double(1.0));
        out.set(s.target_speed_fraction, Value::Double(1.0));
        // A 48 V supply; the arm's current is its mechanical power over it.
        let power: f64 = effort.iter().zip(&qd).map(|(e, v)| (e * v).abs()).sum();
        out.set(s.main_voltage, Value::Double(48.0));
        out.set(s.robot_voltage, Value::Double(48.0));
        out.set(s.robot_current, Value::Double(power / 48.0));
        out.set(s.joint_voltage, v6([48.0; 6]));
        out.set(s.joint_temperatures, v6([30.0; 6]));
        out.set(s.tool_temperature, Value::Double(30.0));
        out.set(s.program_state, Value::Int32(p.state as i32));
        out.set(s.applied, Value::Int32(p.counter()));
        // The input registers read back as the clients set them.
        for (i, value) in inputs.values.iter().enumerate() {
            if let Some(slot) = s.input_echo[i] {
                out.set(slot, *value);
            }
        }
        out
    }

    /// Serves `server` in real time until `stop` is set or `seconds` pass; prints a line of
    /// progress every `report` seconds. Returns the cycles that missed their slot: that started
    /// a whole cycle or more after their time (a later cycle catches up the controller's clock).
    pub fn serve(&mut self, server: &RtdeServer, seconds: Option<f64>, stop: &AtomicBool, report: f64) -> u64 {
        let mut pacer = crate::pacer::Pacer::new(Duration::from_secs_f64(CYCLE));
        let mut last_report = 0.0;
        while !stop.load(Ordering::SeqCst) && seconds.is_none_or(|s| self.time() < s) {
            let began = Instant::now();
            let inputs = server.inputs();
            let (mut out, note) = self.cycle(&inputs);
            out.set(self.slots.execution_time, Value::Double(began.elapsed().as_secs_f64() * 1e3));
            server.publish(Arc::new(out));
            if let Some(note) = note {
                println!("[{:8.3} s] {}", self.time(), note.text);
                server.broadcast(note.level, &note.text);
            }
            for event in server.take_events() {
                println!("[{:8.3} s] rtde {event}", self.time());
            }
            if self.time() - last_report >= report {
                last_report = self.time();
                println!(
                    "[{:8.3} s] {} client(s), program {:?}, {} missed cycle(s)",
                    self.time(),
                    server.clients(),
                    self.program.state,
                    pacer.missed
                );
            }
            pacer.wait();
        }
        pacer.missed
    }
}

/// The controller's identity for RTDE.
pub fn controller_info() -> ControllerInfo {
    ControllerInfo { version: VERSION, cycle_hz: 1.0 / CYCLE, source: "twinbots ur-sim".into() }
}

/// The UR5e's TCP pose as the controller reports it (its DH table, in single precision as the
/// tasks compute it): position (m) and rotation vector (rad) in the base frame.
fn tcp_pose(q: &[f64; 6]) -> [f64; 6] {
    let pose = kinematics::tcp(&q.map(|v| v as f32));
    let mut rotation = pose.rotation;
    // The rotation vector of the shorter way round: angle in [0, π].
    if rotation.w < 0.0 {
        rotation = -rotation;
    }
    let (axis, angle) = rotation.to_axis_angle();
    let r: Vec3 = axis * angle;
    let t = pose.translation;
    [t.x as f64, t.y as f64, t.z as f64, r.x as f64, r.y as f64, r.z as f64]
}

/// The elbow's position: the origin of the frame the elbow joint turns in.
fn elbow(q: &[f64; 6]) -> DVec3 {
    kinematics::frames(&q.map(|v| v as f32))[2].w_axis.truncate()
}

/// Where the stand-in's outputs sit in [`OutputState`].
struct Slots {
    timestamp: usize,
    actual_q: usize,
    actual_qd: usize,
    target_q: usize,
    target_qd: usize,
    target_qdd: usize,
    target_moment: usize,
    actual_tcp_pose: usize,
    actual_tcp_speed: usize,
    target_tcp_pose: usize,
    target_tcp_speed: usize,
    elbow_position: usize,
    elbow_velocity: usize,
    robot_mode: usize,
    joint_mode: usize,
    safety_mode: usize,
    safety_status: usize,
    robot_status_bits: usize,
    safety_status_bits: usize,
    runtime_state: usize,
    speed_scaling: usize,
    target_speed_fraction: usize,
    main_voltage: usize,
    robot_voltage: usize,
    robot_current: usize,
    joint_voltage: usize,
    joint_temperatures: usize,
    tool_temperature: usize,
    execution_time: usize,
    program_state: usize,
    applied: usize,
    /// Per input: its read-back output, if it has one (the registers).
    input_echo: Vec<Option<usize>>,
}

impl Slots {
    fn new() -> Self {
        let at = OutputState::slot;
        Self {
            timestamp: at("timestamp"),
            actual_q: at("actual_q"),
            actual_qd: at("actual_qd"),
            target_q: at("target_q"),
            target_qd: at("target_qd"),
            target_qdd: at("target_qdd"),
            target_moment: at("target_moment"),
            actual_tcp_pose: at("actual_TCP_pose"),
            actual_tcp_speed: at("actual_TCP_speed"),
            target_tcp_pose: at("target_TCP_pose"),
            target_tcp_speed: at("target_TCP_speed"),
            elbow_position: at("elbow_position"),
            elbow_velocity: at("elbow_velocity"),
            robot_mode: at("robot_mode"),
            joint_mode: at("joint_mode"),
            safety_mode: at("safety_mode"),
            safety_status: at("safety_status"),
            robot_status_bits: at("robot_status_bits"),
            safety_status_bits: at("safety_status_bits"),
            runtime_state: at("runtime_state"),
            speed_scaling: at("speed_scaling"),
            target_speed_fraction: at("target_speed_fraction"),
            main_voltage: at("actual_main_voltage"),
            robot_voltage: at("actual_robot_voltage"),
            robot_current: at("actual_robot_current"),
            joint_voltage: at("actual_joint_voltage"),
            joint_temperatures: at("joint_temperatures"),
            tool_temperature: at("tool_temperature"),
            execution_time: at("actual_execution_time"),
            program_state: at(STATE),
            applied: at(APPLIED),
            input_echo: twinbots_rtde::variables::inputs()
                .iter()
                .map(|v| twinbots_rtde::variables::output_index(&v.name))
                .collect(),
        }
    }
}
