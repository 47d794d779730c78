//! Gymnasium-style spaces. Every action and observation travels as a flat `f32` slice; a
//! discrete choice is its index written as a float (exact up to 2^24).

use rand::Rng;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Space {
    /// One choice among `n`: `{0, 1, ..., n-1}`.
    Discrete { n: usize },
    /// A box `[low, high]` per dimension; bounds may be infinite.
    Box {
        #[serde(with = "bounds")]
        low: Vec<f32>,
        #[serde(with = "bounds")]
        high: Vec<f32>,
    },
    /// Several independent choices, the i-th among `nvec[i]`.
    MultiDiscrete { nvec: Vec<usize> },
    /// A camera image: `height × width × channels` whole numbers in [0, 255] (8-bit colour),
    /// row-major from the top-left, channels last (RGB, or several RGB frames stacked).
    /// Gymnasium's `Box(0, 255, (height, width, channels), uint8)`, what SB3's `CnnPolicy` takes.
    Image { height: usize, width: usize, channels: usize },
}

impl Space {
    /// A box with the same bounds in every one of `dim` dimensions.
    pub fn uniform_box(dim: usize, low: f32, high: f32) -> Self {
        Space::Box {
            low: vec![low; dim],
            high: vec![high; dim],
        }
    }

    /// Length of the flat vector that holds one element.
    pub fn dim(&self) -> usize {
        match self {
            Space::Discrete { .. } => 1,
            Space::Box { low, .. } => low.len(),
            Space::MultiDiscrete { nvec } => nvec.len(),
            Space::Image { height, width, channels } => height * width * channels,
        }
    }

    /// Whether `x` is an element of the space.
    pub fn contains(&self, x: &[f32]) -> bool {
        if x.len() != self.dim() {
            return false;
        }
        let choice = |v: f32, n: usize| v.fract() == 0.0 && v >= 0.0 && (v as usize) < n;
        match self {
            Space::Discrete { n } => choice(x[0], *n),
            Space::Box { low, high } => x
                .iter()
                .zip(low.iter().zip(high))
                .all(|(v, (lo, hi))| *v >= *lo && *v <= *hi),
            Space::MultiDiscrete { nvec } => x.iter().zip(nvec).all(|(v, n)| choice(*v, *n)),
            Space::Image { .. } => x.iter().all(|v| choice(*v, 256)),
        }
    }

    /// An action that asks for nothing: choice 0, or 0 in a box (moved inside its bounds).
    pub fn neutral(&self) -> Vec<f32> {
        match self {
            Space::Box { low, high } => low.iter().zip(high).map(|(lo, hi)| 0f32.clamp(*lo, *hi)).collect(),
            _ => vec![0.0; self.dim()],
        }
    }

    /// A uniformly random element (boxes with infinite bounds sample a unit normal there).
    pub fn sample(&self, rng: &mut impl Rng) -> Vec<f32> {
        match self {
            Space::Discrete { n } => vec![rng.random_range(0..*n) as f32],
            Space::Box { low, high } => low
                .iter()
                .zip(high)
                .map(|(lo, hi)| {
                    if lo.is_finite() && hi.is_finite() {
                        rng.random_range(*lo..=*hi)
                    } else {
                        rand_distr::Distribution::sample(&rand_distr::StandardNormal, rng)
                    }
                })
                .collect(),
            Space::MultiDiscrete { nvec } => {
                nvec.iter().map(|n| rng.random_range(0..*n) as f32).collect()
            }
            Space::Image { .. } => (0..self.dim()).map(|_| rng.random_range(0..256u32) as f32).collect(),
        }
    }
}

impl std::fmt::Display for Space {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Space::Discrete { n } => write!(f, "Discrete({n})"),
            Space::Box { low, .. } => write!(f, "Box({})", low.len()),
            Space::MultiDiscrete { nvec } => write!(f, "MultiDiscrete({nvec:?})"),
            Space::Image { height, width, channels } => write!(f, "Image({height}×{width}×{channels})"),
        }
    }
}

/// JSON has no infinity: infinite bounds are written as the strings "inf" and "-inf".
mod bounds {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize, Deserialize)]
    #[serde(untagged)]
    enum Bound {
        Finite(f32),
        Infinite(String),
    }

    pub fn serialize<S: Serializer>(values: &[f32], s: S) -> Result<S::Ok, S::Error> {
        let out: Vec<Bound> = values
            .iter()
            .map(|&v| match v {
                f32::INFINITY => Bound::Infinite("inf".into()),
                f32::NEG_INFINITY => Bound::Infinite("-inf".into()),
                v => Bound::Finite(v),
            })
            .collect();
        out.serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f32>, D::Error> {
        Vec::<Bound>::deserialize(d)?
            .into_iter()
            .map(|b| match b {
                Bound::Finite(v) => Ok(v),
                Bound::Infinite(s) if s == "inf" => Ok(f32::INFINITY),
                Bound::Infinite(s) if s == "-inf" => Ok(f32::NEG_INFINITY),
                Bound::Infinite(s) => Err(serde::de::Error::custom(format!("bad bound '{s}'"))),
            })
            .collect()
    }
}
