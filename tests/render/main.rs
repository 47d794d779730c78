//! Off-screen rendering of the twin (one test binary). Without a graphics adapter these tests
//! skip themselves, unless TWINBOTS_REQUIRE_ADAPTER is set (CI sets it): then they fail.

mod camera;
mod capture;
mod look;
mod monitor;
mod pixels;

use twinbots_render::{RenderError, Renderer, adapter_required};

/// A renderer for the test `test`, or `None` when there is no adapter and none is required:
/// the test then skips, saying so on stderr in a line that starts with SKIPPED (cargo shows
/// it as passed). With TWINBOTS_REQUIRE_ADAPTER=1 a missing adapter fails the test.
pub fn renderer(test: &str, width: u32, height: u32) -> Option<Renderer> {
    match Renderer::new(width, height) {
        Ok(r) => Some(r),
        Err(RenderError::NoAdapter) if !adapter_required() => {
            eprintln!(
                "SKIPPED render::{test}: no graphics adapter, nothing was checked \
                 (install mesa-vulkan-drivers; TWINBOTS_REQUIRE_ADAPTER=1 makes this a failure)"
            );
            None
        }
        Err(e) => panic!("render::{test}: {e} (TWINBOTS_REQUIRE_ADAPTER is set: an adapter is required)"),
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
