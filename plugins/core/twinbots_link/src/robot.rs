//! A design-pattern-3 robot's side of the episode protocol, shared by every robot plugin: it
//! draws its next episode's start (the task's start events) and homes (with its own motors,
//! nothing said to the server; a robot that can drives to the drawn start, as the Supervisor
//! places one under patterns 1 and 2), starts an episode once home,
//! reports each step's outcome and applies the action it gets back, and after an episode's
//! last step goes home again. A lost server is reconnected with backoff and the episode
//! begins afresh from home.
//!
//! The far end is a [`PolicyLink`]: a RobotServer over TCP (the [`Communicator`], given a
//! [`ServerAddress`]), or the robot's own copy of a policy (an [`OnBoardPolicy`], which answers
//! as a server would), so the cycle is the same whether the policy learns elsewhere or runs on
//! board.
//!
//! [`ServerRobotPlugin`] runs that cycle for any robot whose task is defined by terms: the same
//! [`Terms`] as under patterns 1 and 2 turn the controller's state into what is sent. The robot
//! plugin brings only what is its own: a reader of its devices (in `TaskSet::Read`), a homing
//! routine (in [`RobotCycleSet::Home`], setting [`AtHome`]; it may drive to the drawn start),
//! and, where a cell needs one, an operator who puts the drawn start in place (in
//! [`RobotCycleSet::Operate`]).

use std::net::SocketAddr;
use std::time::Duration;

use bevy::ecs::component::Mutable;
use bevy::prelude::*;
use rand_chacha::ChaCha8Rng;
use twinbots_sim::{Arena, SimSet};
use twinbots_task::task::{TaskSet, Terms, configure_task_sets};
use twinbots_task::{Action, ActiveTask, EndedEpisode, Episode};

use crate::checks::{MAX_SERVER_TEXT, truncated};
use crate::client::{Communicator, CommunicatorError, Identity};
pub use crate::onboard::{OnBoardLink, OnBoardPolicy};
pub use crate::policy_link::PolicyLink;
use crate::protocol::{ErrorCode, RobotMessage, ServerMessage};

/// Where the RobotServer is, and how long a robot keeps trying to reach it.
#[derive(Resource, Clone, Copy, Debug)]
pub struct ServerAddress {
    pub addr: SocketAddr,
    pub patience: Duration,
}

/// The RobotServer's shared secret (`serve --token`), if it wants one: sent in every robot's
/// `hello`. Optional beside a [`ServerAddress`].
#[derive(Resource, Clone, Debug, Default)]
pub struct ServerToken(pub Option<String>);

/// TLS to reach the RobotServer with (`robot --tls-ca`), and the name its certificate must
/// bear. Optional beside a [`ServerAddress`]; absent: plain TCP.
#[derive(Resource, Clone, Debug)]
pub struct ServerTlsLink {
    pub tls: crate::tls::ClientTls,
    pub name: rustls::pki_types::ServerName<'static>,
}

/// Set when the robots should stop: `Ok(reason)` when the server finished training.
#[derive(Resource, Clone, Debug, Default)]
pub struct RobotRunState {
    pub stop: Option<Result<String, String>>,
    /// Episodes the robots finished, and reconnections they made.
    pub episodes: u64,
    pub reconnects: u32,
}

/// Where a robot is in its episode cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Returning to its start state with its own motors; the server hears nothing.
    Homing,
    /// Home: this step announces a new episode.
    Starting,
    Running,
}

/// One robot's conversation with where its actions come from.
pub struct Conversation {
    link: Box<dyn PolicyLink>,
    pub phase: Phase,
    awaiting_reply: bool,
    /// Requests refused in a row (non-fatal error replies).
    refused: u32,
}

/// Non-fatal refusals in a row after which a robot stops: a server that refuses everything
/// this robot sends will not start using it.
const MAX_REFUSED: u32 = 3;

impl Conversation {
    /// A conversation over `link` (connected), beginning by homing.
    pub fn over(link: Box<dyn PolicyLink>) -> Self {
        Self { link, phase: Phase::Homing, awaiting_reply: false, refused: 0 }
    }

