//! The control program an operator loads on the UR controller (`assets/urscript/twinbots_control.script`),
//! emulated: it reads its command from RTDE input registers, moves the arm with `speedj` or
//! `servoj`, and stops the arm when the client's counter stops changing (the watchdog). The
//! registers are the upper range (24–47), which UR leaves to external RTDE clients; docs/rtde.md
//! has the table.

use twinbots_rtde::server::InputState;
use twinbots_rtde::{DataType, MessageLevel, Value};

/// `input_int_register_24`: what the client asks for.
pub const MODE: &str = "input_int_register_24";
/// `input_int_register_25`: a counter the client changes with every command (the watchdog's).
pub const COUNTER: &str = "input_int_register_25";
/// `input_double_register_24..29`: joint speeds (rad/s, speedj) or positions (rad, servoj).
pub const TARGET: [&str; 6] = [
    "input_double_register_24",
    "input_double_register_25",
    "input_double_register_26",
    "input_double_register_27",
    "input_double_register_28",
    "input_double_register_29",
];
/// `input_double_register_30`: speedj's acceleration (rad/s²); 0 or less: [`DEFAULT_ACCELERATION`].
pub const ACCELERATION: &str = "input_double_register_30";
/// `output_int_register_24`: the program's [`ProgramState`].
pub const STATE: &str = "output_int_register_24";
/// `output_int_register_25`: the counter of the last command applied.
pub const APPLIED: &str = "output_int_register_25";

/// Modes a client asks for (`input_int_register_24`).
pub const MODE_STOP: i32 = 0;
pub const MODE_SPEEDJ: i32 = 1;
pub const MODE_SERVOJ: i32 = 2;

/// speedj's acceleration when the client gives none (rad/s²): the twin's speed steps, as trained,
/// settle within a control step.
pub const DEFAULT_ACCELERATION: f64 = 40.0;
/// The most a client may ask for (rad/s²); stopj decelerates at this.
pub const MAX_ACCELERATION: f64 = 40.0;
/// servoj's gain (1/s): the speed towards the target per radian it is away.
pub const SERVO_GAIN: f64 = 20.0;

/// What the program is doing (`output_int_register_24`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProgramState {
    /// Holding still, waiting for a mode.
    Idle = 0,
    Speedj = 1,
    Servoj = 2,
    /// The counter stood still longer than the watchdog: braked to a stop; set mode 0 to go on.
    WatchdogStop = 3,
    /// A joint left its range: braked to a stop; set mode 0 to go on.
    ProtectiveStop = 4,
}

/// What the program tells the clients (an RTDE text message): a change of state (info), or a
/// stop and why (warning).
#[derive(Clone, Debug, PartialEq)]
pub struct Note {
    pub level: MessageLevel,
    pub text: String,
}

impl Note {
    fn warning(text: String) -> Self {
        Self { level: MessageLevel::Warning, text }
    }
}

/// The program's limits.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Per joint: the position range (rad, ±).
    pub range: [f64; 6],
    /// Per joint: the fastest speed (rad/s).
    pub speed: [f64; 6],
    /// The longest the counter may stand still while moving (s).
    pub watchdog: f64,
}

/// The program's state between cycles.
#[derive(Clone, Debug)]
pub struct ControlProgram {
    pub limits: Limits,
    pub state: ProgramState,
    counter: i32,
    counter_age: f64,
    /// What the program commands: positions (integrated), speeds, accelerations.
    pub target_q: [f64; 6],
    pub target_qd: [f64; 6],
    pub target_qdd: [f64; 6],
}

impl ControlProgram {
    pub fn new(limits: Limits, q: [f64; 6]) -> Self {
        Self {
            limits,
            state: ProgramState::Idle,
            counter: 0,
            counter_age: 0.0,
            target_q: q,
            target_qd: [0.0; 6],
            target_qdd: [0.0; 6],
        }
    }

    /// The counter of the last command applied.
    pub fn counter(&self) -> i32 {
        self.counter
    }

    /// One control cycle of `dt` seconds at measured joint positions `q`: updates the targets;
    /// returns what changed worth telling the clients.
    pub fn cycle(&mut self, inputs: &InputState, q: &[f64; 6], dt: f64) -> Option<Note> {
        let mode = int(inputs, MODE);
        let counter = int(inputs, COUNTER);
        if counter != self.counter {
            self.counter = counter;
            self.counter_age = 0.0;
        } else {
            self.counter_age += dt;
        }
        let before = self.state;
        let mut note = None;
        let stopped = matches!(self.state, ProgramState::WatchdogStop | ProgramState::ProtectiveStop);
        if stopped {
            if mode == MODE_STOP {
                self.state = ProgramState::Idle;
            }
        } else if let Some(joint) = (0..6).find(|&j| q[j].abs() > self.limits.range[j]) {
            self.state = ProgramState::ProtectiveStop;
            note = Some(Note::warning(format!(
                "protective stop: joint {} at {:.3} rad is past its range ±{:.3}",
                joint + 1,
                q[joint],
                self.limits.range[joint]
            )));
        } else if mode != MODE_STOP && self.counter_age > self.limits.watchdog {
            self.state = ProgramState::WatchdogStop;
            note = Some(Note::warning(format!(
                "watchdog: {COUNTER} unchanged for {:.3} s (limit {:.3} s): arm stopped; set mode 0 to go on",
                self.counter_age, self.limits.watchdog
            )));
        } else {
            self.state = match mode {
                MODE_SPEEDJ => ProgramState::Speedj,
                MODE_SERVOJ => ProgramState::Servoj,
                MODE_STOP => ProgramState::Idle,
                other => {
                    if self.state != ProgramState::Idle {
                        note = Some(Note::warning(format!("unknown mode {other} in {MODE}: stopping")));
                    }
                    ProgramState::Idle
                }
            };
        }
        let (wanted, acceleration) = match self.state {
            ProgramState::Speedj => {
                let a = double(inputs, ACCELERATION);
                let a = if a > 0.0 { a.min(MAX_ACCELERATION) } else { DEFAULT_ACCELERATION };
                (std::array::from_fn(|j| double(inputs, TARGET[j])), a)
            }
            ProgramState::Servoj => {
                (std::array::from_fn(|j| SERVO_GAIN * (double(inputs, TARGET[j]) - q[j])), MAX_ACCELERATION)
            }
            _ => ([0.0; 6], MAX_ACCELERATION),
        };
        for j in 0..6 {
            let goal =
                if wanted[j].is_finite() { wanted[j].clamp(-self.limits.speed[j], self.limits.speed[j]) } else { 0.0 };
            let change = (goal - self.target_qd[j]).clamp(-acceleration * dt, acceleration * dt);
            self.target_qd[j] += change;
            self.target_qdd[j] = change / dt;
        }
        let moving = self.target_qd.iter().any(|v| *v != 0.0);
        for j in 0..6 {
            self.target_q[j] = if moving { self.target_q[j] + self.target_qd[j] * dt } else { q[j] };
        }
        if note.is_none() && self.state != before {
            note = Some(Note { level: MessageLevel::Info, text: format!("program: {:?} -> {:?}", before, self.state) });
        }
        note
    }
}

fn int(inputs: &InputState, name: &str) -> i32 {
    match inputs.get(name) {
        Value::Int32(v) => v,
        other => unreachable!("{name} is INT32, not {:?}", other.data_type()),
    }
}

fn double(inputs: &InputState, name: &str) -> f64 {
    let v = inputs.get(name);
    debug_assert_eq!(v.data_type(), DataType::Double);
    v.as_f64().unwrap_or(0.0)
}
