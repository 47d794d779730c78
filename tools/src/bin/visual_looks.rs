//! A robot's cell under visual domain randomization: the plain twin first, then one look per
//! seed (`[randomization.visual]` at its defaults with 2–4 distractors, or a run
//! configuration's table), tiled into one PNG (docs/figures/ur5e-visual-randomization.png).
//!
//! `cargo run --release -p twinbots_tools --bin visual_looks -- [robot] [looks] [out.png] [config.toml]`

use anyhow::Context;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_render::{Renderer, View};
use twinbots_task::AppVecEnv;
use twinbots_task::randomization::visual::VisualRandomization;
use twinbots_task::randomization::{Randomization, RandomizationPlugin};

const TILE: (u32, u32) = (320, 240);
const COLUMNS: u32 = 3;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let robot = args.first().map_or("ur5e", String::as_str);
    let looks: u32 = args.get(1).map_or(Ok(5), |n| n.parse()).context("looks: a count")?;
    let out = args.get(2).map_or("visual-looks.png", String::as_str);
    let randomization = match args.get(3) {
        Some(path) => Randomization::from_config(&std::fs::read_to_string(path).with_context(|| path.clone())?)?,
        None => Randomization {
            visual: Some(VisualRandomization { distractors: [2, 4], ..Default::default() }),
            ..Default::default()
        },
    };
    let entry = twinbots_run::registry::find(robot)?;
    let view = View::framed(&entry.framing, "iso").context("the iso camera")?;
    let mut renderer = Renderer::new(TILE.0, TILE.1)?;
    renderer.set_view(view);
    let rows = (looks + 1).div_ceil(COLUMNS);
    let mut grid = image::RgbImage::new(TILE.0 * COLUMNS, TILE.1 * rows);
    for i in 0..=looks {
        let mut app = entry.app(None, 1, i as u64, DesignPattern::Supervised)?;
        if i > 0 {
            app.add_plugins(RandomizationPlugin(randomization.clone()));
        }
        let mut env = AppVecEnv::new(app);
        env.reset(Some(i as u64))?;
        let arena = env.arenas()[0];
        renderer.sync(env.app_mut().world_mut(), arena);
        let rgb = renderer.render()?;
        let tile = image::RgbImage::from_raw(TILE.0, TILE.1, rgb).context("a frame of the tile's size")?;
        image::imageops::replace(&mut grid, &tile, ((i % COLUMNS) * TILE.0) as i64, ((i / COLUMNS) * TILE.1) as i64);
    }
    grid.save(out).with_context(|| out.to_string())?;
    println!("wrote {out}: {robot}, the plain twin and {looks} randomized looks (seeds 1..={looks})");
    Ok(())
}
