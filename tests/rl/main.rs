//! End-to-end tests of the RL side (one test binary).

mod bridge;
mod custom_robot;
mod delivery;
mod deploy;
mod learning;
mod model;
mod monitor;
mod onnx;
mod patterns;
mod pixels;
mod ppo;
mod randomization;
mod resume;
mod robot_file_arm;
mod robot_hostile;
#[cfg(feature = "ros2")]
mod ros2;
mod rtde;
mod sac;
mod served;
mod server;
mod server_fuzz;
mod server_hostile;
mod server_load;
mod study;
mod td3;
mod tls;
mod train_cli;
mod ur5e_tasks;
