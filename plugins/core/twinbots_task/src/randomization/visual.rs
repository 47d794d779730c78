//! Visual domain randomization (`[randomization.visual]` in a run's TOML): at every reset each
//! arena draws a new [`Look`] — surface colours and textures, lights, a camera jitter — from a
//! stream of its own (seed, arena index), apart from the physics stream: switching it on
//! changes no trajectory, and the same seed draws the same looks. The defaults of the table's
//! keys are robosuite's `DomainRandomizationWrapper` ranges where it has them (camera ±1 cm,
//! ±0.087 rad, field of view ±5°).

use std::path::PathBuf;

use bevy::prelude::*;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use twinbots_sim::look::{CameraJitter, Distractor, Light, Surface, Texture};
use twinbots_sim::{Arena, InArena, Link, Look, Visuals};

use super::{uniform, uniform_count};
use crate::task::Resetting;

/// Surfaces the table's `surfaces` key can name.
pub const SURFACE_GROUPS: [&str; 3] = ["floor", "tables", "links"];
/// Textures the table's `textures` key can name.
pub const TEXTURE_KINDS: [&str; 5] = ["plain", "checker", "noise", "gradient", "image"];

/// `[randomization.visual]`. Ranges are `[low, high]`, drawn uniformly per arena and episode;
/// a `±` value is drawn uniformly in `[-v, v]`.
#[derive(Resource, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VisualRandomization {
    /// Which surfaces change: `floor`, `tables` (the cell's fixed boxes), `links` (robot links
    /// and parts).
    pub surfaces: Vec<String>,
    /// Texture kinds drawn from (uniformly): plain, checker, noise, gradient, image.
    pub textures: Vec<String>,
    /// PNG files for the `image` texture kind.
    pub images: Vec<PathBuf>,
    /// Metres: a checker's square, a noise cell, a gradient's period, an image's tile.
    pub texture_size: [f32; 2],
    /// Colours are drawn in HSV: any hue, saturation and value in these ranges.
    pub saturation: [f32; 2],
    pub value: [f32; 2],
    /// Each surface's highlight strength (Blinn-Phong); off by default, as it costs a little
    /// per pixel where drawn.
    pub specular: [f32; 2],
    /// How many directional lights.
    pub lights: [u32; 2],
    /// Each light's relative intensity (1: a surface facing it shows its own colour).
    pub light_intensity: [f32; 2],
    /// Each light's colour: every channel scaled by a draw in [1 − tint, 1].
    pub light_tint: f32,
    /// Degrees above the horizon a light comes from (its azimuth is any).
    pub light_elevation: [f32; 2],
    /// The ambient share (white).
    pub ambient: [f32; 2],
    /// ± metres per axis of every camera's eye.
    pub camera_position: f32,
    /// ± radians per axis of every camera's orientation.
    pub camera_rotation: f32,
    /// ± degrees of every camera's vertical field of view.
    pub field_of_view: f32,
    /// How many distractors: boxes drawn on the cell's tables (on the floor near the origin
    /// without one), seen by cameras but not simulated.
    pub distractors: [u32; 2],
    /// Metres: each distractor's half extent along each axis.
    pub distractor_size: [f32; 2],
}

impl Default for VisualRandomization {
    fn default() -> Self {
        Self {
            surfaces: SURFACE_GROUPS.map(String::from).to_vec(),
            textures: ["plain", "checker", "noise", "gradient"].map(String::from).to_vec(),
            images: Vec::new(),
            texture_size: [0.02, 0.3],
            saturation: [0.0, 0.9],
            value: [0.2, 0.95],
            specular: [0.0, 0.0],
            lights: [1, 3],
            light_intensity: [0.3, 0.9],
            light_tint: 0.3,
            light_elevation: [20.0, 85.0],
            ambient: [0.15, 0.6],
            camera_position: 0.01,
            camera_rotation: 0.087,
            field_of_view: 5.0,
            distractors: [0, 0],
            distractor_size: [0.015, 0.05],
        }
    }
}

