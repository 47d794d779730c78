//! Mirroring an arena of the sim app into the render app: a mesh entity per link visual and per
//! static box, posed from the physics world. Physics is Z up (URDF); Bevy is Y up, so every pose
//! is turned by −90° about X on the way in. The arena's [`Look`] (lights, surface colours and
//! textures) is applied here too; meshes carry UVs in metres so patterns keep their scale.

use std::collections::{HashMap, HashSet};
use std::f32::consts::FRAC_PI_2;
use std::path::{Path, PathBuf};

use bevy::asset::RenderAssetUsages;
use bevy::camera::visibility::{NoFrustumCulling, RenderLayers};
use bevy::image::{ImageAddressMode, ImageSampler, ImageSamplerDescriptor};
use bevy::light::{AmbientLight, CascadeShadowConfigBuilder};
use bevy::mesh::MeshTag;
use bevy::mesh::{Indices, PrimitiveTopology, VertexAttributeValues};
use bevy::prelude::*;
use bevy::render::render_resource::{Extent3d, TextureDimension, TextureFormat};
use twinbots_sim::look::{Surface, Texture};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::{Shape, Visual};
use twinbots_sim::{Arena, InArena, Link, Look, Marker, Visuals};

use crate::RenderError;
use crate::batch::{self, Batch};
use crate::shading::{LambertMaterial, SurfaceRecord};

/// The ground plane's colour (sRGB).
pub const GROUND_COLOR: [f32; 3] = [0.45, 0.47, 0.45];

pub use crate::coords::{point_to_bevy, to_bevy, z_up_to_y_up};

/// Whether the lights of the render world cast shadows (`capture --shadows`): each light
/// renders a shadow map, and surfaces sample it. Off by default: on Mesa's CPU renderer a shadow
/// map costs about as much as the frame.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct Shadows(pub bool);

/// The mirrored arenas of a render world. Each arena's entities (and its lights) are on a
/// render layer of their own, so a camera sees one arena by taking its layer: switching arenas
/// costs nothing, and several cameras can draw several arenas in one frame.
///
/// Where the render world has a [`Batch`] (batched frames), surfaces are instances: each
/// carries a `MeshTag` naming its `SurfaceRecord`, every instance of one shape shares its mesh,
/// no Bevy lights are spawned (the `ArenaView` lights), and the frame-wide camera's frustum
/// never culls.
#[derive(Resource, Default)]
pub struct Mirror {
    arenas: HashMap<Entity, ArenaMirror>,
    images: HashMap<PathBuf, Handle<Image>>,
    /// Meshes by shape, shared by the arenas.
    meshes: HashMap<String, Handle<Mesh>>,
    /// The imported meshes keyed by their address above, kept alive so no other takes it.
    kept: Vec<Shape>,
}

/// One mirrored arena: its render entities by (sim link entity, visual index), and how its
/// surfaces and lights look.
struct ArenaMirror {
    layer: usize,
    links: HashMap<(Entity, usize), Entity>,
    /// Every surface's entity and own colour (sRGB), by its `Look` name.
    surfaces: HashMap<String, (Entity, [f32; 3])>,
    /// The look shown; `None` until the first is.
    look: Option<Look>,
    lights: Vec<Entity>,
    distractors: Vec<Entity>,
}

impl Mirror {
    /// The look `arena` is shown in (after its first sync).
    pub fn look(&self, arena: Entity) -> Option<&Look> {
        self.arenas.get(&arena).and_then(|m| m.look.as_ref())
    }

    /// `arena`'s render layer: also its index among batched `ArenaView`s.
    pub fn layer(&self, arena: Entity) -> Option<usize> {
        self.arenas.get(&arena).map(|m| m.layer)
    }

    /// The highest layer in use (0: none).
    pub fn max_layer(&self) -> usize {
        self.arenas.len()
    }
}

/// Points `camera` at a mirrored arena: its render layer and its ambient light.
pub fn watch(render: &mut World, camera: Entity, arena: Entity) {
    let Some(m) = render.resource::<Mirror>().arenas.get(&arena) else { return };
    let layer = RenderLayers::layer(m.layer);
    let [r, g, b] = m.look.as_ref().map_or(Look::default().ambient, |l| l.ambient);
    let ambient = AmbientLight { color: Color::linear_rgb(r, g, b), brightness: 1.0, ..default() };
    let mut e = render.entity_mut(camera);
    if e.get::<RenderLayers>() != Some(&layer) {
        e.insert(layer);
    }
    if e.get::<AmbientLight>().is_none_or(|a| a.color != ambient.color) {
        e.insert(ambient);
    }
}

