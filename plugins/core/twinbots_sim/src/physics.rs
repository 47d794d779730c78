//! Fixed-step physics: a control step is `substeps` physics steps of `dt` seconds, with motors
//! re-applied before and joint states measured after every physics step.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use bevy::ecs::schedule::{ScheduleLabel, SingleThreadedExecutor};
use bevy::math::Vec3;
use bevy::prelude::*;

use crate::SimSet;
use crate::arena::{Arena, ArenaConfig};

/// Arenas, the order of a control step ([`SimSet`]) and fixed-step physics: `substeps` runs of
/// the [`PhysicsSubstep`] schedule per control step, every arena's world stepped in each.
pub struct PhysicsPlugin {
    pub settings: SimSettings,
}

impl Plugin for PhysicsPlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(self.settings)
            .init_resource::<ArenaConfig>()
            .init_resource::<SimClock>()
            .configure_sets(
                Update,
                (
                    SimSet::Radio,
                    SimSet::ProcessActions,
                    SimSet::Actuate,
                    SimSet::Physics,
                    SimSet::Sense,
                    SimSet::Task,
                    SimSet::Reset,
                )
                    .chain()
                    .run_if(sim_started),
            )
            .add_systems(Update, run_substeps.in_set(SimSet::Physics))
            .add_systems(Last, advance_clock)
            // Run from an exclusive system many times per control step: the single-threaded
            // executor costs least, and the parallelism is inside `integrate_arenas`.
            .edit_schedule(PhysicsSubstep, |substep| {
                substep.set_executor(SingleThreadedExecutor::new());
            })
            .configure_sets(
                PhysicsSubstep,
                (SubstepSet::Actuate, SubstepSet::Integrate, SubstepSet::Measure, SubstepSet::Record).chain(),
            )
            .add_systems(PhysicsSubstep, integrate_arenas.in_set(SubstepSet::Integrate))
            .add_systems(PhysicsSubstep, crate::disturbance::apply_pushes.in_set(SubstepSet::Actuate));
    }
}

/// The fixed timing of the simulation. Never tied to the wall clock.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct SimSettings {
    /// Physics step in seconds.
    pub dt: f32,
    /// Physics steps per control step.
    pub substeps: u32,
    pub gravity: Vec3,
    /// Rapier's solver iterations (substeps) per physics step: more keep long joint chains
    /// (an arm) tighter, at a cost proportional to them.
    pub solver_iterations: usize,
}

impl SimSettings {
    /// Seconds of simulated time per control step.
    pub fn control_dt(&self) -> f32 {
        self.dt * self.substeps as f32
    }

    /// The physics step in seconds as the decimal it was set as (0.004, not 0.004000000189…):
    /// for logs, whose times are f64.
    pub fn dt_seconds(&self) -> f64 {
        to_microseconds(self.dt)
    }

    /// The control step in seconds, as [`SimSettings::dt_seconds`].
    pub fn control_seconds(&self) -> f64 {
        to_microseconds(self.control_dt())
    }
}

impl Default for SimSettings {
    fn default() -> Self {
        Self { dt: 0.004, substeps: 8, gravity: Vec3::new(0.0, 0.0, -9.81), solver_iterations: 4 }
    }
}

/// An f32 duration rounded to whole microseconds, as f64 seconds.
fn to_microseconds(seconds: f32) -> f64 {
    (seconds as f64 * 1e6).round() / 1e6
}

/// Counts control steps. The first `App::update` only builds the world (start-up); every later
/// update is one control step.
#[derive(Resource, Default, Debug)]
pub struct SimClock {
    pub control_steps: u64,
    started: bool,
}

impl SimClock {
    pub fn started(&self) -> bool {
        self.started
    }
}

/// Run condition: true once start-up has built the world.
pub fn sim_started(clock: Res<SimClock>) -> bool {
    clock.started
}

pub(crate) fn advance_clock(mut clock: ResMut<SimClock>) {
    if clock.started {
        clock.control_steps += 1;
    }
    clock.started = true;
}

/// The schedule run `substeps` times per control step.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct PhysicsSubstep;

/// Order inside one physics step.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum SubstepSet {
    /// Motors write their joint motors and torques.
    Actuate,
    /// Rapier advances every arena by `dt`.
    Integrate,
    /// Joint positions and velocities are measured.
    Measure,
    /// Recorders that integrate over physics steps (energy meters) read the measured state.
    Record,
}

