//! The off-screen renderer: its own Bevy app (DefaultPlugins, no window) that draws a mirrored
//! arena through a camera into an image and reads the pixels back. It is driven by hand, one
//! frame per call, after the sim app's step: the image of step i shows step i.

use std::sync::{Arc, Mutex};

use bevy::app::PluginsState;
use bevy::asset::RenderAssetUsages;
use bevy::camera::visibility::RenderLayers;
use bevy::camera::{RenderTarget, Viewport};
use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::prelude::*;
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::{
    Buffer, BufferDescriptor, BufferUsages, CommandEncoderDescriptor, Extent3d, MapMode, PipelineCache, PollType,
    TexelCopyBufferInfo, TexelCopyBufferLayout, TextureDimension, TextureFormat, TextureUsages,
};
use bevy::render::renderer::{RenderDevice, RenderQueue, initialize_renderer};
use bevy::render::settings::{InstanceFlags, RenderCreation, WgpuFeatures, WgpuSettings};
use bevy::render::texture::GpuImage;
use bevy::render::{RenderApp, RenderPlugin};
use bevy::window::ExitCondition;
use twinbots_sim::look::CameraJitter;
use twinbots_sim::rapier::math::Pose;

use crate::batch::{self, Batch};
use crate::scene;
use crate::shading::{self, ArenaView, ShadingPlugin};

#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no graphics adapter: pixels need a Vulkan driver (on a machine without a GPU install Mesa's \
         software driver: apt-get install mesa-vulkan-drivers libvulkan1)"
    )]
    NoAdapter,
    #[error("rendering failed: {0}")]
    Failed(String),
}

/// Whether CI asked for render tests to fail rather than skip without an adapter.
pub fn adapter_required() -> bool {
    std::env::var_os("TWINBOTS_REQUIRE_ADAPTER").is_some_and(|v| v != "0" && !v.is_empty())
}

/// Looks for an adapter once, quietly; `None` when there is none.
fn probe() -> Option<RenderCreation> {
    let mut settings = WgpuSettings::default();
    settings.instance_flags |= InstanceFlags::ALLOW_UNDERLYING_NONCOMPLIANT_ADAPTER;
    settings.memory_hints = bevy::render::settings::MemoryHints::MemoryUsage;
    let backends = settings.backends?;
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let resources = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        bevy::tasks::block_on(initialize_renderer(backends, None, &settings))
    }));
    std::panic::set_hook(hook);
    resources.ok().map(RenderCreation::from)
}

/// A camera of the render app, in physics coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Camera pose: it looks along its local −Z with +Y up (Bevy's camera convention), which
    /// [`View::looking_at`] and [`View::from_mount`] set up.
    pub transform: Transform,
    pub fov_y: f32,
}

pub use twinbots_sim::Framing;

impl View {
    /// A named camera of a robot's cell (see [`Framing::eye`]).
    pub fn framed(framing: &Framing, name: &str) -> Option<Self> {
        Some(Self::looking_at(framing.eye(name)?, framing.target, 45f32.to_radians()))
    }

    /// A camera at `eye` looking at `target` (physics coordinates, Z up).
    pub fn looking_at(eye: Vec3, target: Vec3, fov_y: f32) -> Self {
        let transform =
            Transform::from_translation(scene::point_to_bevy(eye)).looking_at(scene::point_to_bevy(target), Vec3::Y);
        Self { transform, fov_y }
    }

    /// A device camera: looks along the mount's +X with the mount's +Z up.
    pub fn from_mount(pose: Pose, fov_y: f32) -> Self {
        let forward = pose.rotation * Vec3::X;
        let up = pose.rotation * Vec3::Z;
        let eye = scene::point_to_bevy(pose.translation);
        let transform =
            Transform::from_translation(eye).looking_to(scene::point_to_bevy(forward), scene::point_to_bevy(up));
        Self { transform, fov_y }
    }

    /// This view moved by a look's camera jitter: the eye by its offset, the orientation by its
    /// rotation (in the camera's own frame), the field of view by its change, kept inside
    /// (1°, 179°).
    pub fn jittered(&self, jitter: &CameraJitter) -> Self {
        let mut transform = self.transform;
        transform.translation += scene::point_to_bevy(Vec3::from_array(jitter.offset));
        transform.rotation *= Quat::from_scaled_axis(Vec3::from_array(jitter.rotation));
        let fov_y = (self.fov_y + jitter.fov).clamp(1f32.to_radians(), 179f32.to_radians());
        Self { transform, fov_y }
    }

