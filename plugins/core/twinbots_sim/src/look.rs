//! How an arena looks this episode: its lights, the colours and textures of its surfaces, and a
//! jitter of the cameras that watch it. Plain data: visual domain randomization
//! (`twinbots_task::visual`) draws one per arena at every reset, the renderer
//! (`twinbots_render`) shows it, and `capture` records it beside the frames (JSON), so a frame
//! can be reproduced. An arena without a `Look` component looks like [`Look::default`].

use std::collections::BTreeMap;
use std::path::PathBuf;

use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// The look of one arena (a component of the arena entity).
#[derive(Component, Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Look {
    /// Directional lights (at most [`Look::MAX_LIGHTS`]).
    pub lights: Vec<Light>,
    /// Ambient light, linear RGB: the share of a surface's colour seen where no light reaches.
    pub ambient: [f32; 3],
    /// A change of every camera's pose and field of view (camera sensors and `capture`'s view).
    pub camera: CameraJitter,
    /// Surfaces by name: `floor`, `static/<i>` (the arena's i-th fixed box, see
    /// `Arena::static_boxes`), `<link>/<i>` (a link's i-th URDF visual; a repeated link name
    /// is numbered, `nest#2/<i>`, see [`Look::link_names`]). A surface not named keeps its own
    /// colour.
    pub surfaces: BTreeMap<String, Surface>,
    /// Boxes that are seen but not there (no collider): clutter for a camera policy to ignore.
    #[serde(default)]
    pub distractors: Vec<Distractor>,
}

/// A box drawn in the scene, not simulated.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Distractor {
    /// Metres, physics coordinates: the box's centre.
    pub centre: [f32; 3],
    pub half_extents: [f32; 3],
    /// Radians about Z.
    pub yaw: f32,
    pub surface: Surface,
}

/// A directional light (a sun).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Light {
    /// The direction the light travels, in physics coordinates (Z up); need not be unit length.
    pub direction: [f32; 3],
    /// Linear RGB.
    pub color: [f32; 3],
    /// Relative intensity: a surface facing a light of intensity 1 and colour white, with no
    /// ambient, shows exactly its own colour.
    pub intensity: f32,
}

/// A camera's pose and field of view, changed (robosuite's camera randomization).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraJitter {
    /// Metres, added to the eye's position (physics coordinates).
    pub offset: [f32; 3],
    /// Radians, a rotation vector applied to the camera's orientation in its own frame.
    pub rotation: [f32; 3],
    /// Radians added to the vertical field of view.
    pub fov: f32,
}

/// What a surface shows: a colour, and a texture over it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Surface {
    /// sRGB in [0, 1], like a URDF material's `rgba`.
    pub color: [f32; 3],
    pub texture: Texture,
    /// Strength of the lights' highlight (Blinn-Phong, exponent 32), 0 for none.
    #[serde(default)]
    pub specular: f32,
}

/// A surface texture. Patterns are laid out in metres on the surface (`size`: a checker's
/// square, a noise cell, a gradient's period), so they keep their scale on any shape.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Texture {
    /// The colour alone.
    Plain,
    /// Squares alternating between the surface's colour and `color` (sRGB).
    Checker { color: [f32; 3], size: f32 },
    /// Value noise between the surface's colour and `color`.
    Noise { color: [f32; 3], size: f32 },
    /// A ramp from the surface's colour to `color` and back over `size`.
    Gradient { color: [f32; 3], size: f32 },
    /// An image file (PNG), tiled every `size` metres and tinted by the surface's colour.
    Image { path: PathBuf, size: f32 },
}

impl Look {
    /// Bevy's shaders take ten directional lights at most.
    pub const MAX_LIGHTS: usize = 10;

    /// The surface name of a link's visual (`link`: its name from [`Look::link_names`]).
    pub fn link_surface(link: &str, visual: usize) -> String {
        format!("{link}/{visual}")
    }

    /// Unique names for an arena's links, in spawn (entity) order: a link name that repeats
    /// (two fixtures from one URDF) is numbered from its second occurrence on (`nest`,
    /// `nest#2`), so each gets its own surfaces.
    pub fn link_names<'a>(links: impl Iterator<Item = (Entity, &'a str)>) -> Vec<(Entity, String)> {
        let mut links: Vec<(Entity, &str)> = links.collect();
        links.sort_by_key(|(e, _)| *e);
        let mut seen: BTreeMap<&str, usize> = BTreeMap::new();
        links
            .into_iter()
            .map(|(e, name)| {
                let n = seen.entry(name).or_default();
                *n += 1;
                (e, if *n == 1 { name.to_string() } else { format!("{name}#{n}") })
            })
            .collect()
    }

    /// The surface name of a [`crate::Marker`].
    pub fn marker_surface(name: &str) -> String {
        format!("marker/{name}")
    }

    /// The surface name of an arena's fixed box.
    pub fn static_surface(index: usize) -> String {
        format!("static/{index}")
    }
}

impl Default for Look {
    /// The twin's look without randomization: one sun from above and to the side (60 % of full
    /// intensity) over a 40 % white ambient, the surfaces' own colours, cameras as placed.
    fn default() -> Self {
        Self {
            lights: vec![Light { direction: [-2.0, 3.0, -6.0], color: [1.0; 3], intensity: 0.6 }],
            ambient: [0.4; 3],
            camera: CameraJitter::default(),
            surfaces: BTreeMap::new(),
            distractors: Vec::new(),
        }
    }
}
