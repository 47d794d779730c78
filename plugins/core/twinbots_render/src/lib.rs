//! twinbots_render: seeing the digital twin. Off-screen PNG frames of an arena through a camera,
//! and camera sensors; the sim itself never needs a GPU, and headless training never adds any
//! of this.

pub mod batch;
pub mod cameras;
pub mod coords;
pub mod pixels;
pub mod recorder;
pub mod renderer;
pub mod scene;
pub mod shading;
pub mod viewer;

pub use cameras::{CameraPlugin, CameraRig};
pub use pixels::PixelSettings;
pub use renderer::{Framing, RenderError, Renderer, View, adapter_required};
pub use shading::{LambertMaterial, ShadingPlugin};