/// What the render world needs to know about one visual, read from the sim world.
pub struct VisualPose {
    pub key: (Entity, usize),
    /// Its `Look` surface name.
    pub surface: String,
    pub visual: Visual,
    pub pose: Pose,
}

/// Poses of every link visual and [`Marker`] in `arena`, in physics coordinates.
pub fn read_visuals(sim: &mut World, arena: Entity) -> Vec<VisualPose> {
    // Link data first (the query borrows the world mutably), then the arena's bodies.
    let mut links = sim.query::<(Entity, &Link, &Visuals, &InArena)>();
    let items: Vec<(Entity, Link, Vec<Visual>)> =
        links.iter(sim).filter(|(_, _, _, a)| a.0 == arena).map(|(e, l, v, _)| (e, l.clone(), v.0.clone())).collect();
    let names: HashMap<Entity, String> =
        Look::link_names(items.iter().map(|(e, l, _)| (*e, l.name.as_str()))).into_iter().collect();
    // The twin's view shows the true world: read as the Supervisor would (`sync_into` refuses
    // an app without its privilege).
    let Some(world) = twinbots_sim::physics_in(sim, arena) else { return Vec::new() };
    let mut out = Vec::new();
    for (entity, link, visuals) in items {
        let name = &names[&entity];
        let Some(body) = world.bodies.get(link.body) else { continue };
        let link_pose = *body.position() * link.offset;
        for (i, visual) in visuals.into_iter().enumerate() {
            let pose = link_pose * visual.geometry.origin;
            out.push(VisualPose { key: (entity, i), surface: Look::link_surface(name, i), visual, pose });
        }
    }
    let mut markers = sim.query::<(Entity, &Marker, &InArena)>();
    for (entity, marker, _) in markers.iter(sim).filter(|(_, _, a)| a.0 == arena) {
        let pose = marker.pose * marker.visual.geometry.origin;
        out.push(VisualPose {
            key: (entity, 0),
            surface: Look::marker_surface(&marker.name),
            visual: marker.visual.clone(),
            pose,
        });
    }
    out
}

/// Where a shape's mesh ([`mesh_for`]) sits in its visual: cylinders are turned so their axis
/// is the visual's Z.
pub fn shape_transform(shape: &Shape) -> Transform {
    match shape {
        Shape::Cylinder { .. } => Transform::from_rotation(Quat::from_rotation_x(FRAC_PI_2)),
        _ => Transform::IDENTITY,
    }
}

/// A Bevy mesh for a URDF shape, with UVs in metres, and where it sits ([`shape_transform`]).
pub fn mesh_for(shape: &Shape) -> (Mesh, Transform) {
    let local = shape_transform(shape);
    let mesh = match shape {
        Shape::Box { half_extents: h } => Cuboid::new(2.0 * h.x, 2.0 * h.y, 2.0 * h.z).into(),
        Shape::Cylinder { radius, length } => Cylinder::new(*radius, *length).into(),
        Shape::Sphere { radius } => Sphere::new(*radius).mesh().uv(32, 18),
        Shape::Mesh(m) => {
            let positions: Vec<[f32; 3]> = m.vertices.iter().map(|v| v.to_array()).collect();
            let indices: Vec<u32> = m.triangles.iter().flatten().copied().collect();
            let mut mesh = Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
                .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
                .with_inserted_indices(Indices::U32(indices));
            mesh.duplicate_vertices();
            mesh.with_computed_flat_normals()
        }
    };
    (metric_uvs(mesh), local)
}

/// A box of `half` extents, UVs in metres (static boxes, distractors).
fn box_mesh(half: Vec3) -> Mesh {
    mesh_for(&Shape::Box { half_extents: half }).0
}

