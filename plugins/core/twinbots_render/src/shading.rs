//! How the twin is shaded: [`LambertMaterial`], a surface colour (optionally patterned or
//! textured) lit by the scene's directional lights (Lambert's cosine law, their colours and
//! intensities) over its ambient light; no specular.
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
//! The light model, in linear RGB: `pixel = albedo × (ambient + Σ colourᵢ × intensityᵢ ×
//! max(0, n·lᵢ)) + specular × Σ colourᵢ × intensityᵢ × max(0, n·hᵢ)^32` (Blinn-Phong, hᵢ halfway
//! between the light and the eye, only where the light reaches), where Bevy carries a light's relative intensity as its `illuminance` and the
//! ambient share as `GlobalAmbientLight::brightness` (see `twinbots_sim::look`).

use bevy::asset::embedded_asset;
use bevy::mesh::MeshVertexBufferLayoutRef;
use bevy::pbr::{MaterialPipeline, MaterialPipelineKey};
use bevy::prelude::*;
use bevy::render::render_resource::{AsBindGroup, RenderPipelineDescriptor, SpecializedMeshPipelineError};
use bevy::shader::{ShaderDefVal, ShaderRef};
use twinbots_sim::look::{Surface, Texture};

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
}

impl From<&LambertMaterial> for LambertKey {
    fn from(m: &LambertMaterial) -> Self {
        Self { kind: m.kind, lights: m.lights, shadows: m.shadows, specular: m.specular > 0.0 }
    }
}

impl LambertMaterial {
    pub fn new(color: Color) -> Self {
        Self { color: color.to_linear(), color2: LinearRgba::BLACK, kind: PLAIN, size: 1.0, specular: 0.0, image: None, lights: 1, shadows: false }
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
}

impl Material for LambertMaterial {
    fn fragment_shader() -> ShaderRef {
        "embedded://twinbots_render/lambert.wgsl".into()
    }

    fn specialize(
        _pipeline: &MaterialPipeline,
        descriptor: &mut RenderPipelineDescriptor,
        _layout: &MeshVertexBufferLayoutRef,
        key: MaterialPipelineKey<Self>,
    ) -> Result<(), SpecializedMeshPipelineError> {
        if let Some(fragment) = descriptor.fragment.as_mut() {
            fragment.shader_defs.push(ShaderDefVal::UInt("PATTERN".into(), key.bind_group_data.kind));
            fragment.shader_defs.push(ShaderDefVal::UInt("LIGHTS".into(), key.bind_group_data.lights));
            if key.bind_group_data.shadows {
                fragment.shader_defs.push("SHADOWS".into());
            }
            if key.bind_group_data.specular {
                fragment.shader_defs.push("SPECULAR".into());
            }
        }
        Ok(())
    }
}

/// Registers [`LambertMaterial`] and its shader (embedded in the binary).
pub struct ShadingPlugin;

impl Plugin for ShadingPlugin {
    fn build(&self, app: &mut App) {
        embedded_asset!(app, "lambert.wgsl");
        app.add_plugins(MaterialPlugin::<LambertMaterial>::default());
    }
}
