//! What an exported policy says about itself, in the ONNX model's `metadata_props` (string
//! keys and values; docs/export.md lists them with their units). A runner reads them to refuse
//! a policy made for another robot, task or observation.

use twinbots_api::{Space, TaskSpec};

pub const VERSION: &str = "twinbots.version";
pub const ROBOT: &str = "twinbots.robot";
pub const TASK: &str = "twinbots.task";
pub const DESIGN_PATTERN: &str = "twinbots.design_pattern";
pub const OBSERVATION_SPACE: &str = "twinbots.observation_space";
pub const OBSERVATION_NAMES: &str = "twinbots.observation_names";
pub const ACTION_SPACE: &str = "twinbots.action_space";
pub const CONTROL_PERIOD_S: &str = "twinbots.control_period_s";
pub const OBSERVATION_NORMALIZATION: &str = "twinbots.observation_normalization";
pub const TIMESTEPS: &str = "twinbots.timesteps";

/// An exported policy's description.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyMetadata {
    /// The twinbots version that exported it.
    pub twinbots_version: String,
    pub robot: String,
    pub task: String,
    /// The design pattern (paper §3) it was trained under: where its observations came from.
    pub design_pattern: u8,
    pub observation_space: Space,
    /// What each observation value is, in order (the task's `observation_names`).
    pub observation_names: Vec<String>,
    pub action_space: Space,
    /// Seconds between two actions (the task's control step).
    pub control_period_s: f32,
    /// Whether the graph normalises observations itself (the training's running statistics,
    /// folded in): the caller always feeds raw observations.
    pub normalizes_observations: bool,
    /// Environment steps the policy was trained for.
    pub timesteps: u64,
}

impl PolicyMetadata {
    /// The key-value pairs written into the model.
    pub fn to_props(&self) -> Vec<(String, String)> {
        vec![
            (VERSION.into(), self.twinbots_version.clone()),
            (ROBOT.into(), self.robot.clone()),
            (TASK.into(), self.task.clone()),
            (DESIGN_PATTERN.into(), self.design_pattern.to_string()),
            (OBSERVATION_SPACE.into(), json(&self.observation_space)),
            (OBSERVATION_NAMES.into(), json(&self.observation_names)),
            (ACTION_SPACE.into(), json(&self.action_space)),
            (CONTROL_PERIOD_S.into(), self.control_period_s.to_string()),
            (OBSERVATION_NORMALIZATION.into(), if self.normalizes_observations { "folded" } else { "none" }.into()),
            (TIMESTEPS.into(), self.timesteps.to_string()),
        ]
    }

    /// Reads them back; a missing or unreadable key is an error naming it.
    pub fn from_props(props: &[(String, String)]) -> anyhow::Result<Self> {
        let get = |key: &str| -> anyhow::Result<&str> {
            props
                .iter()
                .find(|(k, _)| k == key)
                .map(|(_, v)| v.as_str())
                .ok_or_else(|| anyhow::anyhow!("not a twinbots policy: no metadata '{key}'"))
        };
        let parse = |key: &str| -> anyhow::Result<f64> {
            get(key)?.parse::<f64>().map_err(|e| anyhow::anyhow!("metadata '{key}': {e}"))
        };
        let json_value = |key: &str| -> anyhow::Result<serde_json::Value> {
            serde_json::from_str(get(key)?).map_err(|e| anyhow::anyhow!("metadata '{key}': {e}"))
        };
        let space = |key: &str| -> anyhow::Result<Space> {
            serde_json::from_value(json_value(key)?).map_err(|e| anyhow::anyhow!("metadata '{key}': {e}"))
        };
        Ok(Self {
            twinbots_version: get(VERSION)?.to_string(),
            robot: get(ROBOT)?.to_string(),
            task: get(TASK)?.to_string(),
            design_pattern: parse(DESIGN_PATTERN)? as u8,
            observation_space: space(OBSERVATION_SPACE)?,
            observation_names: serde_json::from_value(json_value(OBSERVATION_NAMES)?)
                .map_err(|e| anyhow::anyhow!("metadata '{OBSERVATION_NAMES}': {e}"))?,
            action_space: space(ACTION_SPACE)?,
            control_period_s: parse(CONTROL_PERIOD_S)? as f32,
            normalizes_observations: get(OBSERVATION_NORMALIZATION)? == "folded",
            timesteps: parse(TIMESTEPS)? as u64,
        })
    }

    /// An error unless the robot `robot` running its task `task` (as `spec` declares it) can
    /// run this policy: the same robot and task, the same observations in the same order, the
    /// same actions.
    pub fn check_fits(&self, robot: &str, task: &str, spec: &TaskSpec) -> anyhow::Result<()> {
        anyhow::ensure!(self.robot == robot, "the policy was exported for the robot '{}', not '{robot}'", self.robot);
        anyhow::ensure!(self.task == task, "the policy was exported for the task '{}', not '{task}'", self.task);
        anyhow::ensure!(
            self.observation_space.dim() == spec.observation_space.dim()
                && self.observation_names == spec.observation_names,
            "the policy observes {:?}, but this robot's task observes {:?}",
            self.observation_names,
            spec.observation_names
        );
        anyhow::ensure!(
            self.action_space == spec.action_space,
            "the policy acts in {}, but this robot's task takes {}",
            self.action_space,
            spec.action_space
        );
        Ok(())
    }
}

/// JSON text of a space or a list of names.
fn json<T: serde::Serialize>(value: &T) -> String {
    serde_json::to_string(value).expect("spaces and names serialise")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> PolicyMetadata {
        PolicyMetadata {
            twinbots_version: "0.1.0".into(),
            robot: "ur5e".into(),
            task: "reach".into(),
            design_pattern: 1,
            observation_space: Space::Box { low: vec![f32::NEG_INFINITY, -1.0], high: vec![f32::INFINITY, 1.0] },
            observation_names: vec!["q[0]".into(), "last_action[0]".into()],
            action_space: Space::uniform_box(5, -1.0, 1.0),
            control_period_s: 0.04,
            normalizes_observations: true,
            timesteps: 245_760,
        }
    }

    #[test]
    fn metadata_reads_back_as_written() {
        let m = example();
        assert_eq!(PolicyMetadata::from_props(&m.to_props()).unwrap(), m);
    }

    #[test]
    fn a_missing_key_is_named() {
        let props: Vec<(String, String)> = example().to_props().into_iter().filter(|(k, _)| k != ROBOT).collect();
        let err = PolicyMetadata::from_props(&props).unwrap_err().to_string();
        assert_eq!(err, "not a twinbots policy: no metadata 'twinbots.robot'");
    }
}