    /// Pixel coordinates (x right, y down) of a physics point in a `width × height` image, or
    /// `None` behind the camera.
    pub fn project(&self, point: Vec3, width: u32, height: u32) -> Option<Vec2> {
        let p = self.transform.compute_affine().inverse().transform_point3(scene::point_to_bevy(point));
        if p.z >= 0.0 {
            return None;
        }
        let f = 1.0 / (self.fov_y / 2.0).tan();
        let aspect = width as f32 / height as f32;
        let ndc = Vec2::new(f * p.x / (-p.z) / aspect, f * p.y / (-p.z));
        Some(Vec2::new((ndc.x + 1.0) / 2.0 * width as f32, (1.0 - ndc.y) / 2.0 * height as f32))
    }
}

#[derive(Resource)]
struct Target(Handle<Image>);

/// How a frame's tiles are drawn.
enum Cameras {
    /// One camera over the whole target; each arena is drawn through its own `ArenaView` into
    /// its tile (see `batch`): Bevy's per-view work is paid once a frame.
    Batched(Entity),
    /// A camera per tile, in tile order, lit by Bevy's lights: for shadows (Bevy renders their
    /// maps per view), single images (compiled shading is faster per pixel) and devices that
    /// cannot clip to a tile.
    PerTile(Vec<Entity>),
}

/// An off-screen renderer producing `width × height` RGB images: one at a time ([`Renderer::new`],
/// `sync` + `set_view` + `render`), or several arenas at once, each in one tile of a shared
/// target that is read back once ([`Renderer::tiled`], `render_shots`).
pub struct Renderer {
    app: App,
    /// One image's size (a tile's).
    pub width: u32,
    pub height: u32,
    /// Tiles per row of the target, and in all.
    columns: u32,
    tiles: usize,
    cameras: Cameras,
    /// New meshes were added: their pipelines must compile before a frame is read.
    fresh_meshes: bool,
    /// Where frames are copied to be read (made on the first frame).
    readback_buffer: Option<Buffer>,
    /// The camera as set, before the shown look's jitter.
    view: View,
    /// The arena synced last: the one `render` shows.
    arena: Option<Entity>,
    /// Why the last sync could not show the arena (an image texture that does not read): the
    /// next frame fails with it.
    sync_error: Option<RenderError>,
}

impl Renderer {
    /// Builds the render app; `RenderError::NoAdapter` when no graphics adapter exists.
    pub fn new(width: u32, height: u32) -> Result<Self, RenderError> {
        Self::tiled(width, height, 1)
    }

    /// A renderer that draws up to `tiles` images of `width × height` in one frame.
    pub fn tiled(width: u32, height: u32, tiles: usize) -> Result<Self, RenderError> {
        if width == 0 || height == 0 || tiles == 0 {
            return Err(RenderError::Failed(format!("image size {width}×{height} ({tiles} tiles) is empty")));
        }
        let columns = (tiles as f64).sqrt().ceil() as u32;
        let rows = (tiles as u32).div_ceil(columns);
        let render_creation = probe().ok_or(RenderError::NoAdapter)?;
        let mut app = App::new();
        app.add_plugins(
            DefaultPlugins
                .set(WindowPlugin { primary_window: None, exit_condition: ExitCondition::DontExit, ..default() })
                .set(RenderPlugin { render_creation, synchronous_pipeline_compilation: true, ..default() })
                .disable::<bevy::winit::WinitPlugin>()
                .disable::<bevy::log::LogPlugin>(),
        )
        .add_plugins(ShadingPlugin)
        .insert_resource(ClearColor(Color::srgb(0.78, 0.84, 0.9)));
        while app.plugins_state() == PluginsState::Adding {
            bevy::tasks::tick_global_task_pools_on_main_thread();
        }
        app.finish();
        app.cleanup();
        let batched =
            app.sub_app(RenderApp).world().resource::<RenderDevice>().features().contains(WgpuFeatures::CLIP_DISTANCES);

        let world = app.world_mut();
        let mut image = Image::new_uninit(
            Extent3d { width: width * columns, height: height * rows, depth_or_array_layers: 1 },
            TextureDimension::D2,
            TextureFormat::Rgba8UnormSrgb,
            RenderAssetUsages::RENDER_WORLD,
        );
        image.texture_descriptor.usage |= TextureUsages::RENDER_ATTACHMENT | TextureUsages::COPY_SRC;
        let handle = world.resource_mut::<Assets<Image>>().add(image);
        world.insert_resource(Target(handle.clone()));
        world.insert_resource(Batch::default());
        let camera = spawn_camera(world, &handle, None, 0);
        let view = View {
            transform: Transform::from_xyz(0.0, 1.0, 3.0).looking_at(Vec3::ZERO, Vec3::Y),
            fov_y: PerspectiveProjection::default().fov,
        };
        let renderer = Self {
            app,
            width,
            height,
            columns,
            tiles,
            cameras: Cameras::Batched(camera),
            fresh_meshes: true,
            readback_buffer: None,
            view,
            arena: None,
            sync_error: None,
        };
        // One tile: a camera of its own and compiled shading (at 640×480 the batched shader's
        // per-pixel branches cost 3×: 42–47 against 122–150 frames/s).
        Ok(if batched && tiles > 1 { renderer } else { renderer.per_tile() })
    }

