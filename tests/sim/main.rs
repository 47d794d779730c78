//! End-to-end tests of the simulation core and the cart-pole twin (one test binary).

mod common;
mod determinism;
mod devices;
mod motors;
mod pendulum;
mod pioneer;
mod radio;
mod reset;
mod urdf;
