//! How the twin is shaded: [`LambertMaterial`], diffuse light from the scene's sun plus an
//! ambient share, no specular.
//!
//! Pixels are rendered on the CPU wherever there is no GPU (Mesa's lavapipe: CI, training
//! servers). There Bevy's PBR `StandardMaterial` cost ~40 % of a 640×480 frame (82 ms per frame
//! against 51 ms unlit, measured on a 2-core VM); diffuse shading costs about what unlit does
//! and still shows the shapes and their orientation, which is what people and camera sensors
//! need from the twin.

use bevy::asset::embedded_asset;
use bevy::prelude::*;
use bevy::render::render_resource::AsBindGroup;
use bevy::shader::ShaderRef;

/// A flat colour lit by the sun (Lambert's cosine law) over an ambient floor.
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
pub struct LambertMaterial {
    /// Linear RGBA; alpha is ignored (surfaces are opaque).
    #[uniform(0)]
    pub color: LinearRgba,
}

impl LambertMaterial {
    pub fn new(color: Color) -> Self {
        Self { color: color.to_linear() }
    }
}

impl Material for LambertMaterial {
    fn fragment_shader() -> ShaderRef {
        "embedded://twinbots_render/lambert.wgsl".into()
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
