//! Arenas: independent environment instances, each with its own rapier physics world.
//!
//! Nothing is shared between arenas, so acting in one cannot touch another, and an arena can be
//! put back to exactly its initial state by restoring a snapshot of its world.

use bevy::math::Vec3;
use bevy::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::privilege::SupervisorAccess;
use crate::rapier::prelude::*;

/// Collision group of the environment (ground, walls, objects of the cell).
pub const ENVIRONMENT_GROUP: Group = Group::GROUP_1;
/// Collision group of robot links. Links of a robot do not collide with each other.
pub const ROBOT_GROUP: Group = Group::GROUP_2;

/// How many arenas an app runs, and the seed they start from. Set by the app before start-up.
#[derive(Resource, Clone, Copy, Debug)]
pub struct ArenaConfig {
    pub count: usize,
    pub seed: u64,
    /// The index of the app's first arena: 0, unless the arenas of one run are spread over
    /// several apps (`twinbots robot` runs each robot in an app of its own, so robot k's arena
    /// is index k there, with arena k's random stream).
    pub first: usize,
}

impl Default for ArenaConfig {
    fn default() -> Self {
        Self { count: 1, seed: 0, first: 0 }
    }
}

/// Marks an entity (robot, link, joint, device) as living in the arena entity it names.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct InArena(pub Entity);

/// One environment instance.
#[derive(Component)]
pub struct Arena {
    /// Position among the process's arenas (0-based); the vectorised env's index.
    pub index: usize,
    /// The true state of the arena's world. Private: outside this crate it is reached only
    /// through [`Arena::physics`], which asks for proof of the Supervisor's privilege, so a
    /// design-pattern-3 app (which grants none) has no way to it but the simulator's own
    /// devices and the lab operator's narrow hands.
    pub(crate) world: PhysicsWorld,
    /// The arena's random stream: a function of (seed, index) only.
    pub rng: ChaCha8Rng,
    /// The seed `rng` started from (the latest [`Arena::reseed`]), and how many reseeds so far.
    seed: u64,
    reseeds: u64,
    initial: Option<Snapshot>,
    /// How the world changed since its devices last sampled (see `devices::DeviceSampling`).
    pub(crate) unsampled: WorldChanges,
}

/// What happened to an arena's world since its devices last sampled.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct WorldChanges {
    /// A control step moved it on (`SimSet::Physics`): devices that are due sample.
    pub stepped: bool,
    /// A snapshot restored it (an episode reset): every device samples, whatever its period,
    /// and nothing differentiates across the jump.
    pub restored: bool,
}

/// Everything of a physics world that evolves; the pipeline and CCD solver are scratch space.
#[derive(Clone)]
struct Snapshot {
    islands: IslandManager,
    broad_phase: BroadPhaseBvh,
    narrow_phase: NarrowPhase,
    bodies: RigidBodySet,
    colliders: ColliderSet,
    impulse_joints: ImpulseJointSet,
    multibody_joints: MultibodyJointSet,
}

