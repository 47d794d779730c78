//! How the twin is shaded: [`LambertMaterial`], a surface colour (optionally patterned or
//! textured) lit by the scene's directional lights (Lambert's cosine law, their colours and
//! intensities) over its ambient light, with an optional Blinn-Phong highlight.
//!
//! Pixels are rendered on the CPU wherever there is no GPU (Mesa's lavapipe: CI, training
//! servers). There Bevy's PBR `StandardMaterial` cost ~40 % of a 640×480 frame (82 ms per frame
//! against 51 ms unlit, measured on a 2-core VM); diffuse shading costs about what unlit does
//! and still shows the shapes and their orientation, which is what people and camera sensors
//! need from the twin.
//!
//! Each material's pattern and the scene's light count are compiled into its pipeline (shader
//! defs `PATTERN`, `LIGHTS`): branching on them per pixel, or looping over the light array,
//! cost lavapipe up to 40 % of a 640×480 frame (64 against 100 frames/s measured).
//!
//! **Batched frames** (`Renderer::tiled`, see `batch`): a material with `batched` set takes its
//! surface's colours and pattern from the instance's `SurfaceRecord` and its camera, tile and
//! lights from the arena's `ArenaView` (vertex stage: batched_vertex.wgsl); only image textures
//! are compiled apart, the pattern is branched on and the lights looped over per pixel (at 64×64
//! tiles draw calls cost far more than pixels; a single image keeps the compiled shading).
//!
//! The light model, in linear RGB: `pixel = albedo × (ambient + Σ colourᵢ × intensityᵢ ×
//! max(0, n·lᵢ)) + specular × Σ colourᵢ × intensityᵢ × max(0, n·hᵢ)^32` (Blinn-Phong, hᵢ halfway
//! between the light and the eye, only where the light reaches), where Bevy carries a light's relative intensity as its `illuminance` and the
//! ambient share as `GlobalAmbientLight::brightness` (see `twinbots_sim::look`).

use bevy::asset::{RenderAssetUsages, load_internal_asset, uuid_handle};
use bevy::color::ColorToComponents;
use bevy::mesh::MeshVertexBufferLayoutRef;
use bevy::pbr::{MaterialPipeline, MaterialPipelineKey};
use bevy::prelude::*;
use bevy::render::render_resource::{AsBindGroup, RenderPipelineDescriptor, ShaderType, SpecializedMeshPipelineError};
use bevy::render::storage::ShaderBuffer;
use bevy::shader::{ShaderDefVal, ShaderRef};
use twinbots_sim::look::{Surface, Texture};

use twinbots_sim::Look;

/// Pattern codes of the shader (`kind`).
const PLAIN: u32 = 0;
const CHECKER: u32 = 1;
const NOISE: u32 = 2;
const GRADIENT: u32 = 3;
const IMAGE: u32 = 4;

/// A colour, optionally patterned or textured, lit by the scene's lights over its ambient.
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
#[bind_group_data(LambertKey)]
pub struct LambertMaterial {
    /// Linear RGBA; alpha is ignored (surfaces are opaque).
    #[uniform(0)]
    pub color: LinearRgba,
    /// The pattern's second colour (linear).
    #[uniform(0)]
    pub color2: LinearRgba,
    /// The pattern: plain, checker, noise, gradient, image (the codes above).
    #[uniform(0)]
    pub kind: u32,
    /// Metres per checker square, noise cell, gradient period or image tile.
    #[uniform(0)]
    pub size: f32,
    /// Blinn-Phong highlight strength (0: none, and none compiled in).
    #[uniform(0)]
    pub specular: f32,
    #[texture(1)]
    #[sampler(2)]
    pub image: Option<Handle<Image>>,
    /// Batched frames' arenas and surfaces (the same buffers for all materials).
    #[storage(3, read_only)]
    pub views: Handle<ShaderBuffer>,
    #[storage(4, read_only)]
    pub surfaces: Handle<ShaderBuffer>,
    /// Whether the material draws batched frames' surface instances (see `batch`) rather than
    /// one surface through Bevy's camera and lights.
    pub batched: bool,
    /// How many directional lights the scene has (the renderer keeps it so, see scene.rs).
    pub lights: u32,
    /// Whether the lights cast shadows (their shadow maps are sampled).
    pub shadows: bool,
}

/// What a [`LambertMaterial`]'s pipeline is compiled for.
#[repr(C)]
#[derive(Copy, Clone, Debug, Hash, PartialEq, Eq)]
pub struct LambertKey {
    kind: u32,
    lights: u32,
    shadows: bool,
    specular: bool,
    batched: bool,
}

