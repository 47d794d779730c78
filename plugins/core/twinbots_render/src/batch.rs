//! Batched frames: one camera draws every arena of a frame, each through its own camera into
//! its own tile, with as few draw calls as the frame has distinct meshes. They need a device
//! that clips to user planes (wgpu's `CLIP_DISTANCES`: Vulkan, Metal, DX12); elsewhere, and with
//! shadows, `Renderer` draws a tile per camera.
//!
//! Where a frame of 16 tiles had 16 cameras, Bevy paid its per-view work (visibility, light and
//! view uniforms, bind groups, a render pass) 16 times; and where each surface of each arena
//! had its own material, lavapipe paid a draw call (~0.15 ms on a 2-core VM) per surface per
//! arena. Here the arenas' meshes are shared and their surfaces are instances of a few shared
//! materials: an instance's `SurfaceRecord` (colours, pattern, its arena) is found through
//! its `MeshTag`, and its arena's camera, tile and lights in an `ArenaView`. Both live in
//! storage buffers bound by every material (`shading::{ARENA_VIEWS, SURFACES}`). Figures:
//! docs/benchmarks.md.

use std::collections::HashMap;

use bevy::camera::CameraProjection;
use bevy::prelude::*;
use bevy::render::render_resource::ShaderType;
use bevy::render::render_resource::encase::internal::WriteInto;
use bevy::render::storage::ShaderBuffer;
use twinbots_sim::Look;

use crate::coords::point_to_bevy;
use crate::shading::{ArenaView, LambertMaterial, SurfaceRecord};

impl ArenaView {
    /// An arena seen by a camera at `eye` (Bevy's camera convention) with a vertical field of
    /// view `fov_y`, into the `tile` (pixels) of a `frame` (its size), lit by `look`.
    pub fn new(eye: Transform, fov_y: f32, tile: URect, (frame_w, frame_h): (u32, u32), look: &Look) -> Self {
        let (w, h) = (tile.width() as f32, tile.height() as f32);
        let (x0, y0) = (tile.min.x as f32, tile.min.y as f32);
        let (frame_w, frame_h) = (frame_w as f32, frame_h as f32);
        let projection = PerspectiveProjection { fov: fov_y, aspect_ratio: w / h, ..default() };
        let mut light_directions = [Vec4::ZERO; Look::MAX_LIGHTS];
        let mut light_colors = [Vec4::ZERO; Look::MAX_LIGHTS];
        let lights = look.lights.iter().take(Look::MAX_LIGHTS);
        for (k, l) in lights.enumerate() {
            // As Bevy's own lights carry them: towards the light, colour × intensity.
            light_directions[k] = (-point_to_bevy(Vec3::from_array(l.direction)).normalize_or_zero()).extend(0.0);
            light_colors[k] = (Vec3::from_array(l.color) * l.intensity).extend(1.0);
        }
        Self {
            clip_from_world: projection.get_clip_from_view() * eye.to_matrix().inverse(),
            // The tile's NDC box inside the frame's: x' = x·w/W + (2·x0 + w)/W − 1, and y alike
            // (downwards).
            tile: Vec4::new(w / frame_w, h / frame_h, (2.0 * x0 + w) / frame_w - 1.0, 1.0 - (2.0 * y0 + h) / frame_h),
            eye: eye.translation.extend(1.0),
            ambient: Vec3::from_array(look.ambient).extend(look.lights.len().min(Look::MAX_LIGHTS) as f32),
            light_directions,
            light_colors,
        }
    }
}

/// Fills the buffer `handle` with `items`, padded to a power of two (at least 16) so its size
/// rarely changes. The GPU buffer is rewritten in place while the size stays; returns true when
/// it changed: the next update makes a new buffer, which materials bind only once
/// [`rebind_materials`] is called after it (Bevy prepares materials and storage buffers in no
/// set order).
pub fn upload<T: Default + Clone>(world: &mut World, handle: &Handle<ShaderBuffer>, mut items: Vec<T>) -> bool
where
    Vec<T>: ShaderType + WriteInto,
{
    items.resize(items.len().next_power_of_two().max(16), T::default());
    let mut buffers = world.resource_mut::<Assets<ShaderBuffer>>();
    let Some(mut buffer) = buffers.get_mut(handle) else { return false };
    let old = buffer.data.as_ref().map_or(0, Vec::len);
    buffer.set_data(items);
    buffer.data.as_ref().map_or(0, Vec::len) != old
}

/// Makes every material bind its buffers again.
pub fn rebind_materials(world: &mut World) {
    let mut materials = world.resource_mut::<Assets<LambertMaterial>>();
    let ids: Vec<AssetId<LambertMaterial>> = materials.ids().collect();
    for id in ids {
        // A change is noted on a mutable borrow only.
        if let Some(mut m) = materials.get_mut(id) {
            let _: &mut LambertMaterial = &mut m;
        }
    }
}

/// Batched frames' state in a render world: every surface instance's record (by its tag), and
/// the shared materials. Its presence makes the render world batched (see `scene`).
#[derive(Resource, Default)]
pub struct Batch {
    records: Vec<SurfaceRecord>,
    free: Vec<u32>,
    changed: bool,
    materials: HashMap<Option<AssetId<Image>>, Handle<LambertMaterial>>,
}

impl Batch {
    /// A tag for a new surface instance.
    pub fn tag(&mut self) -> u32 {
        self.free.pop().unwrap_or_else(|| {
            self.records.push(SurfaceRecord::default());
            self.records.len() as u32 - 1
        })
    }

    /// The instance `tag` is gone: its tag is free again.
    pub fn release(&mut self, tag: u32) {
        self.free.push(tag);
    }

    /// How instance `tag` looks.
    pub fn set(&mut self, tag: u32, record: SurfaceRecord) {
        if let Some(r) = self.records.get_mut(tag as usize)
            && *r != record
        {
            *r = record;
            self.changed = true;
        }
    }

    /// The records, when they changed since the last call.
    pub fn take_changed(&mut self) -> Option<&[SurfaceRecord]> {
        std::mem::take(&mut self.changed).then_some(&self.records)
    }
}

/// The material batched instances of a surface textured by `image` (or none) are drawn with.
pub fn material(render: &mut World, image: Option<Handle<Image>>) -> Handle<LambertMaterial> {
    let key = image.as_ref().map(Handle::id);
    if let Some(h) = render.resource::<Batch>().materials.get(&key) {
        return h.clone();
    }
    let handle = render.resource_mut::<Assets<LambertMaterial>>().add(LambertMaterial::batched(image));
    render.resource_mut::<Batch>().materials.insert(key, handle.clone());
    handle
}
