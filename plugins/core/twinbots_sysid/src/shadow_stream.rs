//! The shadow as a robot's samples arrive (`monitor --replay`, a robot followed live): each
//! sample judged as soon as the samples its residual depends on are in, [`LOOKAHEAD`] samples
//! later, and exactly as [`Shadow::flags`] judges the whole recording — the same windows over the
//! same samples, so the same residuals, thresholds and flags, bit for bit.

use std::collections::VecDeque;

use twinbots_sim::urdf::dynamics::Dynamics;

use crate::effort_model::{EffortModel, Flag, Flags, Motion, RESIDUAL_WINDOW, Shadow, residuals};

/// Samples after a sample before it is judged: its residual averages [`RESIDUAL_WINDOW`]
/// samples around it, each of whose accelerations averages samples around that (11 ahead in
/// all); the recording's last [`RESIDUAL_WINDOW`] samples are never judged, as offline.
pub const LOOKAHEAD: usize = RESIDUAL_WINDOW;
/// Samples kept before the one judged: more than its windows reach back (11).
const BEHIND: usize = 2 * RESIDUAL_WINDOW;

/// One sample of a robot, in the chain's joint order.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// The robot's clock (s).
    pub time: f64,
    pub q: Vec<f64>,
    pub qd: Vec<f64>,
    pub effort: Vec<f64>,
}

/// A sample judged.
#[derive(Clone, Debug, PartialEq)]
pub struct Judged {
    /// Its index in the stream and its time from the stream's first sample (s).
    pub index: usize,
    pub time: f64,
    /// Measured less predicted effort per joint (averaged), and the threshold it is held to.
    pub residual: Vec<f64>,
    pub threshold: Vec<f64>,
    /// The flag this sample began, if it began one (a push, a collision).
    pub began: Option<Flag>,
}

/// The shadow over a stream of samples.
pub struct ShadowStream<'a> {
    dynamics: &'a Dynamics,
    model: &'a EffortModel,
    shadow: &'a Shadow,
    /// The latest samples; `first` is the stream index of the oldest.
    samples: VecDeque<Sample>,
    first: usize,
    t0: Option<f64>,
    flags: Flags,
}

impl<'a> ShadowStream<'a> {
    pub fn new(dynamics: &'a Dynamics, model: &'a EffortModel, shadow: &'a Shadow) -> Self {
        Self { dynamics, model, shadow, samples: VecDeque::new(), first: 0, t0: None, flags: Flags::default() }
    }

    /// Takes the next sample (the caller checks that time advances); returns the sample it
    /// made judgeable, once [`LOOKAHEAD`] samples have followed one past the start's.
    pub fn push(&mut self, sample: Sample) -> Option<Judged> {
        self.t0.get_or_insert(sample.time);
        self.samples.push_back(sample);
        let received = self.first + self.samples.len();
        if received < RESIDUAL_WINDOW + LOOKAHEAD + 1 {
            return None;
        }
        let k = received - LOOKAHEAD - 1;
        while self.first + BEHIND < k {
            self.samples.pop_front();
            self.first += 1;
        }
        let at = k - self.first;
        let motion = Motion::new(
            "stream",
            self.samples.iter().map(|s| s.time).collect(),
            self.samples.iter().map(|s| s.q.clone()).collect(),
            self.samples.iter().map(|s| s.qd.clone()).collect(),
            self.samples.iter().map(|s| s.effort.clone()).collect(),
        );
        let residual = residuals(&motion.effort, &self.model.efforts(self.dynamics, &motion)).swap_remove(at);
        let threshold = self.shadow.thresholds(&motion).swap_remove(at);
        let time = motion.time[at] - self.t0.unwrap_or(motion.time[at]);
        let began = self.flags.judge(time, &residual, &threshold).cloned();
        Some(Judged { index: k, time, residual, threshold, began })
    }

    /// The flags so far.
    pub fn flags(&self) -> &[Flag] {
        &self.flags.list
    }
}
