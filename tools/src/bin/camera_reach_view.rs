//! What the camera reach's policy sees: the first observation images of a few arenas, scaled
//! up and tiled into one PNG.
//!
//! `cargo run --release -p twinbots_tools --bin camera_reach_view -- [CAMERA] [FOV] [SIZE] [OUT.png]`
//! (docs/figures/ur5e-camera-reach-view.png: `iso 30 64`)

use twinbots_api::{DesignPattern, VecEnv};
use twinbots_render::PixelSettings;
use twinbots_task::AppVecEnv;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let camera = args.first().map_or("iso", String::as_str).to_string();
    let fov: f32 = args.get(1).map_or(Ok(30.0), |s| s.parse())?;
    let size: u32 = args.get(2).map_or(Ok(64), |s| s.parse())?;
    let out = args.get(3).map_or("camera-reach.png", String::as_str);
    let arenas = 6;
    let settings = PixelSettings { camera, fov, width: size, height: size, ..PixelSettings::default() };
    let mut app = ur5e::headless_app_with(arenas, 3, DesignPattern::Supervised);
    settings.install(&mut app, &ur5e::robot().framing, arenas)?;
    let mut env = AppVecEnv::new(app);
    let obs = env.reset(Some(3))?;
    let scale = 4;
    let (w, h) = (size * scale * arenas as u32, size * scale);
    let mut tile = image::RgbImage::new(w, h);
    let dim = env.observation_space().dim();
    for a in 0..arenas {
        for y in 0..h {
            for x in 0..size * scale {
                let p = ((y / scale) * size + x / scale) as usize * 3 + a * dim;
                tile.put_pixel(
                    a as u32 * size * scale + x,
                    y,
                    image::Rgb([obs[p] as u8, obs[p + 1] as u8, obs[p + 2] as u8]),
                );
            }
        }
    }
    tile.save(out)?;
    Ok(())
}
