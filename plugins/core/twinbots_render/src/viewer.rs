//! Visual mode: a window showing arena 0 live, with an orbit camera (drag with the left mouse
//! button, scroll to zoom) and keys: Space pauses, N single-steps while paused, R resets,
//! Esc quits. The simulation itself stays in its own app; the viewer advances it through a
//! [`ViewSource`] and mirrors arena 0 every frame.

use std::time::{Duration, Instant};

use bevy::input::mouse::{AccumulatedMouseMotion, AccumulatedMouseScroll};
use bevy::prelude::*;

use crate::scene;
use crate::shading::ShadingPlugin;

/// What the viewer shows and drives.
pub trait ViewSource: 'static {
    /// Advances the simulation for at most `budget` of wall time (a real-time player steps to
    /// keep up with the clock; a trainer steps as much as the budget allows). Returns false
    /// when the source is finished and the window should close.
    fn advance(&mut self, budget: Duration, paused: bool, single_step: bool) -> bool;
    fn reset(&mut self);
    fn sim_world(&mut self) -> &mut World;
    /// The arena shown.
    fn arena(&self) -> Entity;
    /// A line for the window title.
    fn status(&self) -> String;
}

struct Source(Box<dyn ViewSource>);

#[derive(Resource, Default)]
struct Controls {
    paused: bool,
    single_step: bool,
    reset: bool,
}

#[derive(Component)]
struct Orbit {
    yaw: f32,
    pitch: f32,
    distance: f32,
    target: Vec3,
}

/// Opens the window and runs until it is closed, Esc is pressed, or the source finishes.
pub fn run(source: Box<dyn ViewSource>, title: &str, framing: crate::Framing) -> anyhow::Result<()> {
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        anyhow::bail!(
            "visual mode needs a display (DISPLAY is not set); for frames without one use `twinbots capture`"
        );
    }
    let mut app = App::new();
    app.add_plugins(DefaultPlugins.set(WindowPlugin {
        primary_window: Some(Window { title: title.into(), resolution: (1024u32, 720u32).into(), ..default() }),
        ..default()
    }))
    .add_plugins(ShadingPlugin)
    .insert_non_send(Source(source))
    .insert_resource(ClearColor(Color::srgb(0.78, 0.84, 0.9)))
    .init_resource::<Controls>()
    .insert_resource(InitialFraming(framing))
    .add_systems(Startup, setup)
    .add_systems(Update, (keys, advance_and_mirror, orbit_camera).chain());
    app.run();
    Ok(())
}

/// Where the orbit camera starts.
#[derive(Resource)]
struct InitialFraming(crate::Framing);

fn setup(mut commands: Commands, framing: Res<InitialFraming>) {
    let framing = framing.0;
    commands.spawn((
        Camera3d::default(),
        Transform::default(),
        Orbit {
            yaw: -0.3,
            pitch: 0.25,
            distance: framing.distance * 1.15,
            target: scene::point_to_bevy(framing.target),
        },
    ));
}

fn keys(input: Res<ButtonInput<KeyCode>>, mut controls: ResMut<Controls>, mut exit: MessageWriter<AppExit>) {
    if input.just_pressed(KeyCode::Space) {
        controls.paused = !controls.paused;
    }
    if input.just_pressed(KeyCode::KeyN) {
        controls.single_step = true;
    }
    if input.just_pressed(KeyCode::KeyR) {
        controls.reset = true;
    }
    if input.just_pressed(KeyCode::Escape) {
        exit.write(AppExit::Success);
    }
}

fn advance_and_mirror(world: &mut World) {
    let Some(mut source) = world.remove_non_send::<Source>() else { return };
    let (paused, single_step, reset) = {
        let mut c = world.resource_mut::<Controls>();
        let out = (c.paused, c.single_step, c.reset);
        c.single_step = false;
        c.reset = false;
        out
    };
    if reset {
        source.0.reset();
    }
    let running = source.0.advance(Duration::from_millis(25), paused, single_step);
    let arena = source.0.arena();
    if let Err(e) = scene::sync_into(world, source.0.sim_world(), arena) {
        error!("{e}");
    }
    let cameras: Vec<Entity> = world.query_filtered::<Entity, With<Orbit>>().iter(world).collect();
    for camera in cameras {
        scene::watch(world, camera, arena);
    }
    let title = format!("twinbots — {}{}", source.0.status(), if paused { " — paused (Space)" } else { "" });
    let mut windows = world.query::<&mut Window>();
    for mut w in windows.iter_mut(world) {
        if w.title != title {
            w.title = title.clone();
        }
    }
    world.insert_non_send(source);
    if !running {
        world.write_message(AppExit::Success);
    }
}

