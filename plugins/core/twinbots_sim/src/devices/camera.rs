//! Webots' Camera: a mounted pinhole camera whose RGB image a task may observe. The component
//! is plain data; `twinbots_render` renders it (the sim itself never needs a GPU).

use bevy::prelude::*;

/// A camera looking along its mount's +X with +Z up (Webots' convention for devices).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct CameraSensor {
    /// Vertical field of view (rad).
    pub fov_y: f32,
    pub width: u32,
    pub height: u32,
    /// The latest image, RGB8, row-major from the top-left; empty until first rendered.
    pub image: Vec<u8>,
    /// Control step of the latest image.
    pub captured_at: Option<u64>,
}

impl CameraSensor {
    pub fn new(fov_y: f32, width: u32, height: u32) -> Self {
        Self { fov_y, width, height, image: Vec::new(), captured_at: None }
    }

    /// The RGB pixel at (x, y), if an image exists.
    pub fn pixel(&self, x: u32, y: u32) -> Option<[u8; 3]> {
        let i = ((y * self.width + x) * 3) as usize;
        self.image.get(i..i + 3).map(|p| [p[0], p[1], p[2]])
    }
}

/// The latest image a pixel task observed of its arena (every camera's, side by side along
/// the width), on the arena's entity: what a viewer of the run is shown. The observation itself
/// is the task's; this is a copy, RGB8, row-major from the top-left, kept only in an app that
/// asks for it ([`KeepObservedImages`]).
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct ObservedImage {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// Present in an app whose pixel observations should also be kept as [`ObservedImage`]s (one
/// with a live view): without it no copy is made.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct KeepObservedImages;