impl Arena {
    /// An empty arena with Z-up gravity (URDF and Webots convention).
    pub fn new(index: usize, seed: u64, dt: f32, gravity: Vec3) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = gravity;
        world.integration_parameters.dt = dt;
        Self {
            index,
            world,
            rng: arena_rng(seed, index),
            seed,
            reseeds: 0,
            initial: None,
            unsampled: WorldChanges::default(),
        }
    }

    /// The physics world, for a holder of the Supervisor's privilege (a system's
    /// `Res<SupervisorAccess>`; in exclusive code [`physics_in`]).
    pub fn physics(&self, _privilege: &SupervisorAccess) -> &PhysicsWorld {
        &self.world
    }

    /// The physics world, mutably (see [`Arena::physics`]).
    pub fn physics_mut(&mut self, _privilege: &SupervisorAccess) -> &mut PhysicsWorld {
        &mut self.world
    }

    /// A flat ground whose top face is the plane z = 0.
    pub fn add_ground(&mut self, friction: f32) -> ColliderHandle {
        // A half-space rather than a thin box: no edges for wheels to catch on.
        self.world.colliders.insert(
            ColliderBuilder::halfspace(crate::rapier::na::Unit::new_unchecked(Vec3::Z))
                .friction(friction)
                .collision_groups(InteractionGroups::new(ENVIRONMENT_GROUP, Group::ALL, InteractionTestMode::And)),
        )
    }

    /// A fixed box of the cell (ground, wall, table), by half extents and centre.
    pub fn add_static_box(&mut self, half_extents: Vec3, centre: Vec3, friction: f32) -> ColliderHandle {
        self.world.colliders.insert(
            ColliderBuilder::cuboid(half_extents.x, half_extents.y, half_extents.z)
                .translation(centre)
                .friction(friction)
                .collision_groups(InteractionGroups::new(ENVIRONMENT_GROUP, Group::ALL, InteractionTestMode::And)),
        )
    }

    /// The fixed boxes of the cell (tables, walls: parentless cuboids) as (half extents, pose),
    /// in the world's collider order: what the renderer draws and `Look` names `static/<i>`.
    pub fn static_boxes(&self) -> impl Iterator<Item = (Vec3, crate::rapier::math::Pose)> + '_ {
        self.world
            .colliders
            .iter()
            .filter(|(_, c)| c.parent().is_none() && c.shape().shape_type() == ShapeType::Cuboid)
            .filter_map(|(_, c)| c.shape().as_cuboid().map(|b| (b.half_extents, *c.position())))
    }

    /// Records the current world as the state [`Arena::restore_initial`] returns to.
    pub fn mark_initial(&mut self) {
        let w = &self.world;
        self.initial = Some(Snapshot {
            islands: w.islands.clone(),
            broad_phase: w.broad_phase.clone(),
            narrow_phase: w.narrow_phase.clone(),
            bodies: w.bodies.clone(),
            colliders: w.colliders.clone(),
            impulse_joints: w.impulse_joints.clone(),
            multibody_joints: w.multibody_joints.clone(),
        });
    }

    /// Puts the world back to the state recorded by [`Arena::mark_initial`], bit for bit: a
    /// teleport of everything, so the Supervisor's privilege. Returns false when no initial
    /// state was recorded.
    pub fn restore_initial(&mut self, _privilege: &SupervisorAccess) -> bool {
        let Some(s) = self.initial.clone() else {
            return false;
        };
        let w = &mut self.world;
        w.islands = s.islands;
        w.broad_phase = s.broad_phase;
        w.narrow_phase = s.narrow_phase;
        w.bodies = s.bodies;
        w.colliders = s.colliders;
        w.impulse_joints = s.impulse_joints;
        w.multibody_joints = s.multibody_joints;
        w.physics_pipeline = PhysicsPipeline::new();
        w.ccd_solver = CCDSolver::new();
        self.unsampled.restored = true;
        true
    }

    /// Restarts the arena's random stream from a new seed.
    pub fn reseed(&mut self, seed: u64) {
        self.rng = arena_rng(seed, self.index);
        self.seed = seed;
        self.reseeds += 1;
    }

    /// Restarts the arena's random stream as arena number `stream`'s would start from `seed`:
    /// runs that must begin alike whatever arena they occupy (a study's tests) share a stream.
    pub fn reseed_as(&mut self, seed: u64, stream: usize) {
        self.rng = arena_rng(seed, stream);
        self.seed = seed;
        self.reseeds += 1;
    }

    /// How many times the arena was re-seeded: side streams restart when it changes.
    pub fn reseeds(&self) -> u64 {
        self.reseeds
    }

    /// A random stream of this arena apart from its physics stream ([`Arena::rng`]), from the
    /// same seed, for draws that must not shift the physics when switched on (visual
    /// randomization): `salt` names it.
    pub fn side_stream(&self, salt: u64) -> ChaCha8Rng {
        arena_rng(self.seed ^ salt, self.index)
    }

    /// FNV-1a over the bits of every body's pose and velocity, in handle order.
    pub fn state_hash(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for (_, body) in self.world.bodies.iter() {
            let p = body.position();
            let (t, r, v, w) = (p.translation, p.rotation, body.linvel(), body.angvel());
            for x in [t.x, t.y, t.z, r.x, r.y, r.z, r.w, v.x, v.y, v.z, w.x, w.y, w.z] {
                for b in x.to_bits().to_le_bytes() {
                    h ^= b as u64;
                    h = h.wrapping_mul(0x100_0000_01b3);
                }
            }
        }
        h
    }
}

fn arena_rng(seed: u64, index: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index as u64);
    rng
}

/// The physics world of `arena` in an app that grants the Supervisor (exclusive code: tools,
/// tests, start-up); `None` without that privilege or for an entity that is no arena.
pub fn physics_in(world: &World, arena: Entity) -> Option<&PhysicsWorld> {
    let privilege = world.get_resource::<SupervisorAccess>()?;
    Some(world.get::<Arena>(arena)?.physics(privilege))
}

/// [`physics_in`], mutably.
pub fn physics_in_mut(world: &mut World, arena: Entity) -> Option<Mut<'_, PhysicsWorld>> {
    world.get_resource::<SupervisorAccess>()?;
    Some(world.get_mut::<Arena>(arena)?.map_unchanged(|a| &mut a.world))
}
