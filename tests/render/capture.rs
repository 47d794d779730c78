//! `twinbots capture` writes frames that show the physics: where the pole is, and that it moves.

use std::process::Command;

use twinbots_api::VecEnv;
use twinbots_render::View;
use twinbots_sim::Link;
use twinbots_task::AppVecEnv;

use crate::{orange, renderer};

fn pixel(rgb: &[u8], w: u32, x: u32, y: u32) -> [u8; 3] {
    let i = ((y * w + x) * 3) as usize;
    [rgb[i], rgb[i + 1], rgb[i + 2]]
}

#[test]
fn the_pole_appears_where_the_physics_says_it_is() {
    let (w, h) = (320, 240);
    let Some(mut renderer) = renderer("the_pole_appears_where_the_physics_says_it_is", w, h) else { return };
    let mut env = AppVecEnv::new(cartpole::headless_app(1, 5));
    env.reset(Some(5)).unwrap();
    let view = View::looking_at([0.0, -2.6, 0.7].into(), [0.0, 0.0, 0.5].into(), 45f32.to_radians());
    renderer.set_view(view);
    for step in 0..25 {
        env.step(&[(step % 2) as f32]).unwrap();
    }
    let arena = env.arenas()[0];
    let parts = *env.app().world().get::<cartpole::CartPoleParts>(arena).unwrap();
    renderer.sync(env.app_mut().world_mut(), arena);
    let rgb = renderer.render().unwrap();
    assert_eq!(rgb.len(), (w * h * 3) as usize);
    // Where the physics puts the pole's middle and its tip.
    let world = env.app().world();
    let link = world.get::<Link>(parts.pole_link).unwrap();
    let pole = *twinbots_sim::physics_in(world, arena).unwrap().bodies[link.body].position() * link.offset;
    let middle = pole * bevy::math::Vec3::new(0.0, 0.0, 0.5);
    let p = view.project(middle, w, h).expect("the pole is in front of the camera");
    let near = (-3i32..=3)
        .flat_map(|dx| (-3i32..=3).map(move |dy| (dx, dy)))
        .filter(|(dx, dy)| orange(pixel(&rgb, w, (p.x as i32 + dx) as u32, (p.y as i32 + dy) as u32)))
        .count();
    assert!(near > 5, "orange around the projected pole middle {p:?}: {near} of 49 pixels");
    // Half a metre beside the pole there is no pole.
    let beside = view.project(middle + bevy::math::Vec3::new(0.5, 0.0, 0.0), w, h).unwrap();
    assert!(!orange(pixel(&rgb, w, beside.x as u32, beside.y as u32)), "no pole at {beside:?}");
}

#[test]
fn capture_writes_frames_of_the_requested_size_that_change_as_the_pole_moves() {
    if crate::renderer("capture_writes_frames_of_the_requested_size_that_change_as_the_pole_moves", 8, 8).is_none() {
        return;
    }
    let out = std::env::temp_dir().join(format!("twinbots-capture-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let status = Command::new(env!("CARGO_BIN_EXE_twinbots"))
        .args(["capture", "cartpole", "--frames", "4", "--every", "3", "--size", "160x120", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let mut files: Vec<_> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    let names: Vec<String> = files.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(names, ["frame_00000.png", "frame_00003.png", "frame_00006.png", "frame_00009.png", "frame_00012.png"]);
    let frames: Vec<image::RgbImage> = files.iter().map(|p| image::open(p).unwrap().to_rgb8()).collect();
    for f in &frames {
        assert_eq!(f.dimensions(), (160, 120));
        let first = f.get_pixel(0, 0);
        assert!(f.pixels().any(|p| p != first), "not a uniform image");
        assert!(f.pixels().any(|p| orange(p.0)), "the pole is in the picture");
    }
    for pair in frames.windows(2) {
        assert_ne!(pair[0], pair[1], "consecutive frames differ while the cart moves");
    }
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn asking_for_pixels_without_an_adapter_is_a_clear_error() {
    // A Vulkan loader that finds no driver: what a machine without GPU or Mesa looks like.
    let out = Command::new(env!("CARGO_BIN_EXE_twinbots"))
        .args(["capture", "cartpole", "--frames", "1", "--out"])
        .arg(std::env::temp_dir().join("twinbots-no-adapter"))
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no graphics adapter") && err.contains("mesa-vulkan-drivers"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}
