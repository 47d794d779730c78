//! A task's terms, in the manner of Isaac Lab's managers: named observation, reward and
//! termination terms and start events over the state `S` a robot's controller knows at a step.
//!
//! Terms are pure functions of that state, written once per task. Where the state comes from
//! is the design pattern's business (the Supervisor, a radio link, or the robot's own devices);
//! what the task makes of it is the same under every pattern.

use rand_chacha::ChaCha8Rng;

use twinbots_api::Space;

/// One named block of the observation vector.
pub struct ObservationTerm<S> {
    pub name: &'static str,
    pub size: usize,
    /// Bounds of every value of the block (unbounded by default).
    pub low: f32,
    pub high: f32,
    /// Where a working sensor's values of the block lie (`None`: within the bounds).
    pub plausible: Option<(f32, f32)>,
    read: Box<dyn Fn(&S, &mut Vec<f32>) + Send + Sync>,
}

impl<S> ObservationTerm<S> {
    /// A block of `size` values that `read` appends to the observation.
    pub fn new(name: &'static str, size: usize, read: impl Fn(&S, &mut Vec<f32>) + Send + Sync + 'static) -> Self {
        Self { name, size, low: f32::NEG_INFINITY, high: f32::INFINITY, plausible: None, read: Box::new(read) }
    }

    /// A single value.
    pub fn scalar(name: &'static str, value: impl Fn(&S) -> f32 + Send + Sync + 'static) -> Self {
        Self::new(name, 1, move |s, out| out.push(value(s)))
    }

    /// Declares the block's bounds (they go into the observation space).
    pub fn bounded(mut self, low: f32, high: f32) -> Self {
        (self.low, self.high) = (low, high);
        self
    }

    /// Declares where a working sensor's values lie, for an unbounded block: well beyond
    /// anything the robot does (a value outside is a fault, not a motion), in the block's units.
    pub fn plausible(mut self, low: f32, high: f32) -> Self {
        self.plausible = Some((low, high));
        self
    }
}

/// One weighted part of the reward: the step's reward is Σ weight · value.
pub struct RewardTerm<S> {
    pub name: &'static str,
    pub weight: f32,
    /// Range of the value (unbounded by default); a bounded value is clamped into it, so the
    /// task's reward range ([`TaskTerms::reward_range`]) holds by construction.
    pub low: f32,
    pub high: f32,
    value: Box<dyn Fn(&S) -> f32 + Send + Sync>,
}

impl<S> RewardTerm<S> {
    pub fn new(name: &'static str, weight: f32, value: impl Fn(&S) -> f32 + Send + Sync + 'static) -> Self {
        Self { name, weight, low: f32::NEG_INFINITY, high: f32::INFINITY, value: Box::new(value) }
    }

    /// Declares the value's range; values outside it are clamped. A RobotServer refuses
    /// rewards outside the task's range, so one robot cannot claim more than the task pays.
    pub fn bounded(mut self, low: f32, high: f32) -> Self {
        (self.low, self.high) = (low, high);
        self
    }

    /// weight × value, the value clamped into its range: the term's share of a step's reward.
    pub fn weighted(&self, s: &S) -> f32 {
        self.weight * (self.value)(s).clamp(self.low, self.high)
    }
}

/// A condition that ends the episode (Gymnasium's `terminated`). A goal term also marks the
/// episode a success (`is_success`); any other term ends it without.
pub struct TerminationTerm<S> {
    pub name: &'static str,
    pub goal: bool,
    when: Box<dyn Fn(&S) -> bool + Send + Sync>,
}

impl<S> TerminationTerm<S> {
    pub fn new(name: &'static str, when: impl Fn(&S) -> bool + Send + Sync + 'static) -> Self {
        Self { name, goal: false, when: Box::new(when) }
    }

    pub fn goal(name: &'static str, when: impl Fn(&S) -> bool + Send + Sync + 'static) -> Self {
        Self { name, goal: true, when: Box::new(when) }
    }
}

