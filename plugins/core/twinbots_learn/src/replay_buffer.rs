//! The replay buffer: a ring of transitions from N envs stepped together, raw observations (a
//! sample is normalised with the statistics in force when it is drawn), and, for hindsight
//! experience replay, how many later steps of its own episode each transition has.
//!
//! Every push adds one transition per env, so env `e`'s steps lie `n_envs` apart: the ring's
//! capacity is a multiple of `n_envs`, and the step `k` later of the same env is `k × n_envs`
//! further on.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

#[cfg(test)]
use twinbots_api::GoalChange;
use twinbots_api::GoalSpec;

/// `remaining` of a transition whose episode has not ended yet.
const RUNNING: u32 = u32::MAX;

/// The ring's observations, row after row: floats, or bytes for camera images (whole numbers
/// 0–255: a quarter of the memory, exactly).
#[derive(Clone, Debug, PartialEq)]
pub enum Rows {
    Floats(Vec<f32>),
    Bytes(Vec<u8>),
}

impl Rows {
    /// Values held (rows × width).
    pub fn len(&self) -> usize {
        match self {
            Rows::Floats(v) => v.len(),
            Rows::Bytes(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Row `i` of `width` values, as floats.
    pub fn row(&self, i: usize, width: usize) -> Vec<f32> {
        match self {
            Rows::Floats(v) => v[i * width..(i + 1) * width].to_vec(),
            Rows::Bytes(v) => v[i * width..(i + 1) * width].iter().map(|&b| b as f32).collect(),
        }
    }

    /// Writes `src` as row `i` (appended when `i` is the next row).
    fn put(&mut self, i: usize, src: &[f32]) {
        let width = src.len();
        match self {
            Rows::Floats(v) if v.len() < (i + 1) * width => v.extend_from_slice(src),
            Rows::Floats(v) => v[i * width..(i + 1) * width].copy_from_slice(src),
            // Image values are whole numbers in 0–255 (`Space::Image`): the cast is exact.
            Rows::Bytes(v) if v.len() < (i + 1) * width => v.extend(src.iter().map(|&x| x as u8)),
            Rows::Bytes(v) => v[i * width..(i + 1) * width].iter_mut().zip(src).for_each(|(b, &x)| *b = x as u8),
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct ReplayBuffer {
    pub n_envs: usize,
    pub obs_dim: usize,
    pub act_dim: usize,
    pub capacity: usize,
    /// Where the next transition goes, and whether the ring has wrapped.
    pub pos: usize,
    pub full: bool,
    pub obs: Rows,
    pub next_obs: Rows,
    /// Actions as the actor gives them, in [-1, 1].
    pub actions: Vec<f32>,
    pub rewards: Vec<f32>,
    /// 1 where the MDP ended (terminated; a truncation bootstraps).
    pub dones: Vec<f32>,
    /// Steps of the same episode after this one, once the episode has ended.
    pub remaining: Vec<u32>,
    /// The termination term that ended the MDP at this step, as 1 + its index in
    /// `terminations` (0: none, or the env did not say): the step information a goal's reward
    /// is recomputed with.
    pub ended_by: Vec<u8>,
    /// The termination terms' names `ended_by` refers to, in the order first met.
    pub terminations: Vec<String>,
    /// Each env's steps so far in its running episode.
    pub episode_steps: Vec<u32>,
}

/// A sampled minibatch, rows flat.
#[derive(Clone, Debug)]
pub struct Batch {
    pub obs: Vec<f32>,
    pub actions: Vec<f32>,
    pub rewards: Vec<f32>,
    pub next_obs: Vec<f32>,
    pub dones: Vec<f32>,
}

impl ReplayBuffer {
    pub fn new(capacity: usize, n_envs: usize, obs_dim: usize, act_dim: usize) -> Self {
        let capacity = (capacity / n_envs).max(1) * n_envs;
        Self {
            n_envs,
            obs_dim,
            act_dim,
            capacity,
            pos: 0,
            full: false,
            obs: Rows::Floats(Vec::new()),
            next_obs: Rows::Floats(Vec::new()),
            actions: Vec::new(),
            rewards: Vec::new(),
            dones: Vec::new(),
            remaining: Vec::new(),
            ended_by: Vec::new(),
            terminations: Vec::new(),
            episode_steps: vec![0; n_envs],
        }
    }

    /// The same ring keeping observations as bytes (for camera images, `Space::Image`).
    pub fn with_byte_observations(mut self) -> Self {
        (self.obs, self.next_obs) = (Rows::Bytes(Vec::new()), Rows::Bytes(Vec::new()));
        self
    }

    pub fn len(&self) -> usize {
        if self.full { self.capacity } else { self.pos }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// One step of every env: `next_obs` is each step's outcome (a finished episode's last
    /// observation, not the next episode's first); `ended` marks episodes that ended
    /// (terminated or truncated), `terminated` those that ended in the MDP, `ended_by` the
    /// termination term that ended each (empty where the env does not say).
    #[allow(clippy::too_many_arguments)]
    pub fn push(
        &mut self,
        obs: &[f32],
        actions: &[f32],
        rewards: &[f32],
        next_obs: &[f32],
        terminated: &[bool],
        ended: &[bool],
        ended_by: &[Option<String>],
    ) {
        let (o, a) = (self.obs_dim, self.act_dim);
        for e in 0..self.n_envs {
            let i = self.pos;
            let put = |dst: &mut Vec<f32>, src: &[f32], width: usize| {
                if dst.len() < (i + 1) * width {
                    dst.extend_from_slice(src);
                } else {
                    dst[i * width..(i + 1) * width].copy_from_slice(src);
                }
            };
            self.obs.put(i, &obs[e * o..(e + 1) * o]);
            self.next_obs.put(i, &next_obs[e * o..(e + 1) * o]);
            put(&mut self.actions, &actions[e * a..(e + 1) * a], a);
            put(&mut self.rewards, &[rewards[e]], 1);
            put(&mut self.dones, &[f32::from(u8::from(terminated[e]))], 1);
            let term = ended_by.get(e).and_then(|t| t.as_deref()).map_or(0, |name| self.term_code(name));
            if self.ended_by.len() <= i {
                self.ended_by.push(term);
            } else {
                self.ended_by[i] = term;
            }
            if self.remaining.len() <= i {
                self.remaining.push(RUNNING);
            } else {
                self.remaining[i] = RUNNING;
            }
            self.episode_steps[e] += 1;
            if ended[e] {
                // The episode's steps, newest first, learn how many followed them.
                let steps = (self.episode_steps[e] as usize).min(self.capacity / self.n_envs);
                for k in 0..steps {
                    let j = (i + self.capacity - k * self.n_envs) % self.capacity;
                    self.remaining[j] = k as u32;
                }
                self.episode_steps[e] = 0;
            }
            self.pos += 1;
            if self.pos == self.capacity {
                self.pos = 0;
                self.full = true;
            }
        }
    }

    /// `name`'s code in `ended_by` (1 + its index in `terminations`, added when first met).
    fn term_code(&mut self, name: &str) -> u8 {
        match self.terminations.iter().position(|t| t == name) {
            Some(k) => k as u8 + 1,
            None => {
                self.terminations.push(name.to_string());
                self.terminations.len().min(u8::MAX as usize) as u8
            }
        }
    }

    /// `batch_size` transitions drawn uniformly; with `her = (goals, n)`, each transition of a
    /// finished episode has its goal replaced, with probability n / (n + 1), by one its episode
    /// achieved at that step or later ("future"), and its reward and `done` recomputed for it.
    pub fn sample(&self, batch_size: usize, rng: &mut ChaCha8Rng, her: Option<(&GoalSpec, usize)>) -> Batch {
        self.assemble(&self.draw(batch_size, rng, her.map(|(_, n)| n)), her.map(|(goal, _)| goal))
    }

    /// Which transitions [`ReplayBuffer::sample`] takes, and for each the transition whose
    /// achieved goal replaces its own, if any: all of the sample's randomness.
    pub fn draw(&self, batch_size: usize, rng: &mut ChaCha8Rng, her_goals: Option<usize>) -> Vec<Draw> {
        let len = self.len();
        (0..batch_size)
            .map(|_| {
                let i = rng.random_range(0..len);
                let goal_from = match her_goals {
                    Some(n) if self.remaining[i] != RUNNING && rng.random_range(0..=n) > 0 => {
                        let k = rng.random_range(0..=self.remaining[i] as usize);
                        Some((i + k * self.n_envs) % self.capacity)
                    }
                    _ => None,
                };
                Draw { index: i, goal_from }
            })
            .collect()
    }

    /// The minibatch of `draws`, relabelled through `goal` (the costly part of HER: a part of a
    /// minibatch may be assembled on each thread).
    pub fn assemble(&self, draws: &[Draw], goal: Option<&GoalSpec>) -> Batch {
        let (o, a) = (self.obs_dim, self.act_dim);
        let n = draws.len();
        let mut b = Batch {
            obs: Vec::with_capacity(n * o),
            actions: Vec::with_capacity(n * a),
            rewards: Vec::with_capacity(n),
            next_obs: Vec::with_capacity(n * o),
            dones: Vec::with_capacity(n),
        };
        for &Draw { index: i, goal_from } in draws {
            let mut obs = self.obs.row(i, o);
            let mut next = self.next_obs.row(i, o);
            let (mut reward, mut done) = (self.rewards[i], self.dones[i] > 0.5);
            if let (Some(goal), Some(j)) = (goal, goal_from) {
                let achieved = (goal.achieved)(&self.next_obs.row(j, o));
                let ended_by = match self.ended_by.get(i) {
                    Some(&code) if code > 0 => self.terminations.get(code as usize - 1).map(String::as_str),
                    _ => None,
                };
                (reward, done) = goal.relabel(&obs, &next, reward, done, ended_by, &achieved);
                (goal.substitute)(&mut obs, &achieved);
                (goal.substitute)(&mut next, &achieved);
            }
            b.obs.extend(obs);
            b.next_obs.extend(next);
            b.actions.extend_from_slice(&self.actions[i * a..(i + 1) * a]);
            b.rewards.push(reward);
            b.dones.push(f32::from(u8::from(done)));
        }
        b
    }
}

/// One transition of a sample: its index, and the transition whose achieved goal HER gives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Draw {
    pub index: usize,
    pub goal_from: Option<usize>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// 1-d "positions" with the goal in the second value: reward −|next − goal|, and the
    /// episode ends on the goal.
    fn line_goal() -> GoalSpec {
        GoalSpec {
            dim: 1,
            achieved: |obs| vec![obs[0]],
            desired: |obs| vec![obs[1]],
            substitute: |obs, goal| obs[1] = goal[0],
            change: |_, next, _, from, to| GoalChange {
                reward: (next[0] - from[0]).abs() - (next[0] - to[0]).abs(),
                ends_at_from: next[0] == from[0],
                ends_at_to: next[0] == to[0],
            },
        }
    }

    #[test]
    fn relabelled_goals_come_from_later_steps_of_the_same_episode() {
        // Two envs; env 0 walks 0,1,2,3 (episode ends after 3 steps, then a running one), env 1
        // walks 100,101,... never ending. Goal 50 everywhere.
        let mut buffer = ReplayBuffer::new(64, 2, 2, 1);
        for t in 0..6 {
            let x0 = (t % 3) as f32 + if t >= 3 { 10.0 } else { 0.0 };
            let obs = [x0, 50.0, 100.0 + t as f32, 50.0];
            let next = [x0 + 1.0, 50.0, 101.0 + t as f32, 50.0];
            let rewards = [-(x0 + 1.0 - 50.0).abs(), -(101.0 + t as f32 - 50.0).abs()];
            buffer.push(&obs, &[0.0, 0.0], &rewards, &next, &[false, false], &[t == 2, false], &[]);
        }
        assert_eq!(&buffer.remaining[..6], &[2, RUNNING, 1, RUNNING, 0, RUNNING]);
        let goal = line_goal();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let batch = buffer.sample(4000, &mut rng, Some((&goal, 4)));
        let mut relabelled = 0;
        for r in 0..4000 {
            let (obs, next) = (&batch.obs[2 * r..2 * r + 2], &batch.next_obs[2 * r..2 * r + 2]);
            if obs[1] != 50.0 {
                relabelled += 1;
                // Env 0's first episode only (x in 0..3), a goal it reached at this step or later.
                assert!(obs[0] < 3.0 && obs[1] >= next[0] && obs[1] <= 3.0, "{obs:?} → {next:?}");
                assert_eq!(obs[1], next[1]);
                assert_eq!(batch.rewards[r], -(next[0] - obs[1]).abs());
                // Done exactly where the relabelled goal is reached.
                assert_eq!(batch.dones[r], f32::from(u8::from(next[0] == obs[1])));
            } else {
                assert_eq!(batch.rewards[r], -(next[0] - 50.0).abs());
            }
        }
        // 3 of 12 transitions are finished, relabelled 4 times in 5: 20 %.
        assert!((600..1000).contains(&relabelled), "{relabelled}");
    }

    #[test]
    fn the_ring_overwrites_the_oldest_and_keeps_envs_apart() {
        let mut buffer = ReplayBuffer::new(5, 2, 1, 1);
        assert_eq!(buffer.capacity, 4);
        for t in 0..3 {
            let x = t as f32;
            buffer.push(&[x, -x], &[0.0, 0.0], &[0.0, 0.0], &[x, -x], &[false, false], &[false, false], &[]);
        }
        assert_eq!(buffer.len(), 4);
        assert_eq!(buffer.obs, Rows::Floats(vec![2.0, -2.0, 1.0, -1.0]));
        let mut bytes = ReplayBuffer::new(5, 2, 1, 1).with_byte_observations();
        for t in 0..3 {
            let x = [t as f32, 200.0 + t as f32];
            bytes.push(&x, &[0.0, 0.0], &[0.0, 0.0], &x, &[false, false], &[false, false], &[]);
        }
        assert_eq!(bytes.obs, Rows::Bytes(vec![2, 202, 1, 201]));
        assert_eq!(bytes.next_obs.row(1, 1), vec![202.0]);
    }

    #[test]
    fn the_goal_is_told_which_termination_ended_a_stored_step() {
        // One env, one-step episodes: the first ended by "stop", the second by "arrived", the
        // third by no term (the env did not say). The goal's reward change is −100 for a stopped step.
        let goal = GoalSpec {
            change: |_, _, ended_by, _, _| GoalChange {
                reward: if ended_by == Some("stop") { -100.0 } else { 0.0 },
                ends_at_from: false,
                ends_at_to: false,
            },
            ..line_goal()
        };
        let mut buffer = ReplayBuffer::new(8, 1, 2, 1);
        for (k, ended_by) in [Some("stop".to_string()), Some("arrived".into()), None].into_iter().enumerate() {
            let x = k as f32;
            buffer.push(&[x, 50.0], &[0.0], &[0.0], &[x, 50.0], &[true], &[true], &[ended_by]);
        }
        assert_eq!(buffer.terminations, ["stop", "arrived"]);
        assert_eq!(buffer.ended_by, [1, 2, 0]);
        let batch = buffer.sample(300, &mut ChaCha8Rng::seed_from_u64(2), Some((&goal, 1_000_000)));
        for r in 0..300 {
            let stopped = batch.obs[2 * r] == 0.0;
            assert_eq!(
                batch.rewards[r],
                if stopped { -100.0 } else { 0.0 },
                "row {r}: {:?}",
                &batch.obs[2 * r..2 * r + 2]
            );
        }
    }
}
