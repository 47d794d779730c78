//! Off-screen rendering of the twin (one test binary). Without a graphics adapter these tests
//! skip themselves, unless TWINBOTS_REQUIRE_ADAPTER is set (CI sets it): then they fail.

mod camera;
mod capture;

use twinbots_render::{RenderError, Renderer, adapter_required};

/// A renderer, or `None` (skip) when there is no adapter and none is required.
pub fn renderer(width: u32, height: u32) -> Option<Renderer> {
    match Renderer::new(width, height) {
        Ok(r) => Some(r),
        Err(RenderError::NoAdapter) if !adapter_required() => {
            eprintln!("skipped: no graphics adapter (set TWINBOTS_REQUIRE_ADAPTER=1 to fail instead)");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// Whether an RGB pixel is the pole's orange (0.95, 0.5, 0.1 lit).
pub fn orange(p: [u8; 3]) -> bool {
    let [r, g, b] = p.map(|c| c as i32);
    r > 120 && r > g + 40 && g > b + 20 && b < 90
}

pub fn red(p: [u8; 3]) -> bool {
    let [r, g, b] = p.map(|c| c as i32);
    r > 100 && r > 2 * g && r > 2 * b
}
