//! Design pattern 3 without a server: the robot runs a policy itself (an exported ONNX graph
//! beside a real controller, say). [`OnBoardLink`] answers the robot's episode protocol as a
//! RobotServer would, from the policy: an action for an episode's start and every step, an ack
//! after its last step. Nothing learns and nothing crosses a network; the robot's cycle (home,
//! start, operate, exchange) is the same code as with a server.

use std::sync::Arc;

use bevy::prelude::*;

use crate::client::CommunicatorError;
use crate::policy_link::PolicyLink;
use crate::protocol::{ErrorCode, RobotMessage, ServerMessage, error};

/// A deterministic policy: the action for one observation (flat, as the task's spaces).
pub type PolicyFn = Arc<dyn Fn(&[f32]) -> anyhow::Result<Vec<f32>> + Send + Sync>;

/// Insert into a pattern-3 robot app in place of a `ServerAddress`: every robot of the app
/// runs this policy on its own observations.
#[derive(Resource, Clone)]
pub struct OnBoardPolicy(pub PolicyFn);

impl OnBoardPolicy {
    pub fn new(policy: impl Fn(&[f32]) -> anyhow::Result<Vec<f32>> + Send + Sync + 'static) -> Self {
        Self(Arc::new(policy))
    }

    /// A robot's link to its copy of the policy.
    pub fn link(&self) -> OnBoardLink {
        OnBoardLink { policy: self.0.clone(), reply: None }
    }
}

/// A robot's on-board policy, speaking the RobotServer's side of the protocol.
pub struct OnBoardLink {
    policy: PolicyFn,
    reply: Option<ServerMessage>,
}

impl OnBoardLink {
    fn act(&self, obs: &[f32]) -> ServerMessage {
        match (self.policy)(obs) {
            Ok(action) => ServerMessage::Action { action },
            // A policy that cannot act stops the robots, as a server's fatal error does.
            Err(e) => error(ErrorCode::LearnerFailed, true, format!("the on-board policy failed: {e:#}")),
        }
    }
}

impl PolicyLink for OnBoardLink {
    fn send(&mut self, message: &RobotMessage) -> Result<(), CommunicatorError> {
        self.reply = match message {
            RobotMessage::Start { obs } => Some(self.act(obs)),
            RobotMessage::Step { terminated, truncated, .. } if *terminated || *truncated => Some(ServerMessage::Ack),
            RobotMessage::Step { obs, .. } => Some(self.act(obs)),
            RobotMessage::Abort => Some(ServerMessage::Ack),
            // Nothing to introduce to or leave: the policy is on board.
            RobotMessage::Hello { .. } | RobotMessage::Bye => None,
        };
        Ok(())
    }

    fn receive(&mut self) -> Result<ServerMessage, CommunicatorError> {
        Ok(self.reply.take().unwrap_or(ServerMessage::Ack))
    }

    fn connect(&mut self) -> Result<(), CommunicatorError> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn it_answers_as_a_server_would() {
        let policy = OnBoardPolicy::new(|obs: &[f32]| {
            anyhow::ensure!(obs.len() == 2, "two values expected, got {}", obs.len());
            Ok(vec![obs[0] + obs[1]])
        });
        let mut link = policy.link();
        let step = |obs: Vec<f32>, terminated: bool| RobotMessage::Step {
            obs,
            reward: 1.0,
            terminated,
            truncated: false,
            success: None,
            ended_by: None,
        };
        link.send(&RobotMessage::Start { obs: vec![1.0, 2.0] }).unwrap();
        assert_eq!(link.receive().unwrap(), ServerMessage::Action { action: vec![3.0] });
        link.send(&step(vec![0.5, 0.25], false)).unwrap();
        assert_eq!(link.receive().unwrap(), ServerMessage::Action { action: vec![0.75] });
        link.send(&step(vec![0.5, 0.25], true)).unwrap();
        assert_eq!(link.receive().unwrap(), ServerMessage::Ack, "an episode's last step is acknowledged");
        link.send(&RobotMessage::Start { obs: vec![1.0] }).unwrap();
        match link.receive().unwrap() {
            ServerMessage::Error { message, fatal: true, .. } => {
                assert!(message.contains("two values expected, got 1"), "{message}")
            }
            other => panic!("expected a fatal error, got {other:?}"),
        }
    }
}
