//! Robot logs, replay and calibration: known-truth recovery per robot, the CLI's files and
//! its errors on bad input, a real UR5's recordings.

mod cli;
mod fuzz;
mod real_ur5;
mod recovery;
mod stream;
