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
    /// A camera image and, after its `height × width × channels` values, state readings the
    /// policy gets beside it, each within `[low, high]` (robosuite's and ManiSkill's image plus
    /// the robot's own state; in Gymnasium a `Dict` of `image` and `state`, what SB3's
    /// `MultiInputPolicy` takes).
    ImageAndState {
        height: usize,
        width: usize,
        channels: usize,
        #[serde(with = "bounds")]
        low: Vec<f32>,
        #[serde(with = "bounds")]
        high: Vec<f32>,
    },
}

impl Space {
    /// A box with the same bounds in every one of `dim` dimensions.
    pub fn uniform_box(dim: usize, low: f32, high: f32) -> Self {
        Space::Box { low: vec![low; dim], high: vec![high; dim] }
    }

    /// Length of the flat vector that holds one element.
    pub fn dim(&self) -> usize {
        match self {
            Space::Discrete { .. } => 1,
            Space::Box { low, .. } => low.len(),
            Space::MultiDiscrete { nvec } => nvec.len(),
            Space::Image { height, width, channels } => height * width * channels,
            Space::ImageAndState { height, width, channels, low, .. } => height * width * channels + low.len(),
        }
    }

    /// The camera image's `(height, width, channels)`, for the spaces that hold one.
    pub fn image_shape(&self) -> Option<(usize, usize, usize)> {
        match self {
            Space::Image { height, width, channels } | Space::ImageAndState { height, width, channels, .. } => {
                Some((*height, *width, *channels))
            }
            _ => None,
        }
    }

    /// How many state values follow the image (`ImageAndState`; 0 for every other space).
    pub fn state_dim(&self) -> usize {
        match self {
            Space::ImageAndState { low, .. } => low.len(),
            _ => 0,
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
            Space::Box { low, high } => x.iter().zip(low.iter().zip(high)).all(|(v, (lo, hi))| *v >= *lo && *v <= *hi),
            Space::MultiDiscrete { nvec } => x.iter().zip(nvec).all(|(v, n)| choice(*v, *n)),
            Space::Image { .. } => x.iter().all(|v| choice(*v, 256)),
            Space::ImageAndState { low, high, .. } => {
                let (image, state) = x.split_at(x.len() - low.len());
                image.iter().all(|v| choice(*v, 256))
                    && state.iter().zip(low.iter().zip(high)).all(|(v, (lo, hi))| *v >= *lo && *v <= *hi)
            }
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
            Space::MultiDiscrete { nvec } => nvec.iter().map(|n| rng.random_range(0..*n) as f32).collect(),
            Space::Image { .. } => (0..self.dim()).map(|_| rng.random_range(0..256u32) as f32).collect(),
            Space::ImageAndState { height, width, channels, low, high } => {
                let mut x: Vec<f32> =
                    (0..height * width * channels).map(|_| rng.random_range(0..256u32) as f32).collect();
                x.extend(Space::Box { low: low.clone(), high: high.clone() }.sample(rng));
                x
            }
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
            Space::ImageAndState { height, width, channels, low, .. } => {
                write!(f, "Image({height}×{width}×{channels})+Box({})", low.len())
            }
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn an_image_and_state_holds_whole_pixel_values_then_bounded_state_values() {
        let space = Space::ImageAndState {
            height: 2,
            width: 2,
            channels: 3,
            low: vec![-1.0, 0.0],
            high: vec![1.0, f32::INFINITY],
        };
        assert_eq!((space.dim(), space.image_shape(), space.state_dim()), (14, Some((2, 2, 3)), 2));
        assert_eq!(space.to_string(), "Image(2×2×3)+Box(2)");
        let mut x = vec![255.0; 12];
        x.extend([0.5, 1e9]);
        assert!(space.contains(&x));
        x[12] = 1.5;
        assert!(!space.contains(&x), "a state value out of its bounds");
        x[12] = 0.5;
        x[3] = 0.5;
        assert!(!space.contains(&x), "a fractional pixel value");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        assert!(space.contains(&space.sample(&mut rng)));
        let json = serde_json::to_string(&space).unwrap();
        assert_eq!(serde_json::from_str::<Space>(&json).unwrap(), space, "{json}");
        assert_eq!(
            (
                Space::Image { height: 2, width: 2, channels: 3 }.state_dim(),
                Space::uniform_box(3, 0.0, 1.0).image_shape()
            ),
            (0, None)
        );
    }
}
