//! The assembly cell any arm works in (docs/cells.md): its layout as data ([`layout`]), what
//! it is built of besides the robot and where a finished program left the part ([`parts`]),
//! and the pick-and-place program a reach policy drives, and how it ended ([`program`]).

pub mod layout;
pub mod parts;
pub mod program;