pub(crate) fn run_substeps(world: &mut World) {
    let substeps = world.resource::<SimSettings>().substeps;
    // The control step moves every world on, so the devices that are due sample after it.
    for mut arena in world.query::<&mut Arena>().iter_mut(world) {
        arena.unsampled.stepped = true;
    }
    for _ in 0..substeps {
        world.run_schedule(PhysicsSubstep);
    }
}

/// Steps every arena's world by `dt`, side by side on the calling thread and rayon's pool:
/// each world is self-contained (its own bodies, contacts, solver scratch), so neither the
/// order nor the thread an arena steps on changes a bit of its result.
pub(crate) fn integrate_arenas(settings: Res<SimSettings>, mut arenas: Query<&mut Arena>) {
    let settings = *settings;
    side_by_side(arenas.iter_mut(), |mut arena| {
        let world = &mut arena.world;
        world.integration_parameters.dt = settings.dt;
        world.integration_parameters.num_solver_iterations = settings.solver_iterations;
        world.gravity = settings.gravity;
        world.step();
    });
}

/// Runs `f` on every item: the calling thread and up to (threads − 1) physics helpers each take
/// the next item until none is left. The caller works too, rather than handing the whole job to
/// a pool and sleeping as `par_iter` from outside the pool does: on 2 cores that hand-over
/// made 2 arenas step slower than one thread did (measured), while this is faster from 2 up.
/// One item, or one thread, runs inline.
fn side_by_side<T: Send>(items: impl IntoIterator<Item = T>, f: impl Fn(T) + Sync) {
    // The mutexes only hand each item to exactly one thread; none is ever contended.
    let items: Vec<Mutex<Option<T>>> = items.into_iter().map(|item| Mutex::new(Some(item))).collect();
    let next = AtomicUsize::new(0);
    let work = || {
        while let Some(slot) = items.get(next.fetch_add(1, Ordering::Relaxed)) {
            if let Some(item) = slot.lock().ok().and_then(|mut slot| slot.take()) {
                f(item);
            }
        }
    };
    let helpers = rayon::current_num_threads().min(items.len()).saturating_sub(1);
    let Some(pool) = (helpers > 0).then(physics_helpers).flatten() else {
        work();
        return;
    };
    let call = CALLS.fetch_add(1, Ordering::Relaxed) + 1;
    pool.in_place_scope(|scope| {
        for _ in 0..helpers {
            scope.spawn(|_| {
                work();
                // On this helper's own queue: it runs next, once the scope has ended.
                rayon::spawn(move || stay_awake(call));
            });
        }
        work();
    });
}

/// The threads that step arenas beside the caller: (threads − 1) of them, in a pool of their
/// own. With rayon's global pool (as many workers as threads, so one idle beside the caller
/// and a helper), the idle worker woke to look for work and took a core from the two that
/// had it: `bench physics` at 16 arenas 17.6–18.7 k against 21.0–21.2 k arena-steps/s with
/// this pool (2 cores). None when the threads cannot be had: the caller steps every arena.
fn physics_helpers() -> Option<&'static rayon::ThreadPool> {
    static POOL: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    POOL.get_or_init(|| {
        let helpers = rayon::current_num_threads().saturating_sub(1).max(1);
        rayon::ThreadPoolBuilder::new()
            .num_threads(helpers)
            .thread_name(|i| format!("twinbots-physics-{i}"))
            .build()
            .ok()
    })
    .as_ref()
}

/// Counts calls of [`side_by_side`]: a helper staying awake goes back to its pool when the
/// next call begins.
static CALLS: AtomicU64 = AtomicU64::new(0);

/// How long a helper stays awake for the next call before it goes back to rayon, which parks
/// it after a few idle rounds. Waking a parked helper cost each stepping call ≈ 45 µs (8
/// cart-pole arenas, ≈ 630 µs a step, measured through Python, where 60 µs or more pass
/// between steps); the gaps between the physics steps of a control step, and between control
/// steps behind Python or a learner's inference, are well within this.
const STAY_AWAKE: Duration = Duration::from_micros(300);

/// Waits, yielding, until the next call of [`side_by_side`] begins (`call` is over) or
/// [`STAY_AWAKE`] has passed, so the next call finds this helper awake. It yields rather than
/// spins: a busy spin took a core from a learner's inference (the bridge's share of `train
/// cartpole` 0.6 → 1.9 s), a yield gives it way.
fn stay_awake(call: u64) {
    let started = Instant::now();
    while CALLS.load(Ordering::Relaxed) == call && started.elapsed() < STAY_AWAKE {
        std::thread::yield_now();
    }
}
