//! Robot logs, replay and calibration: known-truth recovery per robot, the CLI's files and
//! its errors on bad input.

mod cli;
mod fuzz;
mod recovery;
