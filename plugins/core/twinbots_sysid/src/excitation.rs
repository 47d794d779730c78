//! Excitation programs: speed commands that sweep every commanded joint through varying speeds
//! and reversals within its speed and travel (Playground's operators, a UR's `speedj`).

use std::f64::consts::TAU;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use twinbots_sim::MotorCommand;

use crate::rig::{Program, Rig};

/// The lowest and highest frequency (Hz) an excitation holds.
const BAND: (f64, f64) = (0.1, 1.5);
/// Seconds over which a program fades in and out, so it starts and ends at rest.
const FADE: f64 = 1.0;

/// The shape of the speed signal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Excitation {
    /// A sum of sines at log-spaced frequencies with random phases (a new draw per channel).
    Multisine,
    /// A sine whose frequency sweeps the band (up on even channels, down on odd ones).
    Chirp,
}

impl Excitation {
    pub const NAMES: [&str; 2] = ["multisine", "chirp"];

    pub fn parse(name: &str) -> anyhow::Result<Self> {
        match name {
            "multisine" => Ok(Self::Multisine),
            "chirp" => Ok(Self::Chirp),
            _ => anyhow::bail!("unknown excitation '{name}' (known: {})", Self::NAMES.join(", ")),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Multisine => "multisine",
            Self::Chirp => "chirp",
        }
    }
}

/// One channel's speed signal, in units of its joint's speed limit, at time `t` of `seconds`.
struct Signal {
    /// (amplitude, frequency Hz, phase) of each sine (multisine).
    sines: Vec<(f64, f64, f64)>,
    /// A sweep up (true) or down (chirp).
    sweep: Option<bool>,
}

impl Signal {
    fn draw(kind: Excitation, channel: u8, rng: &mut ChaCha8Rng, speed: f64, travel: f64) -> Self {
        match kind {
            Excitation::Multisine => {
                let count = 6;
                let mut sines: Vec<(f64, f64, f64)> = (0..count)
                    .map(|k| {
                        let f = BAND.0 * (BAND.1 / BAND.0).powf(k as f64 / (count - 1) as f64);
                        // Amplitude ∝ frequency: every sine moves the joint equally far.
                        (f / BAND.1, f * rng.random_range(0.9..1.1), rng.random_range(0.0..TAU))
                    })
                    .collect();
                // Peak speed at most the limit; peak travel (2A/ω per sine) at most the range.
                let peak: f64 = sines.iter().map(|s| s.0).sum();
                let reach: f64 = sines.iter().map(|s| 2.0 * s.0 / (TAU * s.1)).sum::<f64>() * speed / peak;
                let scale = (1.0 / peak).min(travel / reach / peak);
                for s in &mut sines {
                    s.0 *= scale;
                }
                Self { sines, sweep: None }
            }
            Excitation::Chirp => Self { sines: Vec::new(), sweep: Some(channel.is_multiple_of(2)) },
        }
    }

    /// The speed (in units of the limit) at `t`, for a joint of `travel` at `speed` limit.
    fn at(&self, t: f64, seconds: f64, speed: f64, travel: f64) -> f64 {
        let v = match self.sweep {
            None => self.sines.iter().map(|(a, f, p)| a * (TAU * f * t + p).sin()).sum(),
            Some(up) => {
                // Log sweep: f(τ) = f0·r^(τ/S); its phase is the integral of f.
                let (f0, f1) = if up { BAND } else { (BAND.1, BAND.0) };
                let rate = (f1 / f0).ln() / seconds;
                let phase = TAU * f0 * ((rate * t).exp() - 1.0) / rate;
                let f = f0 * (rate * t).exp();
                // An amplitude whose excursion (A/ω) stays within the travel.
                let amplitude = (travel * TAU * f / speed).min(1.0);
                amplitude * phase.sin()
            }
        };
        let fade = (t / FADE).min((seconds - t) / FADE).clamp(0.0, 1.0);
        v * fade * fade * (3.0 - 2.0 * fade)
    }
}

/// The speed commands of `kind` for `seconds`, every `command_steps` physics steps, drawn from
/// `seed`.
pub fn program(rig: &Rig, kind: Excitation, seconds: f64, seed: u64) -> Program {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let excitation = &rig.description.excitation;
    let mut signals: Vec<(u8, Signal)> = Vec::new();
    for e in excitation {
        if !signals.iter().any(|(c, _)| *c == e.channel) {
            signals.push((e.channel, Signal::draw(kind, e.channel, &mut rng, e.speed as f64, e.travel as f64)));
        }
    }
    let dt = rig.dt();
    let steps = (seconds / dt).round() as usize;
    let every = rig.description.command_steps.max(1) as usize;
    let targets: Vec<usize> = excitation
        .iter()
        .map(|e| {
            rig.joints
                .iter()
                .position(|j| *j == e.joint)
                .unwrap_or_else(|| panic!("the rig excites '{}', not a joint of it", e.joint))
        })
        .collect();
    let changes = (0..steps)
        .map(|k| {
            if k % every != 0 {
                return Vec::new();
            }
            let t = k as f64 * dt;
            excitation
                .iter()
                .zip(&targets)
                .map(|(e, &j)| {
                    let signal = &signals.iter().find(|(c, _)| *c == e.channel).expect("a signal per channel").1;
                    let v = signal.at(t, seconds, e.speed as f64, e.travel as f64) * e.speed as f64;
                    (j, MotorCommand::Velocity(v as f32))
                })
                .collect()
        })
        .collect();
    Program { changes }
}
