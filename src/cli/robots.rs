//! `twinbots robots`: what is registered.

use crate::registry;

pub fn print() {
    for robot in registry::robots() {
        println!("{:<12} {}", robot.name, robot.description);
    }
}