/// Replaces a mesh's UVs by box projection in metres: each vertex takes the two coordinates of
/// its position across its normal's main axis. Patterns then have the same scale on every
/// surface (a primitive's own UVs stretch one image over any size).
pub fn metric_uvs(mut mesh: Mesh) -> Mesh {
    let (Some(VertexAttributeValues::Float32x3(positions)), Some(VertexAttributeValues::Float32x3(normals))) =
        (mesh.attribute(Mesh::ATTRIBUTE_POSITION), mesh.attribute(Mesh::ATTRIBUTE_NORMAL))
    else {
        return mesh;
    };
    let uvs: Vec<[f32; 2]> = positions
        .iter()
        .zip(normals)
        .map(|(p, n)| {
            let a = n.map(f32::abs);
            if a[0] >= a[1] && a[0] >= a[2] {
                [p[1], p[2]]
            } else if a[1] >= a[2] {
                [p[0], p[2]]
            } else {
                [p[0], p[1]]
            }
        })
        .collect();
    mesh.insert_attribute(Mesh::ATTRIBUTE_UV_0, uvs);
    mesh
}

/// Creates (once) and poses, in `render`, the entities of `arena` of the `sim` world on the
/// arena's render layer: the floor, a mesh per link visual and per static box; shows the
/// arena's [`Look`] (the default look when it has none). Returns whether new meshes were made;
/// an image texture that cannot be read is an error. A camera sees it after [`watch`].
pub fn sync_into(render: &mut World, sim: &mut World, arena: Entity) -> Result<bool, RenderError> {
    if !sim.contains_resource::<twinbots_sim::SupervisorAccess>() {
        // A design-pattern-3 app: its true world is not to be read, drawn included.
        return Err(RenderError::Failed("the twin's view reads the true world, which this app does not grant (no SupervisorAccess: design pattern 3)".into()));
    }
    let visuals = read_visuals(sim, arena);
    let look = sim.get::<Look>(arena).cloned().unwrap_or_default();
    if !render.contains_resource::<Mirror>() {
        render.init_resource::<Mirror>();
    }
    let mut fresh = false;
    if !render.resource::<Mirror>().arenas.contains_key(&arena) {
        let boxes: Vec<(Vec3, Pose)> = sim.get::<Arena>(arena).map(|a| a.static_boxes().collect()).unwrap_or_default();
        // Layer 0 is every camera's default: arenas start at 1.
        let layer = render.resource::<Mirror>().arenas.len() + 1;
        let mirror = ArenaMirror {
            layer,
            links: HashMap::new(),
            surfaces: HashMap::new(),
            look: None,
            lights: Vec::new(),
            distractors: Vec::new(),
        };
        render.resource_mut::<Mirror>().arenas.insert(arena, mirror);
        // The ground: a large plane at physics z = 0.
        let ground =
            shared_mesh(render, "ground".into(), || metric_uvs(Plane3d::default().mesh().size(40.0, 40.0).into()));
        spawn_surface(render, arena, "floor".into(), ground, GROUND_COLOR, Transform::IDENTITY, None);
        for (i, (half, pose)) in boxes.into_iter().enumerate() {
            let mesh = shared_mesh(render, format!("box {half}"), || box_mesh(half));
            spawn_surface(render, arena, Look::static_surface(i), mesh, [0.6, 0.55, 0.5], to_bevy(pose), None);
        }
        fresh = true;
    }
    let layer = RenderLayers::layer(render.resource::<Mirror>().arenas[&arena].layer);
    // Links that left the sim (despawned) leave the picture too.
    let live: HashSet<(Entity, usize)> = visuals.iter().map(|v| v.key).collect();
    let gone: Vec<(Entity, usize)> =
        render.resource::<Mirror>().arenas[&arena].links.keys().filter(|k| !live.contains(k)).copied().collect();
    for key in gone {
        let entity = arena_mut(render, arena).links.remove(&key);
        if let Some(e) = entity {
            let surfaces: Vec<Entity> = render.get::<Children>(e).map(|c| c.to_vec()).unwrap_or_default();
            for surface in surfaces {
                despawn_surface(render, surface);
            }
            render.entity_mut(e).despawn();
        }
    }
    for v in visuals {
        let existing = render.resource::<Mirror>().arenas[&arena].links.get(&v.key).copied();
        let entity = match existing {
            Some(e) => e,
            None => {
                let shape = &v.visual.geometry.shape;
                let local = shape_transform(shape);
                let key = match shape {
                    Shape::Mesh(m) => format!("mesh {:p}", std::sync::Arc::as_ptr(m)),
                    primitive => format!("{primitive:?}"),
                };
                let mut mirror = render.resource_mut::<Mirror>();
                if matches!(shape, Shape::Mesh(_)) && !mirror.meshes.contains_key(&key) {
                    mirror.kept.push(shape.clone());
                }
                let mesh = shared_mesh(render, key, || mesh_for(shape).0);
                let [r, g, b, _] = v.visual.rgba;
                let parent = render.spawn((Transform::default(), Visibility::default(), layer.clone())).id();
                spawn_surface(render, arena, v.surface, mesh, [r, g, b], local, Some(parent));
                arena_mut(render, arena).links.insert(v.key, parent);
                fresh = true;
                parent
            }
        };
        if let Some(mut t) = render.get_mut::<Transform>(entity) {
            *t = to_bevy(v.pose);
        }
    }
    if fresh || render.resource::<Mirror>().look(arena) != Some(&look) {
        show(render, arena, &look)?;
    }
    Ok(fresh)
}