    /// Lights cast shadows from now on (see [`scene::Shadows`]); call before the first sync.
    pub fn with_shadows(mut self, shadows: bool) -> Self {
        // 1024² per cascade: Bevy's 2048² cost a CPU renderer 4× the time for a cell's shadows.
        let world = self.app.world_mut();
        world.insert_resource(scene::Shadows(shadows));
        world.insert_resource(bevy::light::DirectionalLightShadowMap { size: 1024 });
        // Bevy's lights and one view per tile: its shadow maps are rendered per view.
        if shadows { self.per_tile() } else { self }
    }

    /// Draws a tile per camera, lit by Bevy's lights, from now on (call before the first sync).
    fn per_tile(mut self) -> Self {
        if let Cameras::Batched(camera) = self.cameras {
            let tiles: Vec<URect> = (0..self.tiles).map(|i| self.tile_rect(i)).collect();
            let world = self.app.world_mut();
            world.despawn(camera);
            world.remove_resource::<Batch>();
            let handle = world.resource::<Target>().0.clone();
            let cameras = tiles
                .iter()
                .enumerate()
                .map(|(i, tile)| {
                    let viewport = Viewport { physical_position: tile.min, physical_size: tile.size(), ..default() };
                    spawn_camera(world, &handle, Some(viewport), i as isize)
                })
                .collect();
            self.cameras = Cameras::PerTile(cameras);
        }
        self
    }

    /// Where tile `i` lies in the target, in pixels (row-major, `columns` to a row).
    fn tile_rect(&self, i: usize) -> URect {
        let min = UVec2::new(i as u32 % self.columns * self.width, i as u32 / self.columns * self.height);
        URect::from_corners(min, min + UVec2::new(self.width, self.height))
    }

    /// How many images one frame can draw.
    pub fn tiles(&self) -> usize {
        self.tiles
    }

    /// Creates (once) and poses the render entities of `arena` from the sim world, and shows
    /// its look (lights, surfaces, camera jitter); `render` then shows it.
    pub fn sync(&mut self, sim: &mut World, arena: Entity) {
        self.mirror(sim, arena);
        self.arena = Some(arena);
    }

    fn mirror(&mut self, sim: &mut World, arena: Entity) {
        match scene::sync_into(self.app.world_mut(), sim, arena) {
            Ok(fresh) => self.fresh_meshes |= fresh,
            Err(e) => self.sync_error = Some(e),
        }
    }

    /// Points the camera (the shown look's jitter is applied on top).
    pub fn set_view(&mut self, view: View) {
        self.view = view;
    }

    /// The camera of the next frame: the view set, jittered by the shown look.
    pub fn camera(&self) -> View {
        self.arena.map_or(self.view, |a| self.jittered(self.view, a))
    }

    /// `view` moved by the camera jitter of the look `arena` is shown in.
    fn jittered(&self, view: View, arena: Entity) -> View {
        match self.app.world().get_resource::<scene::Mirror>().and_then(|m| m.look(arena)) {
            Some(look) => view.jittered(&look.camera),
            None => view,
        }
    }

    /// Points a tile's `camera` at `arena` through `view` (jittered by the arena's look).
    fn aim(&mut self, camera: Entity, arena: Entity, view: View) {
        let view = self.jittered(view, arena);
        let world = self.app.world_mut();
        scene::watch(world, camera, arena);
        // Only on change: a changed projection makes Bevy rebuild the view's state.
        if let Some(mut t) = world.get_mut::<Transform>(camera) {
            t.set_if_neq(view.transform);
        }
        if let Some(mut p) = world.get_mut::<Projection>(camera)
            && let Projection::Perspective(pp) = p.bypass_change_detection()
            && pp.fov != view.fov_y
        {
            pp.fov = view.fov_y;
            p.set_changed();
        }
    }

