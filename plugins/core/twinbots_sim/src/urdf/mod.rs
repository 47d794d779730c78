//! URDF → robot description ([`RobotModel`]); [`crate::spawn`] turns that into bodies and entities.

pub mod chain;
pub mod check;
mod collada;
pub mod dynamics;
mod error;
mod load;
pub mod mesh;
mod model;
pub mod robot_file;
mod xml_depth;

pub use error::UrdfError;
pub use load::{load_urdf, load_urdf_in, parse_urdf, parse_urdf_exact, parse_urdf_in};
pub use model::*;