impl VisualRandomization {
    /// A clear error, naming the key, for anything that could not be drawn or shown.
    pub fn validate(&self) -> anyhow::Result<()> {
        let key = |k: &str| format!("randomization.visual.{k}");
        let range = |k: &str, [lo, hi]: [f32; 2], min: f32, max: f32| {
            anyhow::ensure!(
                lo.is_finite() && hi.is_finite() && lo <= hi && lo >= min && hi <= max,
                "{} = [{lo}, {hi}]: must be finite, ordered and in [{min}, {max}]",
                key(k)
            );
            Ok(())
        };
        let plus_minus = |k: &str, v: f32, max: f32, unit: &str| {
            anyhow::ensure!(
                v.is_finite() && (0.0..max).contains(&v),
                "{} = {v}: must be a finite ± {unit} in [0, {max})",
                key(k)
            );
            Ok(())
        };
        for s in &self.surfaces {
            anyhow::ensure!(
                SURFACE_GROUPS.contains(&s.as_str()),
                "{}: unknown surface '{s}'; surfaces: {}",
                key("surfaces"),
                SURFACE_GROUPS.join(", ")
            );
        }
        anyhow::ensure!(
            !self.textures.is_empty(),
            "{}: name at least one of {}",
            key("textures"),
            TEXTURE_KINDS.join(", ")
        );
        for t in &self.textures {
            anyhow::ensure!(
                TEXTURE_KINDS.contains(&t.as_str()),
                "{}: unknown texture '{t}'; textures: {}",
                key("textures"),
                TEXTURE_KINDS.join(", ")
            );
        }
        let wants_images = self.textures.iter().any(|t| t == "image");
        anyhow::ensure!(
            wants_images != self.images.is_empty(),
            "{}: the `image` texture and image files go together (textures has {}image, images lists {} files)",
            key("images"),
            if wants_images { "" } else { "no " },
            self.images.len()
        );
        for (i, path) in self.images.iter().enumerate() {
            let bytes = std::fs::read(path)
                .map_err(|e| anyhow::anyhow!("{}[{i}] = '{}': {e}", key("images"), path.display()))?;
            image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).map_err(|e| {
                anyhow::anyhow!("{}[{i}] = '{}': not a PNG image this can read: {e}", key("images"), path.display())
            })?;
        }
        range("texture_size", self.texture_size, 1e-3, 100.0)?;
        range("saturation", self.saturation, 0.0, 1.0)?;
        range("value", self.value, 0.0, 1.0)?;
        range("specular", self.specular, 0.0, 1.0)?;
        let [lo, hi] = self.lights;
        anyhow::ensure!(
            lo <= hi && hi as usize <= Look::MAX_LIGHTS,
            "{} = [{lo}, {hi}]: must be ordered and at most {}",
            key("lights"),
            Look::MAX_LIGHTS
        );
        range("light_intensity", self.light_intensity, 0.0, 100.0)?;
        anyhow::ensure!(
            self.light_tint.is_finite() && (0.0..=1.0).contains(&self.light_tint),
            "{} = {}: must be in [0, 1]",
            key("light_tint"),
            self.light_tint
        );
        range("light_elevation", self.light_elevation, 0.0, 90.0)?;
        range("ambient", self.ambient, 0.0, 100.0)?;
        plus_minus("camera_position", self.camera_position, 10.0, "metres")?;
        plus_minus("camera_rotation", self.camera_rotation, std::f32::consts::PI, "radians")?;
        // Any field of view must stay inside (0°, 180°): a jitter of 90° or more could leave it.
        plus_minus("field_of_view", self.field_of_view, 90.0, "degrees")?;
        let [lo, hi] = self.distractors;
        anyhow::ensure!(
            lo <= hi && hi <= 100,
            "{} = [{lo}, {hi}]: must be ordered and at most 100",
            key("distractors")
        );
        range("distractor_size", self.distractor_size, 1e-3, 1.0)?;
        Ok(())
    }

    /// The look of one arena for one episode. `links`: (link name, its visuals' count);
    /// `statics`: the arena's fixed boxes (half extents, centre).
    pub fn draw(&self, rng: &mut impl Rng, links: &[(String, usize)], statics: &[(Vec3, Vec3)]) -> Look {
        let has = |group: &str| self.surfaces.iter().any(|s| s == group);
        let mut look = Look::default();
        look.surfaces.clear();
        if has("floor") {
            look.surfaces.insert("floor".into(), self.surface(rng));
        }
        if has("tables") {
            for i in 0..statics.len() {
                look.surfaces.insert(Look::static_surface(i), self.surface(rng));
            }
        }
        if has("links") {
            for (name, count) in links {
                for i in 0..*count {
                    look.surfaces.insert(Look::link_surface(name, i), self.surface(rng));
                }
            }
        }
        look.lights = (0..uniform_count(rng, self.lights)).map(|_| self.light(rng)).collect();
        let a = uniform(rng, self.ambient);
        look.ambient = [a; 3];
        look.camera = CameraJitter {
            offset: [0; 3].map(|_| plus_minus(rng, self.camera_position)),
            rotation: [0; 3].map(|_| plus_minus(rng, self.camera_rotation)),
            fov: plus_minus(rng, self.field_of_view).to_radians(),
        };
        look.distractors = (0..uniform_count(rng, self.distractors)).map(|_| self.distractor(rng, statics)).collect();
        look
    }

    /// A box on a random table's top (or on the floor within a metre of the origin).
    fn distractor(&self, rng: &mut impl Rng, statics: &[(Vec3, Vec3)]) -> Distractor {
        let half = [0; 3].map(|_| uniform(rng, self.distractor_size));
        let (centre, spread, floor) = match statics {
            [] => (Vec3::ZERO, Vec2::ONE, 0.0),
            tables => {
                let (h, c) = tables[rng.random_range(0..tables.len())];
                (c, 0.9 * h.truncate(), c.z + h.z)
            }
        };
        let x = centre.x + plus_minus(rng, spread.x);
        let y = centre.y + plus_minus(rng, spread.y);
        let yaw = rng.random_range(0.0..std::f32::consts::PI);
        Distractor { centre: [x, y, floor + half[2]], half_extents: half, yaw, surface: self.surface(rng) }
    }

    fn surface(&self, rng: &mut impl Rng) -> Surface {
        let color = self.color(rng);
        let size = uniform(rng, self.texture_size);
        let kind = &self.textures[rng.random_range(0..self.textures.len())];
        let texture = match kind.as_str() {
            "checker" => Texture::Checker { color: self.color(rng), size },
            "noise" => Texture::Noise { color: self.color(rng), size },
            "gradient" => Texture::Gradient { color: self.color(rng), size },
            "image" => Texture::Image { path: self.images[rng.random_range(0..self.images.len())].clone(), size },
            _ => Texture::Plain,
        };
        Surface { color, texture, specular: uniform(rng, self.specular) }
    }

    fn color(&self, rng: &mut impl Rng) -> [f32; 3] {
        let hue = rng.random_range(0.0..360.0);
        let (s, v) = (uniform(rng, self.saturation), uniform(rng, self.value));
        let c = Color::hsv(hue, s, v).to_srgba();
        [c.red, c.green, c.blue]
    }

    fn light(&self, rng: &mut impl Rng) -> Light {
        let azimuth = rng.random_range(0.0..std::f32::consts::TAU);
        let elevation = uniform(rng, self.light_elevation).to_radians();
        let towards = Vec3::new(elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), elevation.sin());
        let t = self.light_tint;
        let color = [0; 3].map(|_| if t > 0.0 { rng.random_range(1.0 - t..=1.0) } else { 1.0 });
        Light { direction: (-towards).to_array(), color, intensity: uniform(rng, self.light_intensity) }
    }
}

