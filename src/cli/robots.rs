//! `twinbots robots`: what is registered.

use crate::registry;

pub fn print() {
    for robot in registry::robots() {
        println!("{:<12} {}", robot.name, robot.description);
        let patterns: Vec<String> = robot.all_patterns().iter().map(|p| p.number().to_string()).collect();
        println!("{:<12} task: {}; design patterns: {}", "", robot.main_task().name, patterns.join(", "));
        for task in &robot.tasks[1..] {
            println!("{:<12} also --task {}: {}", "", task.name, task.description);
        }
    }
}
