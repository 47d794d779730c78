//! The channel bridge (docs/design/training.md, "Training: threads and the bridge"): the learner
//! runs on its own thread with a [`ChannelVecEnv`]; the Bevy app runs on the main thread with
//! [`BridgePlugin`], which each control step waits for the actions of all arenas, lets the step
//! run, and sends back what it produced. Either side ending (returning, panicking, dropping its
//! end) ends the other with an error message instead of a hang.

use bevy::prelude::*;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvError, Sender, TryRecvError, bounded};

use twinbots_api::{EnvState, Space, StepResult, StreamState, VecEnv};

use crate::env::{ArenaOrder, collect_step, reset_arenas, write_actions};
use crate::replay::{begin_episodes, env_state};
use crate::task::ActiveTask;

/// How long a side of the bridge may poll for the other's message before it sleeps on the
/// channel. Waking a sleeping thread costs tens of microseconds on a small VM — as much as a
/// one-arena cart-pole step (≈ 90 µs). A side polls only while the other side's answers came
/// within this (short steps, a policy's inference); when the last wait was longer (many arenas
/// stepping on both cores, a PPO update) it sleeps at once, so polling never keeps a core from
/// a side with work. It yields while it polls.
const POLL: Duration = Duration::from_micros(300);

/// One end of a bridge channel: the receiver, and how long the last message took to come.
struct Inbox<T> {
    channel: Receiver<T>,
    last_wait: Duration,
}

impl<T> Inbox<T> {
    fn new(channel: Receiver<T>) -> Self {
        Self { channel, last_wait: Duration::ZERO }
    }

    /// The next message: polled for while the last one came within [`POLL`], else waited for.
    fn receive(&mut self) -> Result<T, RecvError> {
        let started = Instant::now();
        let message = loop {
            match self.channel.try_recv() {
                Ok(message) => break Ok(message),
                Err(TryRecvError::Disconnected) => break Err(RecvError),
                Err(TryRecvError::Empty) if self.last_wait < POLL && started.elapsed() < POLL => {
                    std::thread::yield_now()
                }
                Err(TryRecvError::Empty) => break self.channel.recv(),
            }
        };
        self.last_wait = started.elapsed();
        message
    }
}

/// Trainer → app.
#[derive(Clone, Debug)]
pub enum Request {
    Reset {
        seed: Option<u64>,
    },
    Step {
        actions: Vec<f32>,
    },
    /// The envs' running episodes, for a checkpoint.
    State,
    /// New episodes from given streams (a replay's step).
    Begin {
        starts: Vec<(usize, StreamState)>,
        clock: Option<u64>,
    },
}

/// App → trainer; an `Err` is a request the app refused (e.g. wrong action count).
#[derive(Clone, Debug)]
pub enum Reply {
    /// Observations: of a reset, or of begun episodes.
    Reset(Vec<f32>),
    Step(StepResult),
    State(Option<EnvState>),
}

/// The app's end of the bridge.
#[derive(Resource)]
pub struct BridgeEndpoint {
    requests: Inbox<Request>,
    replies: Sender<Result<Reply, String>>,
    /// A step's actions were applied this frame; its results go back after the step.
    pending: bool,
    /// The trainer hung up: the app should stop.
    pub closed: bool,
}

/// Adds the bridge systems; they act once [`connect`] has inserted a [`BridgeEndpoint`].
pub struct BridgePlugin;

impl Plugin for BridgePlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(
            First,
            receive_requests.run_if(resource_exists::<BridgeEndpoint>).run_if(twinbots_sim::physics::sim_started),
        )
        .add_systems(PostUpdate, send_step_results.run_if(resource_exists::<BridgeEndpoint>))
        .init_resource::<SimulationTime>();
    }
}

/// Connects a started app (see [`crate::env::start`]) to a new trainer-side env.
pub fn connect(world: &mut World) -> anyhow::Result<ChannelVecEnv> {
    let spec = world
        .get_resource::<ActiveTask>()
        .map(|task| task.0.clone())
        .ok_or_else(|| anyhow::anyhow!("no robot task in the app"))?;
    let arenas = world
        .get_resource::<ArenaOrder>()
        .map(|o| o.0.len())
        .ok_or_else(|| anyhow::anyhow!("the app has not been started"))?;
    // Capacity 1: one request in flight, as a synchronous step is.
    let (request_tx, request_rx) = bounded(1);
    let (reply_tx, reply_rx) = bounded(1);
    world.insert_resource(BridgeEndpoint {
        requests: Inbox::new(request_rx),
        replies: reply_tx,
        pending: false,
        closed: false,
    });
    Ok(ChannelVecEnv {
        requests: request_tx,
        replies: Inbox::new(reply_rx),
        num_envs: arenas,
        observation_space: spec.observation_space,
        action_space: spec.action_space,
    })
}