fn plus_minus(rng: &mut impl Rng, v: f32) -> f32 {
    if v > 0.0 { rng.random_range(-v..=v) } else { 0.0 }
}

/// An arena's stream of looks (apart from its physics stream), and the arena's reseed count
/// when it started.
#[derive(Component)]
pub struct LookStream {
    reseeds: u64,
    rng: ChaCha8Rng,
}

pub struct VisualRandomizationPlugin(pub VisualRandomization);

impl Plugin for VisualRandomizationPlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(self.0.clone())
            .add_systems(crate::task::EnvReset, draw_looks.in_set(crate::task::ResetSet::Place));
    }
}

/// At every reset, a new look per arena. The stream restarts whenever the arena is re-seeded
/// (a `reset(seed)`), so a seed fixes the looks as it fixes the physics.
fn draw_looks(
    config: Res<VisualRandomization>,
    mut commands: Commands,
    mut arenas: Query<(Entity, &Arena, Option<&mut LookStream>), With<Resetting>>,
    links: Query<(Entity, &Link, &Visuals, &InArena)>,
) {
    for (entity, arena, stream) in &mut arenas {
        let (own, statics) = drawn_over(entity, arena, links.iter());
        let look = match stream {
            Some(mut s) if s.reseeds == arena.reseeds() => config.draw(&mut s.rng, &own, &statics),
            _ => {
                let mut fresh =
                    LookStream { reseeds: arena.reseeds(), rng: arena.side_stream(twinbots_api::seeds::LOOKS) };
                let look = config.draw(&mut fresh.rng, &own, &statics);
                commands.entity(entity).insert(fresh);
                look
            }
        };
        commands.entity(entity).insert(look);
    }
}