/// A draw made when an episode starts (Isaac Lab's reset event, the part that is the task's):
/// a new command (a reach target) or a random start state the pattern then puts in place (the
/// Supervisor teleports, or the robot homes and an operator places). Draws come from the
/// episode's random stream, in the order the events are listed.
pub struct StartEvent<S> {
    pub name: &'static str,
    draw: Box<dyn Fn(&mut S, &mut ChaCha8Rng) + Send + Sync>,
}

impl<S> StartEvent<S> {
    pub fn new(name: &'static str, draw: impl Fn(&mut S, &mut ChaCha8Rng) + Send + Sync + 'static) -> Self {
        Self { name, draw: Box::new(draw) }
    }
}

/// Everything a task says about its episodes.
pub struct TaskTerms<S> {
    pub observations: Vec<ObservationTerm<S>>,
    pub rewards: Vec<RewardTerm<S>>,
    pub terminations: Vec<TerminationTerm<S>>,
    /// Episodes are truncated once they have lasted this many steps (Gymnasium's TimeLimit).
    pub time_limit: Option<u32>,
    pub start_events: Vec<StartEvent<S>>,
}

impl<S> Default for TaskTerms<S> {
    fn default() -> Self {
        Self {
            observations: Vec::new(),
            rewards: Vec::new(),
            terminations: Vec::new(),
            time_limit: None,
            start_events: Vec::new(),
        }
    }
}

/// weight · bound, where a zero weight makes even an infinite bound nothing (not NaN).
fn weighted_bound(weight: f32, bound: f32) -> f32 {
    if weight == 0.0 { 0.0 } else { weight * bound }
}

/// What the terms make of one step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepOutcome {
    pub reward: f32,
    pub terminated: bool,
    pub truncated: bool,
    /// Set on an episode's last step for tasks with a goal term: whether one fired.
    pub success: Option<bool>,
    /// The first termination term (in the task's order) that fired, if any.
    pub ended_by: Option<&'static str>,
}

impl<S> TaskTerms<S> {
    /// Length of the observation vector: the sum of the terms' sizes.
    pub fn observation_dim(&self) -> usize {
        self.observations.iter().map(|t| t.size).sum()
    }

    /// The observation space, with each term's bounds.
    pub fn observation_space(&self) -> Space {
        let (mut low, mut high) = (Vec::new(), Vec::new());
        for t in &self.observations {
            low.extend(std::iter::repeat_n(t.low, t.size));
            high.extend(std::iter::repeat_n(t.high, t.size));
        }
        Space::Box { low, high }
    }

    /// Where a working sensor's observation values lie: each term's plausible range, else its
    /// bounds.
    pub fn observation_plausible(&self) -> Space {
        let (mut low, mut high) = (Vec::new(), Vec::new());
        for t in &self.observations {
            let (lo, hi) = t.plausible.unwrap_or((t.low, t.high));
            low.extend(std::iter::repeat_n(lo, t.size));
            high.extend(std::iter::repeat_n(hi, t.size));
        }
        Space::Box { low, high }
    }

    /// The name of every observation value in order: a term's name, indexed where it has
    /// several (`q[0]`, `q[1]`, …).
    pub fn observation_names(&self) -> Vec<String> {
        self.observations
            .iter()
            .flat_map(|t| {
                (0..t.size).map(move |i| if t.size == 1 { t.name.to_string() } else { format!("{}[{i}]", t.name) })
            })
            .collect()
    }

    /// Where the observation term `name` starts in the flat observation, if the task has it.
    pub fn observation_offset(&self, name: &str) -> Option<usize> {
        let mut at = 0;
        for t in &self.observations {
            if t.name == name {
                return Some(at);
            }
            at += t.size;
        }
        None
    }

