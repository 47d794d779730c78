//! The assembly cell any arm works in (docs/cells.md): its layout as data ([`layout`]), what
//! it is built of besides the robot and how a finished program is judged ([`parts`]), and the
//! pick-and-place program a reach policy drives ([`program`]).

pub mod layout;
pub mod parts;
pub mod program;