/// What an arena's look is drawn over: its links (name, visuals' count) in name order, so that
/// the draw does not depend on the order links were spawned in, and its fixed boxes.
fn drawn_over<'a>(
    entity: Entity,
    arena: &Arena,
    links: impl Iterator<Item = (Entity, &'a Link, &'a Visuals, &'a InArena)>,
) -> (Vec<(String, usize)>, Vec<(Vec3, Vec3)>) {
    let own: Vec<(Entity, &Link, &Visuals)> =
        links.filter(|(_, _, _, a)| a.0 == entity).map(|(e, l, v, _)| (e, l, v)).collect();
    let names = Look::link_names(own.iter().map(|(e, l, _)| (*e, l.name.as_str())));
    let counts: std::collections::HashMap<Entity, usize> = own.iter().map(|(e, _, v)| (*e, v.0.len())).collect();
    let mut own: Vec<(String, usize)> = names.into_iter().map(|(e, name)| (name, counts[&e])).collect();
    own.sort();
    let statics = arena.static_boxes().map(|(h, pose)| (h, pose.translation)).collect();
    (own, statics)
}

/// A new look for every arena now, mid-episode, drawn from `rng` by the world's
/// [`VisualRandomization`] (the arenas' own streams untouched). For collecting labelled images
/// where each shows a look of its own (examples/pixel_probe.rs): with a look per episode, an
/// encoder can learn which look goes with which label instead of reading the label off the
/// picture. Does nothing in a world without visual randomization.
pub fn redraw_looks(world: &mut World, rng: &mut impl Rng) {
    let Some(config) = world.get_resource::<VisualRandomization>().cloned() else { return };
    let mut links = world.query::<(Entity, &Link, &Visuals, &InArena)>();
    let mut arenas = world.query::<(Entity, &Arena)>();
    let looks: Vec<(Entity, Look)> = arenas
        .iter(world)
        .map(|(entity, arena)| {
            let (own, statics) = drawn_over(entity, arena, links.iter(world));
            (entity, config.draw(rng, &own, &statics))
        })
        .collect();
    for (entity, look) in looks {
        world.entity_mut(entity).insert(look);
    }
}
