//! End-to-end tests of the simulation core and the robot twins (one test binary).

mod accuracy;
mod common;
mod determinism;
mod devices;
mod disturbance;
mod motors;
mod pattern3_access;
mod pendulum;
mod pioneer;
mod protective_stop;
mod radio;
mod reset;
mod soak;
mod ur5e_cell;
mod urdf;
mod urdf_fuzz;
