//! `twinbots robots`: what is registered.

use crate::registry;

pub fn print() {
    for robot in registry::robots() {
        println!("{:<12} {}", robot.name, robot.description);
        let patterns: Vec<String> = robot.patterns.iter().map(|p| p.number().to_string()).chain(robot.server_robot.map(|_| "3".into())).collect();
        println!("{:<12} task: {}; design patterns: {}", "", robot.task_name, patterns.join(", "));
        for variant in robot.variants {
            println!("{:<12} also --task {}: {}", "", variant.name, variant.description);
        }
    }
}