    pub fn reward_names(&self) -> Vec<&'static str> {
        self.rewards.iter().map(|t| t.name).collect()
    }

    /// The termination terms' names, in order (the time limit truncates: it is none of them).
    pub fn termination_names(&self) -> Vec<String> {
        self.terminations.iter().map(|t| t.name.to_string()).collect()
    }

    /// The lowest and highest reward one step can give: Σ weight · [low, high] over the terms
    /// (infinite where a term is unbounded on the side its weight selects).
    pub fn reward_range(&self) -> (f32, f32) {
        self.rewards.iter().fold((0.0, 0.0), |(lo, hi), t| {
            let (a, b) = (weighted_bound(t.weight, t.low), weighted_bound(t.weight, t.high));
            (lo + a.min(b), hi + a.max(b))
        })
    }

    /// Writes the observation of state `s` into `out` (cleared first).
    pub fn observe(&self, s: &S, out: &mut Vec<f32>) {
        out.clear();
        for term in &self.observations {
            (term.read)(s, out);
        }
        debug_assert_eq!(out.len(), self.observation_dim(), "an observation term wrote other than its size");
    }

    /// Reward, termination and truncation of a step into state `s`, the episode having lasted
    /// `steps_before` steps before it. Each reward term's weighted value is added to
    /// `reward_sums` (one per term, for the episode's log).
    pub fn evaluate(&self, s: &S, steps_before: u32, reward_sums: &mut Vec<f32>) -> StepOutcome {
        reward_sums.resize(self.rewards.len(), 0.0);
        let mut reward = 0.0;
        for (term, sum) in self.rewards.iter().zip(reward_sums.iter_mut()) {
            let r = term.weighted(s);
            *sum += r;
            reward += r;
        }
        let mut terminated = false;
        let mut goal = false;
        let mut ended_by = None;
        for term in &self.terminations {
            if (term.when)(s) {
                terminated = true;
                goal |= term.goal;
                ended_by = ended_by.or(Some(term.name));
            }
        }
        let truncated = !terminated && self.time_limit.is_some_and(|n| steps_before + 1 >= n);
        let has_goal = self.terminations.iter().any(|t| t.goal);
        let success = (has_goal && (terminated || truncated)).then_some(goal);
        StepOutcome { reward, terminated, truncated, success, ended_by }
    }

    /// Runs the start events on `s`, drawing from `rng`.
    pub fn start(&self, s: &mut S, rng: &mut ChaCha8Rng) {
        for event in &self.start_events {
            (event.draw)(s, rng);
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;

    #[derive(Default)]
    struct Cart {
        x: f32,
        angle: f32,
        tilt: f32,
    }

    fn terms() -> TaskTerms<Cart> {
        TaskTerms {
            observations: vec![
                ObservationTerm::scalar("x", |s: &Cart| s.x).plausible(-5.0, 5.0),
                ObservationTerm::new("angle_twice", 2, |s: &Cart, out: &mut Vec<f32>| out.extend([s.angle, s.angle]))
                    .bounded(-1.0, 1.0),
            ],
            rewards: vec![
                RewardTerm::new("alive", 1.0, |_| 1.0),
                RewardTerm::new("angle", -2.0, |s: &Cart| s.angle.abs()),
            ],
            terminations: vec![
                TerminationTerm::new("fallen", |s: &Cart| s.angle.abs() > 0.5),
                TerminationTerm::goal("home", |s: &Cart| s.x == 0.0),
            ],
            time_limit: Some(3),
            start_events: vec![StartEvent::new("tilt", |s: &mut Cart, rng: &mut ChaCha8Rng| {
                s.tilt = rand::Rng::random_range(rng, -0.1..0.1)
            })],
        }
    }

    #[test]
    fn the_observation_is_the_terms_in_order_and_its_size_is_derived() {
        let t = terms();
        let mut obs = vec![9.0];
        t.observe(&Cart { x: 0.3, angle: 0.2, tilt: 0.0 }, &mut obs);
        assert_eq!(obs, vec![0.3, 0.2, 0.2]);
        assert_eq!(t.observation_dim(), 3);
        assert_eq!(t.observation_names(), vec!["x", "angle_twice[0]", "angle_twice[1]"]);
        assert_eq!(
            t.observation_space(),
            Space::Box { low: vec![f32::NEG_INFINITY, -1.0, -1.0], high: vec![f32::INFINITY, 1.0, 1.0] }
        );
        assert_eq!(
            t.observation_plausible(),
            Space::Box { low: vec![-5.0, -1.0, -1.0], high: vec![5.0, 1.0, 1.0] },
            "declared, else the bounds"
        );
    }

    #[test]
    fn bounded_reward_terms_give_the_task_a_reward_range_and_are_clamped_into_it() {
        let mut t = terms();
        assert_eq!(t.reward_range(), (f32::NEG_INFINITY, f32::INFINITY), "terms without bounds are unbounded");
        t.rewards = vec![
            RewardTerm::new("alive", 1.0, |_| 1.0).bounded(1.0, 1.0),
            RewardTerm::new("angle", -2.0, |s: &Cart| s.angle.abs()).bounded(0.0, 0.5),
            RewardTerm::new("unused", 0.0, |_| 1.0),
        ];
        assert_eq!(t.reward_range(), (0.0, 1.0), "a zero weight adds nothing, even unbounded");
        let mut sums = Vec::new();
        let outcome = t.evaluate(&Cart { angle: 3.0, ..Default::default() }, 0, &mut sums);
        assert_eq!(outcome.reward, 0.0, "the angle's value is clamped to 0.5");
    }

    #[test]
    fn rewards_sum_weighted_terms_and_are_logged_per_term() {
        let t = terms();
        let mut sums = Vec::new();
        let o = t.evaluate(&Cart { x: 0.3, angle: 0.25, tilt: 0.0 }, 0, &mut sums);
        assert_eq!(o.reward, 0.5);
        let o2 = t.evaluate(&Cart { x: 0.3, angle: 0.1, tilt: 0.0 }, 1, &mut sums);
        assert!((o2.reward - 0.8).abs() < 1e-6);
        assert!((sums[0] - 2.0).abs() < 1e-6 && (sums[1] + 0.7).abs() < 1e-6, "{sums:?}");
        assert_eq!((o.terminated, o.truncated, o.success), (false, false, None));
    }

    #[test]
    fn terminations_time_limit_and_success() {
        let t = terms();
        let mut sums = Vec::new();
        let fallen = t.evaluate(&Cart { x: 0.3, angle: 0.6, tilt: 0.0 }, 0, &mut sums);
        assert_eq!((fallen.terminated, fallen.truncated, fallen.success), (true, false, Some(false)));
        let home = t.evaluate(&Cart { x: 0.0, angle: 0.0, tilt: 0.0 }, 0, &mut sums);
        assert_eq!((home.terminated, home.success), (true, Some(true)));
        let third = t.evaluate(&Cart { x: 0.3, angle: 0.0, tilt: 0.0 }, 2, &mut sums);
        assert_eq!(
            (third.terminated, third.truncated, third.success),
            (false, true, Some(false)),
            "the third step hits the limit of 3"
        );
        let second = t.evaluate(&Cart { x: 0.3, angle: 0.0, tilt: 0.0 }, 1, &mut sums);
        assert!(!second.truncated);
    }

    #[test]
    fn start_events_draw_from_the_given_stream() {
        let t = terms();
        let (mut a, mut b) = (Cart::default(), Cart::default());
        t.start(&mut a, &mut ChaCha8Rng::seed_from_u64(7));
        t.start(&mut b, &mut ChaCha8Rng::seed_from_u64(7));
        assert_eq!(a.tilt, b.tilt);
        assert!(a.tilt != 0.0 && a.tilt.abs() < 0.1);
    }
}