/// Runs the app's frames on this thread until the trainer hangs up.
pub fn run_until_closed(app: &mut App) {
    loop {
        app.update();
        if app.world().get_resource::<BridgeEndpoint>().is_none_or(|e| e.closed) {
            break;
        }
    }
}

/// Seconds the app spent simulating for the trainer (steps from their actions to their results,
/// and resets), without the time it waited for requests: the trainer's env time less this is
/// the bridge's own cost.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct SimulationTime {
    pub seconds: f64,
    step_started: Option<std::time::Instant>,
}

/// Waits for the trainer: answers resets at once; a step's actions are written and the frame
/// goes on to simulate it.
fn receive_requests(world: &mut World) {
    let arenas = world.resource::<ArenaOrder>().0.clone();
    loop {
        let request = world.resource_mut::<BridgeEndpoint>().requests.receive();
        let reply = match request {
            Ok(Request::Reset { seed }) => {
                let started = std::time::Instant::now();
                let obs = reset_arenas(world, &arenas, seed);
                world.resource_mut::<SimulationTime>().seconds += started.elapsed().as_secs_f64();
                Ok(Reply::Reset(obs))
            }
            Ok(Request::Step { actions }) => match write_actions(world, &arenas, &actions) {
                Ok(()) => {
                    world.resource_mut::<SimulationTime>().step_started = Some(std::time::Instant::now());
                    world.resource_mut::<BridgeEndpoint>().pending = true;
                    return;
                }
                Err(e) => Err(e.to_string()),
            },
            Ok(Request::State) => Ok(Reply::State(env_state(world, &arenas))),
            Ok(Request::Begin { starts, clock }) => {
                begin_episodes(world, &arenas, &starts, clock).map(Reply::Reset).map_err(|e| e.to_string())
            }
            Err(_) => {
                world.resource_mut::<BridgeEndpoint>().closed = true;
                return;
            }
        };
        if world.resource::<BridgeEndpoint>().replies.send(reply).is_err() {
            world.resource_mut::<BridgeEndpoint>().closed = true;
            return;
        }
    }
}

fn send_step_results(world: &mut World) {
    if !world.resource::<BridgeEndpoint>().pending {
        return;
    }
    let arenas = &world.resource::<ArenaOrder>().0;
    let result = collect_step(world, arenas);
    let mut time = world.resource_mut::<SimulationTime>();
    if let Some(started) = time.step_started.take() {
        time.seconds += started.elapsed().as_secs_f64();
    }
    let mut endpoint = world.resource_mut::<BridgeEndpoint>();
    endpoint.pending = false;
    if endpoint.replies.send(Ok(Reply::Step(result))).is_err() {
        endpoint.closed = true;
    }
}

/// The trainer's end: a [`VecEnv`] whose steps happen in the app on the other thread.
pub struct ChannelVecEnv {
    requests: Sender<Request>,
    replies: Inbox<Result<Reply, String>>,
    num_envs: usize,
    observation_space: Space,
    action_space: Space,
}

impl ChannelVecEnv {
    fn call(&mut self, request: Request) -> anyhow::Result<Reply> {
        const GONE: &str = "the simulation app has stopped (its thread ended or panicked)";
        self.requests.send(request).map_err(|_| anyhow::anyhow!(GONE))?;
        let reply = self.replies.receive().map_err(|_| anyhow::anyhow!(GONE))?;
        reply.map_err(|e| anyhow::anyhow!("the simulation refused the request: {e}"))
    }
}

impl VecEnv for ChannelVecEnv {
    fn num_envs(&self) -> usize {
        self.num_envs
    }
    fn observation_space(&self) -> &Space {
        &self.observation_space
    }
    fn action_space(&self) -> &Space {
        &self.action_space
    }
    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>> {
        match self.call(Request::Reset { seed })? {
            Reply::Reset(obs) => Ok(obs),
            other => anyhow::bail!("bridge protocol error: {other:?} in reply to a reset"),
        }
    }
    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult> {
        match self.call(Request::Step { actions: actions.to_vec() })? {
            Reply::Step(result) => Ok(result),
            other => anyhow::bail!("bridge protocol error: {other:?} in reply to a step"),
        }
    }
    fn state(&mut self) -> anyhow::Result<Option<EnvState>> {
        match self.call(Request::State)? {
            Reply::State(state) => Ok(state),
            other => anyhow::bail!("bridge protocol error: {other:?} in reply to a state request"),
        }
    }
    fn begin_episodes(&mut self, starts: &[(usize, StreamState)], clock: Option<u64>) -> anyhow::Result<Vec<f32>> {
        match self.call(Request::Begin { starts: starts.to_vec(), clock })? {
            Reply::Reset(obs) => Ok(obs),
            other => anyhow::bail!("bridge protocol error: {other:?} in reply to new episodes"),
        }
    }
}
