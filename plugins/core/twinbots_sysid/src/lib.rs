//! twinbots_sysid: the twin against the robot's data.
//!
//! A robot's test [`rig`] (the robot alone, no task) is driven three ways: by an
//! [`excitation`] program with hidden "true" physics, to [`record`] a stand-in robot's log; by a
//! log's commands, to [`replay`] it and measure how far the twin strays; and by a log's commands
//! with many candidate parameter sets side by side, to [`identify`] (calibrate) the twin with
//! CMA-ES. Logs are `twinbots_log`'s; figures are PNG ([`plot`]).

pub mod effort_model;
pub mod excitation;
pub mod identify;
pub mod plot;
pub mod record;
pub mod replay;
pub mod report;
pub mod rig;
pub mod search;
pub mod sensitivity;
pub mod shadow_stream;
pub mod trace;
pub mod uncertainty;

pub use excitation::Excitation;
pub use identify::{Fit, FitOptions, identify};
pub use record::{Recording, SensorNoise, perturbed_truth, random_truth, record};
pub use replay::{PreparedLog, ReplayReport, compare, prepare};
pub use rig::{Rig, Stand, run};