impl From<&LambertMaterial> for LambertKey {
    fn from(m: &LambertMaterial) -> Self {
        Self { kind: m.kind, lights: m.lights, shadows: m.shadows, specular: m.specular > 0.0, batched: m.batched }
    }
}

impl LambertMaterial {
    pub fn new(color: Color) -> Self {
        Self {
            color: color.to_linear(),
            color2: LinearRgba::BLACK,
            kind: PLAIN,
            size: 1.0,
            specular: 0.0,
            image: None,
            views: ARENA_VIEWS,
            surfaces: SURFACES,
            batched: false,
            lights: 1,
            shadows: false,
        }
    }

    /// A look's surface; `image` is the loaded image of an image texture.
    pub fn of_surface(surface: &Surface, image: Option<Handle<Image>>) -> Self {
        let Surface { color, texture, specular } = surface;
        let srgb = |[r, g, b]: [f32; 3]| Color::srgb(r, g, b).to_linear();
        let base = Self { specular: *specular, ..Self::new(Color::srgb(color[0], color[1], color[2])) };
        let (kind, color2, size) = match texture {
            Texture::Plain => return base,
            Texture::Checker { color, size } => (CHECKER, srgb(*color), *size),
            Texture::Noise { color, size } => (NOISE, srgb(*color), *size),
            Texture::Gradient { color, size } => (GRADIENT, srgb(*color), *size),
            Texture::Image { size, .. } => (IMAGE, LinearRgba::WHITE, *size),
        };
        Self { kind, color2, size, image, ..base }
    }

    /// The material batched frames draw instances through: one per image texture (and one
    /// without).
    pub fn batched(image: Option<Handle<Image>>) -> Self {
        let kind = if image.is_some() { IMAGE } else { PLAIN };
        Self { kind, image, batched: true, ..Self::new(Color::WHITE) }
    }
}

impl Material for LambertMaterial {
    fn vertex_shader() -> ShaderRef {
        LAMBERT_SHADER.into()
    }

    fn fragment_shader() -> ShaderRef {
        LAMBERT_SHADER.into()
    }

    fn specialize(
        _pipeline: &MaterialPipeline,
        descriptor: &mut RenderPipelineDescriptor,
        _layout: &MeshVertexBufferLayoutRef,
        key: MaterialPipelineKey<Self>,
    ) -> Result<(), SpecializedMeshPipelineError> {
        // One file holds both stages: each is compiled with every def.
        let key = key.bind_group_data;
        let mut defs =
            vec![ShaderDefVal::UInt("PATTERN".into(), key.kind), ShaderDefVal::UInt("LIGHTS".into(), key.lights)];
        for (on, def) in [(key.shadows, "SHADOWS"), (key.specular, "SPECULAR"), (key.batched, "BATCHED")] {
            if on {
                defs.push(def.into());
            }
        }
        if key.batched {
            descriptor.vertex.shader = BATCHED_VERTEX_SHADER;
        }
        descriptor.vertex.shader_defs.extend(defs.iter().cloned());
        if let Some(fragment) = descriptor.fragment.as_mut() {
            fragment.shader_defs.extend(defs);
        }
        Ok(())
    }
}

const LAMBERT_SHADER: Handle<Shader> = uuid_handle!("0f4b8f3e-6a51-4d2c-8a3b-1e9d7c5a2f10");
const BATCHED_VERTEX_SHADER: Handle<Shader> = uuid_handle!("a3c5e7f9-1b2d-4e6f-8a0c-2d4f6b8e0a13");

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
fn init_buffers(world: &mut World) {
    let mut buffers = world.resource_mut::<Assets<ShaderBuffer>>();
    let kept = |b: ShaderBuffer| ShaderBuffer { asset_usage: RenderAssetUsages::default(), ..b };
    let _ = buffers.insert(&ARENA_VIEWS, kept(ShaderBuffer::from(vec![ArenaView::default()])));
    let _ = buffers.insert(&SURFACES, kept(ShaderBuffer::from(vec![SurfaceRecord::default()])));
}

/// Registers [`LambertMaterial`] and its shaders (embedded in the binary), and batched frames'
/// buffers (empty).
pub struct ShadingPlugin;

impl Plugin for ShadingPlugin {
    fn build(&self, app: &mut App) {
        // Shaders under fixed handles: one process may hold several render apps.
        load_internal_asset!(app, LAMBERT_SHADER, "lambert.wgsl", Shader::from_wgsl);
        load_internal_asset!(app, BATCHED_VERTEX_SHADER, "batched_vertex.wgsl", Shader::from_wgsl);
        app.add_plugins(MaterialPlugin::<LambertMaterial>::default());
        init_buffers(app.world_mut());
    }
}