fn arena_mut(render: &mut World, arena: Entity) -> Mut<'_, ArenaMirror> {
    render.resource_mut::<Mirror>().map_unchanged(|m| m.arenas.get_mut(&arena).expect("a mirrored arena"))
}

/// A mesh entity of `arena`, registered as the surface `name` (`show` dresses it).
fn spawn_surface(
    render: &mut World,
    arena: Entity,
    name: String,
    mesh: Handle<Mesh>,
    srgb: [f32; 3],
    local: Transform,
    parent: Option<Entity>,
) -> Entity {
    let layer = render.resource::<Mirror>().arenas[&arena].layer;
    let id = spawn_mesh(render, mesh, local, layer);
    if let Some(p) = parent {
        render.entity_mut(id).insert(ChildOf(p));
    }
    arena_mut(render, arena).surfaces.insert(name, (id, srgb));
    id
}

/// The mesh made by `make`, shared by every surface of the same `key` (its shape).
fn shared_mesh(render: &mut World, key: String, make: impl FnOnce() -> Mesh) -> Handle<Mesh> {
    if let Some(h) = render.resource::<Mirror>().meshes.get(&key) {
        return h.clone();
    }
    let handle = render.resource_mut::<Assets<Mesh>>().add(make());
    render.resource_mut::<Mirror>().meshes.insert(key, handle.clone());
    handle
}

/// A surface entity on render `layer`: batched, an instance with its tag; otherwise with a
/// material of its own. [`dress`] sets how it looks.
fn spawn_mesh(render: &mut World, mesh: Handle<Mesh>, transform: Transform, layer: usize) -> Entity {
    let bundle = (Mesh3d(mesh), transform, RenderLayers::layer(layer));
    if render.contains_resource::<Batch>() {
        let tag = render.resource_mut::<Batch>().tag();
        let material = batch::material(render, None);
        render.spawn((bundle, MeshMaterial3d(material), MeshTag(tag), NoFrustumCulling)).id()
    } else {
        let material = render.resource_mut::<Assets<LambertMaterial>>().add(LambertMaterial::new(Color::WHITE));
        render.spawn((bundle, MeshMaterial3d(material))).id()
    }
}

/// Shows `material` on the surface `entity` of render `layer`: batched, as its instance's
/// record and shared material; otherwise in its own material.
fn dress(render: &mut World, entity: Entity, material: LambertMaterial, layer: usize) {
    let own = render.get::<MeshMaterial3d<LambertMaterial>>(entity).map(|m| m.0.clone());
    match render.get::<MeshTag>(entity).map(|t| t.0) {
        Some(tag) => {
            render.resource_mut::<Batch>().set(tag, SurfaceRecord::new(&material, layer));
            let shared = batch::material(render, material.image);
            if own.as_ref() != Some(&shared) {
                render.entity_mut(entity).insert(MeshMaterial3d(shared));
            }
        }
        None => {
            if let Some(h) = own
                && let Some(mut m) = render.resource_mut::<Assets<LambertMaterial>>().get_mut(&h)
            {
                *m = material;
            }
        }
    }
}

/// Despawns a surface entity (an instance's tag is freed).
fn despawn_surface(render: &mut World, entity: Entity) {
    if let Some(tag) = render.get::<MeshTag>(entity).map(|t| t.0) {
        render.resource_mut::<Batch>().release(tag);
    }
    render.despawn(entity);
}

