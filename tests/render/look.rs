//! What an arena's `Look` shows: a known colour under known lights gives the pixel the light
//! model says; textures pattern the surface; visual randomization in `capture` is seeded and
//! recorded.

use std::collections::BTreeMap;
use std::process::Command;

use bevy::prelude::*;
use twinbots_render::{CameraRig, RenderError};
use twinbots_sim::look::{CameraJitter, Distractor, Light, Surface, Texture};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::parse_urdf;
use twinbots_sim::{Arena, CameraSensor, InArena, Look, Mount, SimPlugin, SimSettings, SpawnOptions, spawn_robot};

/// The wall's colour (sRGB) in its URDF.
const WALL: [f32; 3] = [0.8, 0.4, 0.2];
const SCENE: &str = r#"<robot name="wall"><link name="wall">
  <visual><geometry><box size="0.05 2 2"/></geometry><material name="w"><color rgba="0.8 0.4 0.2 1"/></material></visual>
</link></robot>"#;
const POST: &str = r#"<robot name="post"><link name="post"/></robot>"#;

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

fn linear_to_srgb8(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    255.0 * if c <= 0.0031308 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

/// A camera at the origin (0.5 m up) looking along +X at a 2 m wall 1 m away whose face (normal
/// −X) fills the picture; the arena wears `look`. Returns the centre pixel and the whole image.
fn wall_seen_under(look: Look) -> Result<([u8; 3], Vec<u8>), RenderError> {
    let mut app = App::new();
    app.add_plugins(MinimalPlugins).add_plugins(SimPlugin::default());
    let world = app.world_mut();
    let arena_entity = world.spawn_empty().id();
    let mut arena = Arena::new(0, 0, SimSettings::default().dt, SimSettings::default().gravity);
    let model = |text: &str| parse_urdf(text, "t.urdf".as_ref(), ".".as_ref()).unwrap();
    let at =
        |x: f32| SpawnOptions { base: Pose::from_translation(Vec3::new(x, 0.0, 0.5)), fixed_base: true, ..default() };
    let mut queue = bevy::ecs::world::CommandQueue::default();
    let post = {
        let mut commands = Commands::new(&mut queue, world);
        spawn_robot(&mut commands, arena_entity, &mut arena, &model(SCENE), at(1.0));
        spawn_robot(&mut commands, arena_entity, &mut arena, &model(POST), at(0.0))
    };
    queue.apply(world);
    arena.mark_initial();
    world.entity_mut(arena_entity).insert((arena, look));
    let camera = world
        .spawn((
            CameraSensor::new(40f32.to_radians(), 32, 24),
            Mount { link: post.link("post").unwrap(), offset: Pose::IDENTITY },
            InArena(arena_entity),
        ))
        .id();
    app.update();
    let mut rig = CameraRig::default();
    rig.sample(app.world_mut())?;
    let sensor = app.world().get::<CameraSensor>(camera).unwrap();
    Ok((sensor.pixel(16, 12).unwrap(), sensor.image.clone()))
}

fn look(lights: Vec<Light>, ambient: f32, surfaces: BTreeMap<String, Surface>) -> Look {
    Look { lights, ambient: [ambient; 3], camera: CameraJitter::default(), surfaces, distractors: Vec::new() }
}

#[test]
fn a_known_colour_under_known_lights_gives_the_pixel_of_the_light_model() {
    if crate::renderer("a_known_colour_under_known_lights_gives_the_pixel_of_the_light_model", 8, 8).is_none() {
        return;
    }
    // Light travelling +X falls straight onto the wall's −X face; the second comes in at 60°
    // from the face's normal (cos = 0.5); a third from behind the wall adds nothing.
    let head_on = Light { direction: [1.0, 0.0, 0.0], color: [1.0, 0.8, 0.5], intensity: 0.7 };
    let slanted = Light { direction: [0.5, 0.0, -(0.75f32).sqrt()], color: [0.2, 0.4, 1.0], intensity: 0.6 };
    let behind = Light { direction: [-1.0, 0.0, 0.0], color: [1.0; 3], intensity: 5.0 };
    let cases = [
        (vec![head_on.clone()], 0.1, [0.1 + 0.7, 0.1 + 0.56, 0.1 + 0.35]),
        (vec![head_on, slanted, behind], 0.05, [0.05 + 0.7 + 0.06, 0.05 + 0.56 + 0.12, 0.05 + 0.35 + 0.3]),
        (vec![], 0.5, [0.5; 3]),
    ];
    for (lights, ambient, light) in cases {
        let (pixel, _) = wall_seen_under(look(lights.clone(), ambient, BTreeMap::new())).unwrap();
        let expected: Vec<f32> = (0..3).map(|c| linear_to_srgb8(srgb_to_linear(WALL[c]) * light[c])).collect();
        for c in 0..3 {
            assert!(
                (pixel[c] as f32 - expected[c]).abs() <= 2.0,
                "{} lights, ambient {ambient}: pixel {pixel:?}, the model says {expected:?}",
                lights.len()
            );
        }
    }
    // A highlight: the light and the eye straight in front of the wall, so n·h = 1 and the
    // surface adds specular × the light's colour × intensity to the diffuse term.
    let white = vec![Light { direction: [1.0, 0.0, 0.0], color: [1.0; 3], intensity: 0.5 }];
    let shiny =
        BTreeMap::from([("wall/0".to_string(), Surface { color: WALL, texture: Texture::Plain, specular: 0.5 })]);
    let (pixel, _) = wall_seen_under(look(white, 0.1, shiny)).unwrap();
    let expected: Vec<f32> = (0..3).map(|c| linear_to_srgb8(srgb_to_linear(WALL[c]) * 0.6 + 0.5 * 0.5)).collect();
    assert!(
        pixel.iter().zip(&expected).all(|(p, e)| (*p as f32 - e).abs() <= 2.0),
        "specular: {pixel:?}, the model says {expected:?}"
    );
}

#[test]
fn textures_pattern_a_surface_in_metres_and_an_unreadable_image_is_an_error() {
    if crate::renderer("textures_pattern_a_surface_in_metres_and_an_unreadable_image_is_an_error", 8, 8).is_none() {
        return;
    }
    let white = vec![Light { direction: [1.0, 0.0, 0.0], color: [1.0; 3], intensity: 1.0 }];
    let on_wall = |texture: Texture| {
        BTreeMap::from([("wall/0".to_string(), Surface { color: [1.0, 0.0, 0.0], texture, specular: 0.0 })])
    };
    // Red and blue squares of 10 cm: the 32-pixel-wide view of 0.73 m of wall shows both, in
    // about equal shares, and nothing else.
    let (_, image) =
        wall_seen_under(look(white.clone(), 0.0, on_wall(Texture::Checker { color: [0.0, 0.0, 1.0], size: 0.1 })))
            .unwrap();
    let pixels: Vec<[u8; 3]> = image.chunks(3).map(|p| [p[0], p[1], p[2]]).collect();
    let red = pixels.iter().filter(|p| p[0] > 240 && p[2] < 15).count();
    let blue = pixels.iter().filter(|p| p[2] > 240 && p[0] < 15).count();
    assert!(red > 200 && blue > 200 && red + blue > 32 * 24 - 80, "red {red}, blue {blue} of {}", 32 * 24);
    // An image texture, tinted by the surface colour (white here): its pixels show.
    let dir = std::env::temp_dir().join(format!("twinbots-texture-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let green = dir.join("green.png");
    image::RgbImage::from_pixel(8, 8, image::Rgb([20, 200, 40])).save(&green).unwrap();
    let surfaces = BTreeMap::from([(
        "wall/0".to_string(),
        Surface { color: [1.0; 3], texture: Texture::Image { path: green, size: 0.2 }, specular: 0.0 },
    )]);
    let (pixel, _) = wall_seen_under(look(white.clone(), 0.0, surfaces)).unwrap();
    assert!(pixel.iter().zip([20u8, 200, 40]).all(|(a, b)| a.abs_diff(b) <= 2), "{pixel:?}");
    // An image that is not there: the frame fails, naming the file.
    let missing = BTreeMap::from([(
        "wall/0".to_string(),
        Surface { color: [1.0; 3], texture: Texture::Image { path: dir.join("gone.png"), size: 0.2 }, specular: 0.0 },
    )]);
    let message = wall_seen_under(look(white.clone(), 0.0, missing)).unwrap_err().to_string();
    assert!(message.contains("gone.png") && message.contains("image texture"), "{message}");
    // A distractor between the camera and the wall: seen in the first frame, in its colour,
    // and not simulated (no collider in the arena).
    let mut with_box = look(white, 0.0, BTreeMap::new());
    with_box.distractors.push(Distractor {
        centre: [0.5, 0.0, 0.5],
        half_extents: [0.05, 0.1, 0.1],
        yaw: 0.0,
        surface: Surface { color: [0.0, 1.0, 0.0], texture: Texture::Plain, specular: 0.0 },
    });
    let (pixel, _) = wall_seen_under(with_box).unwrap();
    assert!(pixel[1] > 250 && pixel[0] < 5 && pixel[2] < 5, "the green distractor in front: {pixel:?}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn capture_with_visual_randomization_is_seeded_and_records_each_look() {
    if crate::renderer("capture_with_visual_randomization_is_seeded_and_records_each_look", 8, 8).is_none() {
        return;
    }
    let dir = std::env::temp_dir().join(format!("twinbots-looks-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("run.toml");
    std::fs::write(&config, "[randomization.visual]\n").unwrap();
    let capture = |name: &str, seed: &str, randomized: bool| {
        let out = dir.join(name);
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_twinbots"));
        cmd.args(["capture", "cartpole", "--frames", "2", "--every", "40", "--size", "96x72", "--seed", seed, "--out"])
            .arg(&out);
        if randomized {
            cmd.arg("--config").arg(&config);
        }
        let status = cmd.status().unwrap();
        assert!(status.success());
        out
    };
    let frame = |out: &std::path::Path, i: u32| std::fs::read(out.join(format!("frame_{:05}.png", i * 40))).unwrap();
    let (a, b, c, plain) =
        (capture("a", "3", true), capture("b", "3", true), capture("c", "4", true), capture("plain", "3", false));
    for i in 0..3 {
        assert_eq!(frame(&a, i), frame(&b, i), "frame {i}: the same seed, the same frame");
    }
    assert_ne!(frame(&a, 0), frame(&c, 0), "another seed, another look");
    assert_ne!(frame(&a, 0), frame(&plain, 0), "randomized against the plain twin");
    let looks = std::fs::read_to_string(a.join("looks.jsonl")).unwrap();
    let first: serde_json::Value = serde_json::from_str(looks.lines().next().unwrap()).unwrap();
    assert_eq!(first["frame"], 0);
    let look: Look = serde_json::from_value(first["look"].clone()).unwrap();
    assert!(look.surfaces.contains_key("floor") && !look.lights.is_empty(), "{look:?}");
    assert!(!plain.join("looks.jsonl").exists());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn arenas_rendered_together_in_tiles_look_as_each_does_alone() {
    if crate::renderer("arenas_rendered_together_in_tiles_look_as_each_does_alone", 8, 8).is_none() {
        return;
    }
    use twinbots_api::VecEnv;
    use twinbots_render::{Renderer, View};
    use twinbots_task::randomization::visual::VisualRandomization;
    use twinbots_task::randomization::{Randomization, RandomizationPlugin};
    let mut app = cartpole::headless_app(3, 2);
    app.add_plugins(RandomizationPlugin(Randomization {
        visual: Some(VisualRandomization::default()),
        ..Default::default()
    }));
    let mut env = twinbots_task::AppVecEnv::new(app);
    env.reset(Some(2)).unwrap();
    let view = View::looking_at([0.0, -2.6, 0.7].into(), [0.0, 0.0, 0.5].into(), 45f32.to_radians());
    let arenas = env.arenas().to_vec();
    let shots: Vec<(Entity, View)> = arenas.iter().map(|&a| (a, view)).collect();
    let together = Renderer::tiled(48, 36, 3).unwrap().render_shots(env.app_mut().world_mut(), &shots).unwrap();
    let mut alone = Renderer::new(48, 36).unwrap();
    for (i, &arena) in arenas.iter().enumerate() {
        alone.set_view(view);
        alone.sync(env.app_mut().world_mut(), arena);
        let image = alone.render().unwrap();
        let differing = image.iter().zip(&together[i]).filter(|(a, b)| a.abs_diff(**b) > 1).count();
        assert_eq!(differing, 0, "arena {i}: {differing} bytes differ between its tile and its own frame");
    }
    assert_ne!(together[0], together[1], "each arena in its own look");
    // Fewer shots than tiles: the idle tiles' cameras rest, the shot comes out alone.
    let one = Renderer::tiled(48, 36, 4).unwrap().render_shots(env.app_mut().world_mut(), &shots[1..2]).unwrap();
    assert_eq!(one.len(), 1);
    assert!(one[0].iter().zip(&together[1]).all(|(a, b)| a.abs_diff(*b) <= 1));
    // Two cameras in one arena (two frames: an arena has one camera a frame), in shot order.
    let side = View::looking_at([2.4, -1.2, 0.9].into(), [0.0, 0.0, 0.5].into(), 60f32.to_radians());
    let pair = [(arenas[0], view), (arenas[0], side), (arenas[1], side)];
    let images = Renderer::tiled(48, 36, 3).unwrap().render_shots(env.app_mut().world_mut(), &pair).unwrap();
    for (i, (image, (arena, v))) in images.iter().zip(pair).enumerate() {
        alone.set_view(v);
        alone.sync(env.app_mut().world_mut(), arena);
        let differing = alone.render().unwrap().iter().zip(image).filter(|(a, b)| a.abs_diff(**b) > 1).count();
        assert_eq!(differing, 0, "shot {i}: {differing} bytes differ from its camera's frame alone");
    }
    assert_ne!(images[0], images[1], "the arena through two cameras");
}

#[test]
fn with_shadows_a_box_shades_the_floor_under_it() {
    if crate::renderer("with_shadows_a_box_shades_the_floor_under_it", 8, 8).is_none() {
        return;
    }
    use twinbots_render::{Renderer, View};
    const FLOATING: &str = r#"<robot name="slab"><link name="slab">
      <visual><geometry><box size="0.6 0.6 0.1"/></geometry></visual></link></robot>"#;
    let mut app = App::new();
    app.add_plugins(MinimalPlugins).add_plugins(SimPlugin::default());
    let world = app.world_mut();
    let arena_entity = world.spawn_empty().id();
    let mut arena = Arena::new(0, 0, SimSettings::default().dt, SimSettings::default().gravity);
    let mut queue = bevy::ecs::world::CommandQueue::default();
    {
        let mut commands = Commands::new(&mut queue, world);
        let model = parse_urdf(FLOATING, "t.urdf".as_ref(), ".".as_ref()).unwrap();
        let at = SpawnOptions { base: Pose::from_translation(Vec3::new(0.0, 0.0, 0.6)), fixed_base: true, ..default() };
        spawn_robot(&mut commands, arena_entity, &mut arena, &model, at);
    }
    queue.apply(world);
    arena.mark_initial();
    // The sun straight overhead, a third of ambient.
    let sun = vec![Light { direction: [0.0, 0.0, -1.0], color: [1.0; 3], intensity: 0.7 }];
    world.entity_mut(arena_entity).insert((arena, look(sun, 0.3, BTreeMap::new())));
    app.update();
    let view = View::looking_at([2.0, 0.0, 1.2].into(), [0.0, 0.0, 0.0].into(), 40f32.to_radians());
    let frame = |shadows: bool, app: &mut App| {
        let mut renderer = Renderer::new(160, 120).unwrap().with_shadows(shadows);
        renderer.set_view(view);
        renderer.sync(app.world_mut(), arena_entity);
        renderer.render().unwrap()
    };
    let pixel = |rgb: &[u8], p: Vec3| {
        let at = view.project(p, 160, 120).unwrap();
        let i = ((at.y as usize) * 160 + at.x as usize) * 3;
        [rgb[i], rgb[i + 1], rgb[i + 2]]
    };
    let (plain, shaded) = (frame(false, &mut app), frame(true, &mut app));
    let (under, open) = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(-0.8, 0.6, 0.0));
    // The floor's colour lit fully (ambient 0.3 + the sun 0.7) and by the ambient alone.
    let ground = [0.45f32, 0.47, 0.45];
    let expect = |light: f32| ground.map(|c| linear_to_srgb8(srgb_to_linear(c) * light));
    let near = |p: [u8; 3], e: [f32; 3], tol: f32| p.iter().zip(e).all(|(a, b)| (*a as f32 - b).abs() <= tol);
    assert!(near(pixel(&plain, under), expect(1.0), 2.0), "no shadows: lit under the slab, {:?}", pixel(&plain, under));
    assert!(
        near(pixel(&shaded, under), expect(0.3), 4.0),
        "shadows: ambient only under the slab, {:?} vs {:?}",
        pixel(&shaded, under),
        expect(0.3)
    );
    assert!(near(pixel(&shaded, open), expect(1.0), 2.0), "shadows: lit in the open, {:?}", pixel(&shaded, open));
}
