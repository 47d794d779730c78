//! Mirroring an arena of the sim app into the render app: a mesh entity per link visual and per
//! static box, posed from the physics world. Physics is Z up (URDF); Bevy is Y up, so every pose
//! is turned by −90° about X on the way in.

use std::collections::HashMap;
use std::f32::consts::FRAC_PI_2;

use bevy::asset::RenderAssetUsages;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::rapier::prelude::ShapeType;
use twinbots_sim::urdf::{Shape, Visual};
use twinbots_sim::{Arena, InArena, Link, Visuals};

use crate::shading::LambertMaterial;

/// The rotation taking Z-up physics coordinates to Bevy's Y-up.
pub fn z_up_to_y_up() -> Quat {
    Quat::from_rotation_x(-FRAC_PI_2)
}

/// A physics pose as a Bevy transform.
pub fn to_bevy(pose: Pose) -> Transform {
    let r = z_up_to_y_up();
    Transform { translation: r * pose.translation, rotation: r * pose.rotation, scale: Vec3::ONE }
}

/// A physics point in Bevy coordinates.
pub fn point_to_bevy(p: Vec3) -> Vec3 {
    z_up_to_y_up() * p
}

/// Render entities of the mirrored arena, by (sim link entity, visual index).
#[derive(Resource, Default)]
pub struct Mirror {
    pub links: HashMap<(Entity, usize), Entity>,
    pub statics: Vec<Entity>,
    pub arena: Option<Entity>,
}

/// What the render world needs to know about one visual, read from the sim world.
pub struct VisualPose {
    pub key: (Entity, usize),
    pub visual: Visual,
    pub pose: Pose,
}

/// Poses of every link visual in `arena`, in physics coordinates.
pub fn read_visuals(sim: &mut World, arena: Entity) -> Vec<VisualPose> {
    // Link data first (the query borrows the world mutably), then the arena's bodies.
    let mut links = sim.query::<(Entity, &Link, &Visuals, &InArena)>();
    let items: Vec<(Entity, Link, Vec<Visual>)> = links
        .iter(sim)
        .filter(|(_, _, _, a)| a.0 == arena)
        .map(|(e, l, v, _)| (e, l.clone(), v.0.clone()))
        .collect();
    let Some(arena) = sim.get::<Arena>(arena) else { return Vec::new() };
    let mut out = Vec::new();
    for (entity, link, visuals) in items {
        let Some(body) = arena.world.bodies.get(link.body) else { continue };
        let link_pose = *body.position() * link.offset;
        for (i, visual) in visuals.into_iter().enumerate() {
            let pose = link_pose * visual.geometry.origin;
            out.push(VisualPose { key: (entity, i), visual, pose });
        }
    }
    out
}

/// Static boxes of the arena (walls, tables) as (half extents, pose).
pub fn read_static_boxes(sim: &World, arena: Entity) -> Vec<(Vec3, Pose)> {
    let Some(arena) = sim.get::<Arena>(arena) else { return Vec::new() };
    arena
        .world
        .colliders
        .iter()
        .filter(|(_, c)| c.parent().is_none() && c.shape().shape_type() == ShapeType::Cuboid)
        .filter_map(|(_, c)| c.shape().as_cuboid().map(|b| (b.half_extents, *c.position())))
        .collect()
}

/// A Bevy mesh for a URDF shape. Cylinders are turned so their axis is the visual's Z.
pub fn mesh_for(shape: &Shape) -> (Mesh, Transform) {
    match shape {
        Shape::Box { half_extents: h } => (Cuboid::new(2.0 * h.x, 2.0 * h.y, 2.0 * h.z).into(), Transform::IDENTITY),
        Shape::Cylinder { radius, length } => (
            Cylinder::new(*radius, *length).into(),
            Transform::from_rotation(Quat::from_rotation_x(FRAC_PI_2)),
        ),
        Shape::Sphere { radius } => (Sphere::new(*radius).mesh().uv(32, 18), Transform::IDENTITY),
        Shape::Mesh(m) => {
            let positions: Vec<[f32; 3]> = m.vertices.iter().map(|v| v.to_array()).collect();
            let indices: Vec<u32> = m.triangles.iter().flatten().copied().collect();
            let mut mesh = Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
                .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
                .with_inserted_indices(Indices::U32(indices));
            mesh.duplicate_vertices();
            (mesh.with_computed_flat_normals(), Transform::IDENTITY)
        }
    }
}

/// Creates (once) and poses, in `render`, the entities of `arena` of the `sim` world: a mesh
/// per link visual and per static box. Returns whether new meshes were made.
pub fn sync_into(render: &mut World, sim: &mut World, arena: Entity) -> bool {
    let visuals = read_visuals(sim, arena);
    let boxes = read_static_boxes(sim, arena);
    if !render.contains_resource::<Mirror>() {
        render.init_resource::<Mirror>();
    }
    let mut fresh = false;
    if render.resource::<Mirror>().arena != Some(arena) {
        let old: Vec<Entity> = {
            let m = render.resource::<Mirror>();
            m.links.values().chain(m.statics.iter()).copied().collect()
        };
        for e in old {
            render.despawn(e);
        }
        let mut mirror = Mirror { arena: Some(arena), ..default() };
        for (half, pose) in boxes {
            let mesh = render.resource_mut::<Assets<Mesh>>().add(Cuboid::new(2.0 * half.x, 2.0 * half.y, 2.0 * half.z));
            let mat = render.resource_mut::<Assets<LambertMaterial>>().add(LambertMaterial::new(Color::srgb(0.6, 0.55, 0.5)));
            mirror.statics.push(render.spawn((Mesh3d(mesh), MeshMaterial3d(mat), to_bevy(pose))).id());
        }
        render.insert_resource(mirror);
        fresh = true;
    }
    // Links that left the sim (despawned) leave the picture too.
    let live: std::collections::HashSet<(Entity, usize)> = visuals.iter().map(|v| v.key).collect();
    let gone: Vec<((Entity, usize), Entity)> = render
        .resource::<Mirror>()
        .links
        .iter()
        .filter(|(k, _)| !live.contains(k))
        .map(|(k, e)| (*k, *e))
        .collect();
    for (key, entity) in gone {
        render.resource_mut::<Mirror>().links.remove(&key);
        render.entity_mut(entity).despawn();
    }
    for v in visuals {
        let existing = render.resource::<Mirror>().links.get(&v.key).copied();
        let entity = match existing {
            Some(e) => e,
            None => {
                let (mesh, local) = mesh_for(&v.visual.geometry.shape);
                let mesh = render.resource_mut::<Assets<Mesh>>().add(mesh);
                let [r, g, b, a] = v.visual.rgba;
                let mat = render.resource_mut::<Assets<LambertMaterial>>().add(LambertMaterial::new(Color::srgba(r, g, b, a)));
                let parent = render.spawn((Transform::default(), Visibility::default())).id();
                render.spawn((Mesh3d(mesh), MeshMaterial3d(mat), local, ChildOf(parent)));
                render.resource_mut::<Mirror>().links.insert(v.key, parent);
                fresh = true;
                parent
            }
        };
        if let Some(mut t) = render.get_mut::<Transform>(entity) {
            *t = to_bevy(v.pose);
        }
    }
    fresh
}