    /// Renders the current scene and returns RGB8 pixels, row-major from the top-left.
    pub fn render(&mut self) -> Result<Vec<u8>, RenderError> {
        let arena = self.arena.ok_or_else(|| RenderError::Failed("nothing to render: no arena was synced".into()))?;
        let mut tiles = self.draw(&[(arena, self.view)])?;
        Ok(tiles.swap_remove(0))
    }

    /// Syncs and renders several arenas, each through its view, in one frame per
    /// [`Renderer::tiles`] shots: one RGB8 image per shot, in order.
    pub fn render_shots(&mut self, sim: &mut World, shots: &[(Entity, View)]) -> Result<Vec<Vec<u8>>, RenderError> {
        let mut seen = std::collections::HashSet::new();
        for (arena, _) in shots {
            if seen.insert(*arena) {
                self.mirror(sim, *arena);
            }
        }
        // Frames of up to `tiles` shots, each arena once a frame (it has one `ArenaView`).
        let mut images = Vec::with_capacity(shots.len());
        let mut frame: Vec<(Entity, View)> = Vec::with_capacity(self.tiles);
        for &shot in shots {
            if frame.len() == self.tiles || frame.iter().any(|(a, _)| *a == shot.0) {
                images.extend(self.draw(&frame)?);
                frame.clear();
            }
            frame.push(shot);
        }
        if !frame.is_empty() {
            images.extend(self.draw(&frame)?);
        }
        Ok(images)
    }

    /// Points the batched camera at the shots' arenas and fills their `ArenaView`s: shot i
    /// through its view (jittered by its arena's look) into tile i, lit by that look.
    fn aim_batched(&mut self, camera: Entity, shots: &[(Entity, View)]) {
        let mirror = self.app.world().resource::<scene::Mirror>();
        let mut views = vec![ArenaView::default(); mirror.max_layer() + 1];
        let mut layers = RenderLayers::none();
        let default_look = twinbots_sim::Look::default();
        for (i, (arena, view)) in shots.iter().enumerate() {
            let Some(layer) = mirror.layer(*arena) else { continue };
            let look = mirror.look(*arena).unwrap_or(&default_look);
            let view = view.jittered(&look.camera);
            views[layer] = ArenaView::new(view.transform, view.fov_y, self.tile_rect(i), self.target_size(), look);
            layers = layers.with(layer);
        }
        let world = self.app.world_mut();
        if world.get::<RenderLayers>(camera) != Some(&layers) {
            world.entity_mut(camera).insert(layers);
        }
        let mut resized = batch::upload(world, &shading::ARENA_VIEWS, views);
        let records = world.resource_mut::<Batch>().take_changed().map(<[_]>::to_vec);
        if let Some(records) = records {
            resized |= batch::upload(world, &shading::SURFACES, records);
        }
        if resized {
            // A new buffer: made by this update, bound by every material from the next.
            self.app.update();
            batch::rebind_materials(self.app.world_mut());
        }
    }

    /// One frame: tile i shows `shots[i]`; the other tiles' cameras rest.
    fn draw(&mut self, shots: &[(Entity, View)]) -> Result<Vec<Vec<u8>>, RenderError> {
        if let Some(e) = self.sync_error.take() {
            return Err(e);
        }
        match &self.cameras {
            Cameras::Batched(camera) => self.aim_batched(*camera, shots),
            Cameras::PerTile(cameras) => {
                let cameras = cameras.clone();
                for (i, &camera) in cameras.iter().enumerate() {
                    if let Some(&(arena, view)) = shots.get(i) {
                        self.aim(camera, arena, view);
                    }
                    if let Some(mut c) = self.app.world_mut().get_mut::<Camera>(camera)
                        && c.is_active != (i < shots.len())
                    {
                        c.is_active = i < shots.len();
                    }
                }
            }
        }
        if std::mem::take(&mut self.fresh_meshes) {
            self.settle()?;
        }
        // One update draws the frame into the target texture; it is copied out at once. (Bevy's
        // `Readback` delivers only on the next update, which would draw the scene again.)
        self.app.update();
        self.poll()?;
        self.read_target(shots.len())
    }

    /// The target's size in pixels.
    fn target_size(&self) -> (u32, u32) {
        let rows = (self.tiles as u32).div_ceil(self.columns);
        (self.width * self.columns, self.height * rows)
    }