    /// Connects to a RobotServer (retrying until the address's patience runs out) and begins
    /// by homing.
    pub fn connect(
        address: &ServerAddress,
        identity: Identity,
        tls: Option<&ServerTlsLink>,
    ) -> Result<Self, CommunicatorError> {
        let mut communicator = Communicator::new(address.addr, identity, address.patience);
        if let Some(link) = tls {
            communicator = communicator.with_tls(link.tls.clone(), link.name.clone());
        }
        communicator.connect()?;
        Ok(Self::over(Box::new(communicator)))
    }

    /// Connects the robot of arena `index`; if it cannot, the robots stop, naming it.
    pub fn connect_robot(
        address: &ServerAddress,
        identity: Identity,
        tls: Option<&ServerTlsLink>,
        index: usize,
        state: &mut RobotRunState,
    ) -> Option<Self> {
        Self::connect(address, identity, tls).map_err(|e| state.stop = Some(Err(format!("robot {index}: {e}")))).ok()
    }

    /// Sends this step's message: `start` when starting, the step's outcome when running.
    /// Send every robot's message before receiving any reply, so the server works on all.
    pub fn send(&mut self, message: &RobotMessage, state: &mut RobotRunState) {
        match self.link.send(message) {
            Ok(()) => self.awaiting_reply = true,
            Err(CommunicatorError::Disconnected(_)) => self.lost(state),
            Err(e) => state.stop = Some(Err(e.to_string())),
        }
    }

    /// The reply to this step's message: the action to apply, if the server sent one.
    pub fn receive(&mut self, state: &mut RobotRunState) -> Option<Vec<f32>> {
        if !std::mem::take(&mut self.awaiting_reply) {
            return None;
        }
        match self.link.receive() {
            Ok(ServerMessage::Action { action }) => {
                self.refused = 0;
                if self.phase == Phase::Starting {
                    self.phase = Phase::Running;
                }
                return Some(action);
            }
            Ok(ServerMessage::Ack) => {
                state.episodes += 1;
                self.phase = Phase::Homing;
            }
            Ok(ServerMessage::Done { reason }) => state.stop = Some(Ok(truncated(&reason, MAX_SERVER_TEXT))),
            // The server closed an idle connection (a robot that homed for longer than its
            // read timeout): the link is lost, not the training.
            Ok(ServerMessage::Error { code: ErrorCode::Timeout, .. }) => self.lost(state),
            Ok(ServerMessage::Error { message, fatal: true, .. }) => {
                state.stop = Some(Err(truncated(&message, MAX_SERVER_TEXT)))
            }
            // The request was not used: the episode cannot go on without an action. The robot
            // homes and starts afresh (a `start` drops the running episode), and stops if the
            // server refuses request after request.
            Ok(ServerMessage::Error { message, .. }) => {
                let message = truncated(&message, MAX_SERVER_TEXT);
                warn!("server refused a request: {message}");
                self.refused += 1;
                self.phase = Phase::Homing;
                if self.refused >= MAX_REFUSED {
                    state.stop =
                        Some(Err(format!("the server refused {MAX_REFUSED} requests in a row; the last: {message}")));
                }
                return None;
            }
            Ok(ServerMessage::Welcome { .. }) => {
                state.stop = Some(Err("the server sent a second welcome in the middle of the conversation".into()))
            }
            Err(CommunicatorError::Disconnected(_)) => self.lost(state),
            Err(e) => state.stop = Some(Err(e.to_string())),
        }
        self.refused = 0;
        None
    }

    /// The server went away: reconnect (with backoff) and begin a fresh episode from home.
    fn lost(&mut self, state: &mut RobotRunState) {
        self.phase = Phase::Homing;
        match self.link.connect() {
            Ok(()) => state.reconnects += 1,
            Err(e) => state.stop = Some(Err(e.to_string())),
        }
    }
}

/// A pattern-3 robot's controller on its arena: its conversation with the server and its own
/// random stream (the arena's, cloned when it connects; the robot draws its episodes' starts
/// from it).
#[derive(Component)]
pub struct Controller {
    conversation: Conversation,
    pub rng: ChaCha8Rng,
    /// This control step's outcome was evaluated by the task's terms (to be tallied).
    evaluated: bool,
    /// The next episode's start is drawn (the task's start events ran since the last began).
    start_drawn: bool,
}

