//! The assembly cell any arm works in (docs/cells.md): its layout as data ([`layout`]), what
//! it is built of besides the robot and where a finished program left the part ([`parts`]),
//! the pick-and-place program a reach policy drives, and how it ended ([`program`]), and the
//! goals of pick-and-place learned end to end ([`learned`]).

pub mod layout;
pub mod learned;
pub mod parts;
pub mod program;