    /// Copies the target texture into a mappable buffer (kept between frames) and reads its
    /// first `tiles` tiles out of it as RGB images.
    fn read_target(&mut self, tiles: usize) -> Result<Vec<Vec<u8>>, RenderError> {
        let (width, height) = self.target_size();
        let rects: Vec<URect> = (0..tiles).map(|i| self.tile_rect(i)).collect();
        let handle = self.app.world().resource::<Target>().0.clone();
        let world = self.app.sub_app(RenderApp).world();
        let image = world
            .resource::<RenderAssets<GpuImage>>()
            .get(&handle)
            .ok_or_else(|| RenderError::Failed("the render target is not on the GPU".into()))?;
        let device = world.resource::<RenderDevice>();
        let padded = RenderDevice::align_copy_bytes_per_row((width * 4) as usize);
        let size = (padded * height as usize) as u64;
        let buffer = self.readback_buffer.get_or_insert_with(|| {
            device.create_buffer(&BufferDescriptor {
                label: Some("twinbots frame readback"),
                size,
                usage: BufferUsages::MAP_READ | BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        let mut encoder =
            device.create_command_encoder(&CommandEncoderDescriptor { label: Some("twinbots frame copy") });
        encoder.copy_texture_to_buffer(
            image.texture.as_image_copy(),
            TexelCopyBufferInfo {
                buffer,
                layout: TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded as u32), rows_per_image: None },
            },
            Extent3d { width, height, depth_or_array_layers: 1 },
        );
        world.resource::<RenderQueue>().submit([encoder.finish()]);
        let slice = buffer.slice(..);
        let mapped: Arc<Mutex<Option<Result<(), String>>>> = Arc::default();
        let done = mapped.clone();
        slice.map_async(MapMode::Read, move |r| *done.lock().expect("map flag") = Some(r.map_err(|e| e.to_string())));
        device.poll(PollType::wait_indefinitely()).map_err(|e| RenderError::Failed(format!("{e:?}")))?;
        match mapped.lock().expect("map flag").take() {
            Some(Ok(())) => {}
            Some(Err(e)) => return Err(RenderError::Failed(format!("reading the frame back: {e}"))),
            None => return Err(RenderError::Failed("no pixels came back".into())),
        }
        let images = {
            let data = slice.get_mapped_range();
            rects
                .iter()
                .map(|r| {
                    tile(&data, padded, (r.min.x as usize, r.min.y as usize), (r.width() as usize, r.height() as usize))
                })
                .collect()
        };
        buffer.unmap();
        Ok(images)
    }

    /// Updates until no pipeline is still compiling, so new meshes do not render blank.
    fn settle(&mut self) -> Result<(), RenderError> {
        for _ in 0..200 {
            self.app.update();
            self.poll()?;
            let waiting =
                self.app.sub_app(RenderApp).world().resource::<PipelineCache>().waiting_pipelines().next().is_some();
            if !waiting {
                return Ok(());
            }
        }
        Err(RenderError::Failed("render pipelines never finished compiling".into()))
    }

    fn poll(&mut self) -> Result<(), RenderError> {
        if let Some(exit) = self.app.should_exit() {
            return Err(RenderError::Failed(format!("the render app stopped: {exit:?}")));
        }
        self.app
            .world()
            .resource::<RenderDevice>()
            .poll(PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| RenderError::Failed(format!("{e:?}")))
    }
}

/// A camera drawing into `target` (its `viewport` of it, or all of it), in `order` (so tiles
/// never race; the first clears the whole target).
fn spawn_camera(world: &mut World, target: &Handle<Image>, viewport: Option<Viewport>, order: isize) -> Entity {
    let size = world.resource::<Assets<Image>>().get(target).map_or(UVec2::ONE, |i| i.size());
    let size = viewport.as_ref().map_or(size, |v| v.physical_size);
    world
        .spawn((
            Camera3d::default(),
            Camera { order, viewport, is_active: order == 0, ..default() },
            RenderTarget::from(target.clone()),
            Msaa::Off,
            Tonemapping::None,
            // Only directional lights: one light cluster per view (the default builds thousands).
            bevy::light::cluster::ClusterConfig::Single,
            Projection::Perspective(PerspectiveProjection { aspect_ratio: size.x as f32 / size.y as f32, ..default() }),
            Transform::from_xyz(0.0, 1.0, 3.0).looking_at(Vec3::ZERO, Vec3::Y),
        ))
        .id()
}

/// The `w × h` RGB image at pixel `(x0, y0)` of RGBA rows `padded` bytes apart.
fn tile(data: &[u8], padded: usize, (x0, y0): (usize, usize), (w, h): (usize, usize)) -> Vec<u8> {
    let mut rgb = Vec::with_capacity(w * h * 3);
    for row in data.chunks(padded).skip(y0).take(h) {
        for px in row[x0 * 4..(x0 + w) * 4].chunks_exact(4) {
            rgb.extend_from_slice(&px[..3]);
        }
    }
    rgb
}