impl Controller {
    pub fn phase(&self) -> Phase {
        self.conversation.phase
    }
}

/// Written by the robot's homing routine while it homes: whether it is home and still.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AtHome(pub bool);

/// Order of a pattern-3 robot's episode cycle inside `SimSet::Actuate`.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum RobotCycleSet {
    /// A robot that begins homing draws its next episode's start: the task's start events
    /// (generic), run when the episode before ended, as under patterns 1 and 2.
    Draw,
    /// The robot drives itself home, or to the drawn start where it can (the UR5e's arm), and
    /// says when it is there ([`AtHome`]).
    Home,
    /// A robot at home begins an episode (generic).
    Start,
    /// The lab operator puts the drawn start in place (re-seats a part, lets go of a pole).
    Operate,
}

/// The pattern-3 episode cycle of robots with controller state `S` and a `Terms<S>` task
/// (inserted by the task's `TaskTermsPlugin` under `DesignPattern::Server`). Needs a
/// [`ServerAddress`] or an [`OnBoardPolicy`] resource; every arena gets a [`Controller`] and an
/// [`AtHome`] after start-up. An episode's steps are tallied after the task's reports
/// (`TaskSet::Tally`), and on its last step `Episode::finished` holds its summary, as under the
/// in-process patterns.
pub struct ServerRobotPlugin<S> {
    /// The robot kind the server expects in `hello.robot`.
    pub robot: String,
    state: std::marker::PhantomData<fn() -> S>,
}

impl<S> ServerRobotPlugin<S> {
    pub fn new(robot: &str) -> Self {
        Self { robot: robot.into(), state: std::marker::PhantomData }
    }
}

/// The robot kind announced in `hello`.
#[derive(Resource, Clone, Debug)]
struct RobotKind(String);

impl<S: Component<Mutability = Mutable>> Plugin for ServerRobotPlugin<S> {
    fn build(&self, app: &mut App) {
        configure_task_sets(app);
        app.init_resource::<RobotRunState>()
            .insert_resource(RobotKind(self.robot.clone()))
            .configure_sets(
                Update,
                (RobotCycleSet::Draw, RobotCycleSet::Home, RobotCycleSet::Start, RobotCycleSet::Operate)
                    .chain()
                    .in_set(SimSet::Actuate),
            )
            .add_systems(PostStartup, connect_robots)
            .add_systems(
                Update,
                (draw_starts::<S>.in_set(RobotCycleSet::Draw), begin_episodes.in_set(RobotCycleSet::Start)),
            )
            .add_systems(Update, exchange::<S>.in_set(TaskSet::Evaluate))
            .add_systems(Update, tally_steps.in_set(TaskSet::Tally));
    }
}

/// What a robot of this app announces: its kind and its task's spaces.
pub fn identity(world: &World) -> Identity {
    let spec = world.resource::<ActiveTask>();
    Identity {
        robot: world.resource::<RobotKind>().0.clone(),
        observation_space: spec.observation_space.clone(),
        action_space: spec.action_space.clone(),
        token: world.get_resource::<ServerToken>().and_then(|t| t.0.clone()),
    }
}

/// Each arena's robot connects to its server, or takes its copy of the on-board policy; its
/// controller's random stream is its arena's.
fn connect_robots(world: &mut World) {
    let address = world.get_resource::<ServerAddress>().copied();
    let tls = world.get_resource::<ServerTlsLink>().cloned();
    let on_board = world.get_resource::<OnBoardPolicy>().cloned();
    let identity = identity(world);
    let arenas: Vec<(Entity, usize, ChaCha8Rng)> =
        world.query::<(Entity, &Arena)>().iter(world).map(|(e, a)| (e, a.index, a.rng.clone())).collect();
    for (entity, index, rng) in arenas {
        let mut state = world.resource_mut::<RobotRunState>();
        let conversation = match (&address, &on_board) {
            (Some(address), _) => {
                Conversation::connect_robot(address, identity.clone(), tls.as_ref(), index, &mut state)
            }
            (None, Some(policy)) => Some(Conversation::over(Box::new(policy.link()))),
            (None, None) => {
                state.stop = Some(Err("a pattern-3 robot needs a ServerAddress or an OnBoardPolicy resource".into()));
                None
            }
        };
        let Some(conversation) = conversation else { return };
        world
            .entity_mut(entity)
            .insert((Controller { conversation, rng, evaluated: false, start_drawn: false }, AtHome(false)));
    }
}

