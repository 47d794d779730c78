//! Batched frames: one camera draws every arena of a frame, each through its own camera into
//! its own tile, with as few draw calls as the frame has distinct meshes. They need a device
//! that clips to user planes (wgpu's `CLIP_DISTANCES`: Vulkan, Metal, DX12); elsewhere, and with
//! shadows, `Renderer` draws a tile per camera.
//!
//! Where a frame of 16 tiles had 16 cameras, Bevy paid its per-view work (visibility, light and
//! view uniforms, bind groups, a render pass) 16 times; and where each surface of each arena
//! had its own material, lavapipe paid a draw call (~0.15 ms on a 2-core VM) per surface per
//! arena. Here the arenas' meshes are shared and their surfaces are instances of a few shared
//! materials: an instance's [`SurfaceRecord`] (colours, pattern, its arena) is found through
//! its `MeshTag`, and its arena's camera, tile and lights in an [`ArenaView`]. Both live in
//! storage buffers bound by every material ([`ARENA_VIEWS`], [`SURFACES`]). Figures:
//! docs/benchmarks.md.

use std::collections::HashMap;

use bevy::asset::{RenderAssetUsages, uuid_handle};
use bevy::prelude::*;
use bevy::color::ColorToComponents;
use bevy::render::render_resource::ShaderType;
use bevy::render::render_resource::encase::internal::WriteInto;
use bevy::render::storage::ShaderBuffer;
use twinbots_sim::Look;

use crate::shading::LambertMaterial;

/// One arena's camera and lights in a batched frame, as the shader reads it.
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq)]
pub struct ArenaView {
    /// The arena's camera: Bevy's clip space from world space (reverse Z, infinite far).
    pub clip_from_world: Mat4,
    /// Where its tile lies in the frame: clip x, y scaled by `.xy`, then moved by `.zw` × w.
    pub tile: Vec4,
    /// The camera's position (world, Bevy's Y up), for highlights.
    pub eye: Vec4,
    /// Ambient light (linear RGB), and how many lights follow (`.w`).
    pub ambient: Vec4,
    /// Towards each light (world, unit), and its colour × intensity (linear RGB).
    pub light_directions: [Vec4; Look::MAX_LIGHTS],
    pub light_colors: [Vec4; Look::MAX_LIGHTS],
}

/// How one surface instance looks: a [`LambertMaterial`]'s own fields, and its arena.
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq)]
pub struct SurfaceRecord {
    pub color: Vec4,
    pub color2: Vec4,
    pub kind: u32,
    pub size: f32,
    pub specular: f32,
    /// Its arena's index among the [`ArenaView`]s.
    pub arena: u32,
}

impl SurfaceRecord {
    pub fn new(material: &LambertMaterial, arena: usize) -> Self {
        Self {
            color: material.color.to_vec4(),
            color2: material.color2.to_vec4(),
            kind: material.kind,
            size: material.size,
            specular: material.specular,
            arena: arena as u32,
        }
    }
}

/// The storage buffer of [`ArenaView`]s, indexed by `SurfaceRecord::arena`.
pub const ARENA_VIEWS: Handle<ShaderBuffer> = uuid_handle!("5c1d7f0e-2b7a-4f0c-9d57-6a3e8f1b2c44");
/// The storage buffer of [`SurfaceRecord`]s, indexed by each instance's `MeshTag`.
pub const SURFACES: Handle<ShaderBuffer> = uuid_handle!("b84e2c17-95d3-4a6f-8e21-7c0f3d9a5b62");

/// Adds both buffers, holding one empty element each.
pub fn init_buffers(world: &mut World) {
    let mut buffers = world.resource_mut::<Assets<ShaderBuffer>>();
    let kept = |b: ShaderBuffer| ShaderBuffer { asset_usage: RenderAssetUsages::default(), ..b };
    let _ = buffers.insert(&ARENA_VIEWS, kept(ShaderBuffer::from(vec![ArenaView::default()])));
    let _ = buffers.insert(&SURFACES, kept(ShaderBuffer::from(vec![SurfaceRecord::default()])));
}

/// Fills the buffer `handle` with `items`, padded to a power of two (at least 16) so its size
/// rarely changes. The GPU buffer is rewritten in place while the size stays; returns true when
/// it changed: the next update makes a new buffer, which materials bind only once
/// [`rebind_materials`] is called after it (Bevy prepares materials and storage buffers in no
/// set order).
pub fn upload<T: Default + Clone>(world: &mut World, handle: &Handle<ShaderBuffer>, items: &[T]) -> bool
where
    Vec<T>: ShaderType + WriteInto,
{
    let mut padded = items.to_vec();
    padded.resize(items.len().next_power_of_two().max(16), T::default());
    let mut buffers = world.resource_mut::<Assets<ShaderBuffer>>();
    let Some(mut buffer) = buffers.get_mut(handle) else { return false };
    let old = buffer.data.as_ref().map_or(0, Vec::len);
    buffer.set_data(padded);
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
