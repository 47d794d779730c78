//! A training run, whoever drives it (`twinbots train`, `twinbots serve`, Python): the robots
//! this build knows ([`registry`]), the settings a run is made of ([`settings`]: its
//! `config.toml`), the twin it trains on ([`twin`], [`robot_log`]), the learner made for it or
//! taken from its checkpoints ([`learner`]), and the run itself ([`run`]: its directory, its
//! callbacks, training in process or hosted by a RobotServer, its end); and the live view any
//! command that runs a twin serves ([`live`]).

pub mod learner;
pub mod live;
pub mod registry;
pub mod robot_log;
pub mod run;
pub mod settings;
pub mod twin;