fn orbit_camera(
    buttons: Res<ButtonInput<MouseButton>>,
    motion: Res<AccumulatedMouseMotion>,
    scroll: Res<AccumulatedMouseScroll>,
    mut cameras: Query<(&mut Transform, &mut Orbit)>,
) {
    for (mut t, mut o) in &mut cameras {
        if buttons.pressed(MouseButton::Left) {
            o.yaw -= motion.delta.x * 0.005;
            o.pitch = (o.pitch + motion.delta.y * 0.005).clamp(-1.4, 1.4);
        }
        o.distance = (o.distance * (1.0 - scroll.delta.y * 0.1)).clamp(0.3, 30.0);
        let rotation = Quat::from_euler(EulerRot::YXZ, o.yaw, -o.pitch, 0.0);
        t.translation = o.target + rotation * Vec3::new(0.0, 0.0, o.distance);
        t.look_at(o.target, Vec3::Y);
    }
}

/// A real-time player: steps so that simulated time keeps pace with the wall clock.
pub struct RealTime {
    pub control_dt: f32,
    started: Option<Instant>,
    simulated: f64,
}

impl RealTime {
    pub fn new(control_dt: f32) -> Self {
        Self { control_dt, started: None, simulated: 0.0 }
    }

    /// How many steps to take now to catch up (at most `max`).
    pub fn steps_due(&mut self, paused: bool, max: usize) -> usize {
        let now = Instant::now();
        let started = *self.started.get_or_insert(now);
        let wall = now.duration_since(started).as_secs_f64();
        if paused {
            // Time stands still while paused.
            self.started = Some(now - Duration::from_secs_f64(self.simulated));
            return 0;
        }
        let mut n = 0;
        while self.simulated + (self.control_dt as f64) <= wall && n < max {
            self.simulated += self.control_dt as f64;
            n += 1;
        }
        if n == max {
            self.simulated = wall; // too slow to keep up: do not build a backlog
        }
        n
    }
}

/// `train --view`: the bridged training app, advanced in time slices between frames so that
/// every arena keeps training as fast as the window allows; arena 0 is shown.
pub struct TrainingView {
    app: App,
    arena: Entity,
    frames: u64,
    updates: u64,
    started: Instant,
    /// When the last slice ended: the gap until the next is what drawing a frame cost.
    last_slice_end: Option<Instant>,
}

impl ViewSource for TrainingView {
    fn advance(&mut self, budget: Duration, paused: bool, single_step: bool) -> bool {
        self.frames += 1;
        // Train at least 3× as long as a frame takes to draw: ≥ 75 % of the time trains,
        // whether frames come from a GPU (fast) or a software renderer (slow).
        let drawing = self.last_slice_end.map_or(Duration::ZERO, |t| t.elapsed());
        let until = Instant::now() + budget.max(drawing * 3);
        let result = self.slice(until, paused, single_step);
        self.last_slice_end = Some(Instant::now());
        result
    }
    fn reset(&mut self) {}
    fn sim_world(&mut self) -> &mut World {
        self.app.world_mut()
    }
    fn arena(&self) -> Entity {
        self.arena
    }
    fn status(&self) -> String {
        let secs = self.started.elapsed().as_secs_f64();
        format!("training — {} frames shown, {:.0} app updates/s", self.frames, self.updates as f64 / secs)
    }
}

impl TrainingView {
    /// The training `app`, showing `arena`.
    pub fn new(app: App, arena: Entity) -> Self {
        Self { app, arena, frames: 0, updates: 0, started: Instant::now(), last_slice_end: None }
    }

    fn slice(&mut self, until: Instant, paused: bool, single_step: bool) -> bool {
        loop {
            if paused && !single_step {
                return true;
            }
            self.app.update();
            self.updates += 1;
            let closed =
                self.app.world().get_resource::<twinbots_task::bridge::BridgeEndpoint>().is_none_or(|e| e.closed);
            if closed {
                return false;
            }
            if paused || Instant::now() >= until {
                return true;
            }
        }
    }
}
