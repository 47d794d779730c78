//! The robot a deployment drives: a UR through RTDE and the shipped control program, or (for
//! `--dry-run`) the twin alone, started where the robot stands.

use std::time::{Duration, Instant};

use twinbots_rtde::server::InputState;
use twinbots_rtde::{InputRecipe, RtdeClient, Value};

use crate::ur_sim::program::{ACCELERATION, COUNTER, MODE, MODE_SPEEDJ, MODE_STOP, STATE, TARGET};
use crate::ur_sim::{UrSim, UrSimOptions};

/// One state report of the robot.
#[derive(Clone, Debug)]
pub struct Measured {
    /// The controller's clock (s).
    pub time: f64,
    pub q: [f64; 6],
    pub qd: [f64; 6],
    /// The joint motors' efforts (N·m).
    pub effort: [f64; 6],
    /// The control program's state (`output_int_register_24`).
    pub program: i32,
    /// When it arrived here.
    pub received: Instant,
}

/// A robot that reports its joints every controller cycle and takes joint speeds.
pub trait Arm {
    /// The next state report (waits for it).
    fn read(&mut self) -> anyhow::Result<Measured>;
    /// Joint speeds (rad/s, speedj), with a fresh watchdog counter.
    fn command(&mut self, speeds: &[f64; 6]) -> anyhow::Result<()>;
    /// Mode 0: the program brakes the arm to rest.
    fn stop(&mut self) -> anyhow::Result<()>;
    /// What the robot is, for the report.
    fn describe(&self) -> String;
}

/// The outputs a deployment reads, at the controller's full rate.
const OUTPUTS: [&str; 5] = ["timestamp", "actual_q", "actual_qd", "target_moment", STATE];

/// A UR through RTDE.
pub struct RtdeArm {
    client: RtdeClient,
    inputs: InputRecipe,
    counter: i32,
}

impl RtdeArm {
    /// Connects, sets up the recipes (500 Hz outputs; the program's input registers) and starts.
    pub fn connect(address: &str, patience: Duration) -> anyhow::Result<Self> {
        let mut client = RtdeClient::connect(address, patience)?;
        let version = client.controller_version()?;
        anyhow::ensure!(
            version.major >= 5,
            "the controller at {address} runs software {version}: deploy needs an e-Series (5.x) for 500 Hz RTDE"
        );
        client.setup_outputs(&OUTPUTS, twinbots_rtde::MAX_FREQUENCY)?;
        let mut names = vec![MODE, COUNTER, ACCELERATION];
        names.extend(TARGET);
        let inputs = client.setup_inputs(&names)?;
        client.start()?;
        Ok(Self { client, inputs, counter: 0 })
    }

    fn send(&mut self, mode: i32, speeds: &[f64; 6]) -> anyhow::Result<()> {
        self.counter = self.counter.wrapping_add(1);
        let mut values = vec![Value::Int32(mode), Value::Int32(self.counter), Value::Double(0.0)];
        values.extend(speeds.iter().map(|&v| Value::Double(v)));
        Ok(self.client.send(&self.inputs, &values)?)
    }
}

impl Arm for RtdeArm {
    fn read(&mut self) -> anyhow::Result<Measured> {
        let p = self.client.receive()?;
        let received = Instant::now();
        // The recipe asked for each: a missing one reads as NaN, which the deployment refuses.
        let six = |name: &str| p.vector6(name).unwrap_or([f64::NAN; 6]);
        Ok(Measured {
            time: p.double("timestamp").unwrap_or(f64::NAN),
            q: six("actual_q"),
            qd: six("actual_qd"),
            effort: six("target_moment"),
            program: p.get(STATE).and_then(Value::as_i64).unwrap_or(-1) as i32,
            received,
        })
    }

    fn command(&mut self, speeds: &[f64; 6]) -> anyhow::Result<()> {
        self.send(MODE_SPEEDJ, speeds)
    }

    fn stop(&mut self) -> anyhow::Result<()> {
        self.send(MODE_STOP, &[0.0; 6])
    }

    fn describe(&self) -> String {
        format!("RTDE {}", self.client.address())
    }
}

/// The twin alone (`--dry-run`): the stand-in's program and physics in this process, a cycle
/// per read, started at the robot's measured joints.
pub struct TwinArm {
    sim: UrSim,
    inputs: InputState,
    counter: i32,
}

impl TwinArm {
    pub fn new(options: &UrSimOptions, start: Option<[f64; 6]>) -> anyhow::Result<Self> {
        let sim = UrSim::with_start(options, start)?;
        Ok(Self { sim, inputs: InputState::new(), counter: 0 })
    }

    fn set(&mut self, mode: i32, speeds: &[f64; 6]) {
        self.counter = self.counter.wrapping_add(1);
        self.inputs.set(MODE, Value::Int32(mode));
        self.inputs.set(COUNTER, Value::Int32(self.counter));
        for (name, v) in TARGET.iter().zip(speeds) {
            self.inputs.set(name, Value::Double(*v));
        }
    }
}

impl Arm for TwinArm {
    fn read(&mut self) -> anyhow::Result<Measured> {
        let (out, _) = self.sim.cycle(&self.inputs);
        let six = |name: &str| out.get(name).as_vector6().expect("the stand-in's output is a VECTOR6D");
        Ok(Measured {
            time: out.get("timestamp").as_f64().expect("the stand-in's timestamp is a DOUBLE"),
            q: six("actual_q"),
            qd: six("actual_qd"),
            effort: six("target_moment"),
            program: out.get(STATE).as_i64().unwrap_or(-1) as i32,
            received: Instant::now(),
        })
    }

    fn command(&mut self, speeds: &[f64; 6]) -> anyhow::Result<()> {
        self.set(MODE_SPEEDJ, speeds);
        Ok(())
    }

    fn stop(&mut self) -> anyhow::Result<()> {
        self.set(MODE_STOP, &[0.0; 6]);
        Ok(())
    }

    fn describe(&self) -> String {
        "the twin (dry run)".into()
    }
}
