//! Demonstrations in LeRobot's dataset format (LeRobotDataset v3.0), the one owner of that
//! format in twinbots: [`lerobot`] writes a dataset of episodes, [`reader`] reads the
//! demonstrations of any dataset in the format, [`table`] the Parquet files it
//! is made of (as Apache Arrow's writers lay them out), [`stats`] the features' statistics
//! LeRobot normalizes with.

pub mod lerobot;
pub mod reader;
pub mod stats;
pub mod table;

pub use lerobot::{CameraSpec, DatasetSpec, DatasetWriter, Episode, Frame, Written};
pub use reader::{Demonstrations, read_demonstrations};
