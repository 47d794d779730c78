//! The state of a vectorised env as a checkpoint keeps it: the random stream at each running
//! episode's reset and the actions since ([`EnvState`]); [`crate::replay`] puts an env back in it.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// A ChaCha stream's exact position, as a file can keep it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct StreamState {
    /// The 32-byte key, as hex.
    pub seed: String,
    pub stream: u64,
    /// 32-bit words consumed since the start of the stream (a u128, as a decimal string).
    pub word_pos: String,
}

impl StreamState {
    pub fn of(rng: &ChaCha8Rng) -> Self {
        Self {
            seed: rng.get_seed().iter().map(|b| format!("{b:02x}")).collect(),
            stream: rng.get_stream(),
            word_pos: rng.get_word_pos().to_string(),
        }
    }

    pub fn to_rng(&self) -> anyhow::Result<ChaCha8Rng> {
        let bad = || anyhow::anyhow!("a random stream's state is damaged: {self:?}");
        anyhow::ensure!(self.seed.len() == 64, bad());
        let mut seed = [0u8; 32];
        for (i, byte) in seed.iter_mut().enumerate() {
            *byte = u8::from_str_radix(&self.seed[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
        }
        let mut rng = ChaCha8Rng::from_seed(seed);
        rng.set_stream(self.stream);
        rng.set_word_pos(self.word_pos.parse::<u128>().map_err(|_| bad())?);
        Ok(rng)
    }
}

/// One env's running episode, as a checkpoint keeps it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunningEpisode {
    pub start: StreamState,
    /// Flat, `steps × action dimension`.
    pub actions: Vec<f32>,
}

/// A vectorised env's state: the control-step clock and each env's running episode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvState {
    pub clock: u64,
    pub episodes: Vec<RunningEpisode>,
}