/// Shows `look` in `arena`: every surface's material and the lights.
fn show(render: &mut World, arena: Entity, look: &Look) -> Result<(), RenderError> {
    let (surfaces, layer): (Vec<(String, Entity, [f32; 3])>, usize) = {
        let m = &render.resource::<Mirror>().arenas[&arena];
        (m.surfaces.iter().map(|(n, (e, c))| (n.clone(), *e, *c)).collect(), m.layer)
    };
    let batched = render.contains_resource::<Batch>();
    let shadows = render.get_resource::<Shadows>().is_some_and(|s| s.0);
    // How every material of the arena is lit.
    let lit =
        |m: LambertMaterial| LambertMaterial { lights: look.lights.len().min(Look::MAX_LIGHTS) as u32, shadows, ..m };
    for (name, entity, own) in surfaces {
        let material = match look.surfaces.get(&name) {
            Some(surface) => surface_material(render, surface)?,
            None => LambertMaterial::new(Color::srgb(own[0], own[1], own[2])),
        };
        dress(render, entity, lit(material), layer);
    }
    let old = {
        let mut m = arena_mut(render, arena);
        let shown = std::mem::take(&mut m.lights);
        shown.into_iter().chain(std::mem::take(&mut m.distractors)).collect::<Vec<Entity>>()
    };
    for e in old {
        despawn_surface(render, e);
    }
    let mut distractors = Vec::with_capacity(look.distractors.len());
    for d in &look.distractors {
        let half = Vec3::from_array(d.half_extents);
        let mesh = shared_mesh(render, format!("box {half}"), || box_mesh(half));
        let material = lit(surface_material(render, &d.surface)?);
        let pose = Pose::from_parts(Vec3::from_array(d.centre), Quat::from_rotation_z(d.yaw));
        let e = spawn_mesh(render, mesh, to_bevy(pose), layer);
        dress(render, e, material, layer);
        distractors.push(e);
    }
    // Batched frames light each arena from its `ArenaView` instead.
    let lights: Vec<Entity> = look
        .lights
        .iter()
        .take(if batched { 0 } else { Look::MAX_LIGHTS })
        .map(|l| {
            let [r, g, b] = l.color;
            let towards = point_to_bevy(Vec3::from_array(l.direction));
            let light = DirectionalLight {
                illuminance: l.intensity,
                color: Color::linear_rgb(r, g, b),
                shadow_maps_enabled: shadows,
                ..default()
            };
            let pose = Transform::default().looking_to(towards, any_orthogonal(towards));
            // A cell is a few metres across: two cascades over 8 m keep the shadows sharp.
            let cascades = CascadeShadowConfigBuilder {
                num_cascades: 2,
                first_cascade_far_bound: 2.5,
                maximum_distance: 8.0,
                ..default()
            }
            .build();
            render.spawn((light, cascades, pose, RenderLayers::layer(layer))).id()
        })
        .collect();
    let mut mirror = arena_mut(render, arena);
    mirror.lights = lights;
    mirror.distractors = distractors;
    mirror.look = Some(look.clone());
    Ok(())
}

/// The material of a look's surface (its image loaded if it has one).
fn surface_material(render: &mut World, surface: &Surface) -> Result<LambertMaterial, RenderError> {
    let image = match &surface.texture {
        Texture::Image { path, .. } => Some(image_texture(render, path)?),
        _ => None,
    };
    Ok(LambertMaterial::of_surface(surface, image))
}

/// An up vector for `looking_to` that is never parallel to the direction.
fn any_orthogonal(d: Vec3) -> Vec3 {
    if d.normalize_or_zero().y.abs() > 0.99 { Vec3::Z } else { Vec3::Y }
}

/// An image file as a texture that repeats (loaded once per path).
fn image_texture(render: &mut World, path: &Path) -> Result<Handle<Image>, RenderError> {
    if let Some(h) = render.resource::<Mirror>().images.get(path) {
        return Ok(h.clone());
    }
    let read =
        image::open(path).map_err(|e| RenderError::Failed(format!("image texture '{}': {e}", path.display())))?;
    let rgba = read.to_rgba8();
    let mut image = Image::new(
        Extent3d { width: rgba.width(), height: rgba.height(), depth_or_array_layers: 1 },
        TextureDimension::D2,
        rgba.into_raw(),
        TextureFormat::Rgba8UnormSrgb,
        RenderAssetUsages::RENDER_WORLD,
    );
    image.sampler = ImageSampler::Descriptor(ImageSamplerDescriptor {
        address_mode_u: ImageAddressMode::Repeat,
        address_mode_v: ImageAddressMode::Repeat,
        ..ImageSamplerDescriptor::linear()
    });
    let handle = render.resource_mut::<Assets<Image>>().add(image);
    render.resource_mut::<Mirror>().images.insert(path.to_path_buf(), handle.clone());
    Ok(handle)
}