/// A robot that begins homing draws its next episode's start with the task's start events
/// (once per episode), so that its homing can drive to it: what they draw from (a UR5e's
/// reach chains from where the last one arrived) is the state the last episode ended in, as
/// when the Supervisor resets an arena.
fn draw_starts<S: Component<Mutability = Mutable>>(terms: Res<Terms<S>>, mut robots: Query<(&mut Controller, &mut S)>) {
    for (mut controller, mut state) in &mut robots {
        if controller.conversation.phase == Phase::Homing && !controller.start_drawn {
            controller.start_drawn = true;
            terms.0.start(&mut state, &mut controller.rng);
        }
    }
}

/// A robot that is home (or at its drawn start) begins an episode.
fn begin_episodes(mut robots: Query<(&mut Controller, &mut AtHome)>) {
    for (mut controller, mut home) in &mut robots {
        if controller.conversation.phase == Phase::Homing && home.0 {
            home.0 = false;
            controller.start_drawn = false;
            controller.conversation.phase = Phase::Starting;
        }
    }
}

/// One request and reply per robot per step, all requests out before any reply is awaited.
/// The step's outcome comes from the task's terms (into the arena's `Episode`, where the
/// task's reports see it); the action received is applied by the robot's actuation next step,
/// as under the other patterns. Between episodes the robot has no action (its homing drives it).
fn exchange<S: Component>(
    terms: Res<Terms<S>>,
    mut run: ResMut<RobotRunState>,
    mut robots: Query<(&S, &mut Controller, &mut Episode, &mut Action)>,
) {
    if run.stop.is_some() {
        return;
    }
    for (state, mut controller, mut episode, _) in &mut robots {
        let e = &mut *episode;
        let message = match controller.conversation.phase {
            Phase::Homing => continue,
            Phase::Starting => {
                e.begin();
                (e.step.terminated, e.step.truncated) = (false, false);
                terms.0.observe(state, &mut e.observation);
                RobotMessage::Start { obs: e.observation.clone() }
            }
            Phase::Running => {
                terms.0.observe(state, &mut e.observation);
                let outcome = terms.0.evaluate(state, e.running.length, &mut e.running.reward_sums);
                (e.step.reward, e.step.terminated, e.step.truncated, e.step.ended_by) =
                    (outcome.reward, outcome.terminated, outcome.truncated, outcome.ended_by);
                if outcome.success.is_some() {
                    e.running.success = outcome.success;
                }
                controller.evaluated = true;
                RobotMessage::Step {
                    obs: e.observation.clone(),
                    reward: outcome.reward,
                    terminated: outcome.terminated,
                    truncated: outcome.truncated,
                    success: outcome.success,
                    ended_by: outcome.ended_by.map(str::to_string),
                }
            }
        };
        controller.conversation.send(&message, &mut run);
    }
    for (_, mut controller, _, mut action) in &mut robots {
        match controller.conversation.receive(&mut run) {
            Some(a) => action.0 = a,
            None if controller.conversation.phase == Phase::Homing => action.0.clear(),
            None => {}
        }
    }
}

/// Counts each evaluated step into its episode, after the task's reports; an episode that ended
/// is summed up into `Episode::ended` (for that step only, as the in-process patterns'
/// auto-reset does) and the robot is between episodes.
fn tally_steps(spec: Res<ActiveTask>, mut robots: Query<(&mut Controller, &mut Episode)>) {
    for (mut controller, mut e) in &mut robots {
        e.ended = None;
        if !std::mem::take(&mut controller.evaluated) {
            continue;
        }
        e.tally();
        if e.done() {
            let summary = e.running.summary(&spec.reward_terms);
            e.ended = Some(EndedEpisode { final_observation: e.observation.clone(), summary });
            (e.step.terminated, e.step.truncated) = (false, false);
        }
    }
}
