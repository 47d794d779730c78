//! What a policy's networks read: the observation as it is, or features a CNN draws from a
//! camera image (SB3's `MlpPolicy` and `CnnPolicy` with its `NatureCNN` features extractor,
//! Mnih et al. 2015). The policy and value heads sit on top of either. State values that
//! follow an image ([`Space::ImageAndState`]) pass beside the image's features, as SB3's
//! `CombinedExtractor` concatenates a `Dict` observation's flattened vectors to its CNN's.

use candle_core::{DType, Device, Result, Tensor, Var};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use twinbots_api::Space;

use super::Dense;
use super::conv::{Conv2d, Patches, RELU_GAIN};
use super::keypoints::KeypointCnn;
use crate::policy_net::{ConvEncoder, ConvHead, ConvLayer, InputEncoding};

/// The learner's `policy` setting.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PolicyKind {
    /// `cnn` for image observations, `mlp` for the rest.
    #[default]
    Auto,
    /// The observation straight into the MLPs (an image's values scaled to [0, 1] first, as SB3).
    Mlp,
    /// NatureCNN features (images of at least 36×36 only).
    Cnn,
    /// Keypoints: where in the image each of the last convolution's 32 maps peaks, as
    /// coordinates (a spatial softmax, Levine et al. 2016; images of at least 36×36 only).
    Keypoints,
}

/// The smallest image NatureCNN's three convolutions fit (8/4, 4/2, 3/1).
pub const CNN_MIN_SIZE: usize = 36;

/// NatureCNN: 32 filters 8×8 stride 4, 64 4×4 stride 2, 64 3×3 stride 1, then a dense layer
/// to `features` values, ReLU after each; images come in as 0–255 and are scaled to [0, 1].
pub struct NatureCnn {
    pub convs: Vec<Conv2d>,
    pub fc: Dense,
}

impl NatureCnn {
    fn new(
        height: usize,
        width: usize,
        channels: usize,
        features: usize,
        rng: &mut ChaCha8Rng,
        dev: &Device,
    ) -> Result<Self> {
        let mut convs = Vec::new();
        let (mut h, mut w, mut c) = (height, width, channels);
        for (filters, kernel, stride) in [(32, 8, 4), (64, 4, 2), (64, 3, 1)] {
            let patches = Patches { height: h, width: w, channels: c, kernel, stride };
            (h, w) = patches.output();
            c = filters;
            convs.push(Conv2d::new(patches, filters, RELU_GAIN, rng, dev)?);
        }
        Ok(Self { convs, fc: Dense::new(h * w * c, features, RELU_GAIN, rng, dev)? })
    }

    fn forward(&self, obs: &Tensor) -> Result<Tensor> {
        self.dense(&self.convolutions(obs)?)
    }

    /// `[batch, pixels]` images (0–255) → the convolutions' output, flat: the dense layer's input.
    pub fn convolutions(&self, obs: &Tensor) -> Result<Tensor> {
        let batch = obs.dim(0)?;
        let mut x = (obs * (1.0 / 255.0))?;
        for (i, conv) in self.convs.iter().enumerate() {
            // The observations need no gradient: the first layer's products skip it.
            x = conv.forward(&x, i == 0)?;
        }
        x.reshape((batch, ()))
    }

    /// The dense layer with its ReLU: the features, from [`Self::convolutions`]' output.
    pub fn dense(&self, flat: &Tensor) -> Result<Tensor> {
        self.fc.forward(flat)?.relu()
    }
}

/// Refuses running-statistics normalisation of camera images (`<algo>.normalize_observations`):
/// the encoders scale them to [0, 1], as SB3 does.
pub fn check_normalization(space: &Space, normalize_observations: bool, algo: &str) -> anyhow::Result<()> {
    anyhow::ensure!(
        !(normalize_observations && space.image_shape().is_some()),
        "{algo}.normalize_observations = true: camera images are scaled to [0, 1], not normalised by running statistics"
    );
    Ok(())
}

/// A policy's observation encoder.
pub enum Encoder {
    /// The observation as it is (`dim` values).
    Flat { dim: usize },
    /// An image's values scaled to [0, 1], flat (an MLP on pixels), and the `state` values
    /// after it as they are.
    ScaledImage { dim: usize, state: usize },
    /// NatureCNN features of the image, then the `state` values after it as they are.
    Cnn { cnn: NatureCnn, state: usize },
    /// The image's keypoints, then the `state` values.
    Keypoints { net: KeypointCnn, state: usize },
}

impl Encoder {
    /// The encoder `kind` asks for on `space`; a CNN on anything but a large enough image is
    /// an error naming the setting (`<algo>.policy`).
    pub fn new(
        kind: PolicyKind,
        space: &Space,
        features: usize,
        algo: &str,
        rng: &mut ChaCha8Rng,
        dev: &Device,
    ) -> anyhow::Result<Self> {
        let (image, state) = (space.image_shape(), space.state_dim());
        Ok(match (kind, image) {
            (PolicyKind::Mlp, Some(_)) => Encoder::ScaledImage { dim: space.dim(), state },
            (PolicyKind::Mlp | PolicyKind::Auto, None) => Encoder::Flat { dim: space.dim() },
            (PolicyKind::Keypoints, Some((h, w, c))) => {
                fits(h, w, "keypoints", "its convolutions need", algo, space)?;
                Encoder::Keypoints { net: KeypointCnn::new(h, w, c, rng, dev)?, state }
            }
            (PolicyKind::Cnn | PolicyKind::Auto, Some((h, w, c))) => {
                fits(h, w, "cnn", "NatureCNN needs", algo, space)?;
                anyhow::ensure!(
                    (1..=4096).contains(&features),
                    "{algo}.features_dim = {features}: must be a whole number in 1..=4096"
                );
                Encoder::Cnn { cnn: NatureCnn::new(h, w, c, features, rng, dev)?, state }
            }
            (PolicyKind::Cnn | PolicyKind::Keypoints, None) => {
                let name = if kind == PolicyKind::Cnn { "cnn" } else { "keypoints" };
                anyhow::bail!(
                    "{algo}.policy = \"{name}\": the observation {space} is not an image (use pixel observations, [pixels])"
                )
            }
        })
    }

    /// Values per observation the heads read.
    pub fn dim(&self) -> usize {
        match self {
            Encoder::Flat { dim } | Encoder::ScaledImage { dim, .. } => *dim,
            Encoder::Cnn { cnn, state } => cnn.fc.bias.as_tensor().dims1().unwrap_or(0) + state,
            Encoder::Keypoints { net, state } => net.dim() + state,
        }
    }

    pub fn is_flat(&self) -> bool {
        matches!(self, Encoder::Flat { .. })
    }

    /// `[batch, obs_dim]` → `[batch, dim()]`.
    pub fn forward(&self, obs: &Tensor) -> Result<Tensor> {
        match self {
            Encoder::Flat { .. } => Ok(obs.clone()),
            Encoder::ScaledImage { state: 0, .. } => obs.to_dtype(DType::F32)? * (1.0 / 255.0),
            Encoder::ScaledImage { state, .. } => {
                let (image, state) = split(obs, *state)?;
                Tensor::cat(&[(image.to_dtype(DType::F32)? * (1.0 / 255.0))?, state], 1)
            }
            Encoder::Cnn { cnn, state } => image_then_state(obs, *state, |image| cnn.forward(image)),
            Encoder::Keypoints { net, state } => image_then_state(obs, *state, |image| net.forward(image)),
        }
    }

    /// Its numbers, for an exporter; the layers named `<prefix>features.<i>`.
    pub fn export(&self, prefix: &str) -> Result<InputEncoding> {
        Ok(match self {
            Encoder::Flat { .. } => InputEncoding::Flat,
            Encoder::ScaledImage { state: 0, .. } => InputEncoding::Scaled { scale: 1.0 / 255.0 },
            Encoder::ScaledImage { .. } => {
                return Err(candle_core::Error::Msg(
                    "an MLP policy on an image and state values cannot be exported to ONNX yet: use policy = \"cnn\""
                        .into(),
                ));
            }
            Encoder::Keypoints { net, state } => {
                InputEncoding::Cnn(conv_encoder(&net.convs, ConvHead::Keypoints, *state, prefix)?)
            }
            Encoder::Cnn { cnn, state } => {
                let fc = cnn.fc.values(&format!("{prefix}features.{}", cnn.convs.len()))?;
                InputEncoding::Cnn(conv_encoder(&cnn.convs, ConvHead::Dense(fc), *state, prefix)?)
            }
        })
    }

    /// Its variables as `features.<i>.weight` / `.bias` (NatureCNN's dense layer last).
    pub fn named_vars(&self) -> Vec<(String, Var)> {
        let layers: Vec<&Dense> = match self {
            Encoder::Cnn { cnn, .. } => cnn.convs.iter().map(|c| &c.dense).chain([&cnn.fc]).collect(),
            Encoder::Keypoints { net, .. } => net.convs.iter().map(|c| &c.dense).collect(),
            Encoder::Flat { .. } | Encoder::ScaledImage { .. } => return Vec::new(),
        };
        layers
            .into_iter()
            .enumerate()
            .flat_map(|(i, l)| {
                [(format!("features.{i}.weight"), l.weight.clone()), (format!("features.{i}.bias"), l.bias.clone())]
            })
            .collect()
    }

    /// A copy sharing no variable with this one.
    pub fn deep_copy(&self) -> Result<Self> {
        Ok(match self {
            Encoder::Flat { dim } => Encoder::Flat { dim: *dim },
            Encoder::ScaledImage { dim, state } => Encoder::ScaledImage { dim: *dim, state: *state },
            Encoder::Cnn { cnn, state } => Encoder::Cnn {
                cnn: NatureCnn {
                    convs: cnn
                        .convs
                        .iter()
                        .map(|c| Ok(Conv2d { patches: c.patches, dense: c.dense.deep_copy()? }))
                        .collect::<Result<_>>()?,
                    fc: cnn.fc.deep_copy()?,
                },
                state: *state,
            },
            Encoder::Keypoints { net, state } => Encoder::Keypoints { net: net.deep_copy()?, state: *state },
        })
    }
}

/// `[batch, image + state]` → the image's columns and the state's.
fn split(obs: &Tensor, state: usize) -> Result<(Tensor, Tensor)> {
    let dim = obs.dim(1)?;
    Ok((obs.narrow(1, 0, dim - state)?, obs.narrow(1, dim - state, state)?))
}

/// `features` of the image's columns of `obs`, then its `state` columns as they are.
fn image_then_state(obs: &Tensor, state: usize, features: impl Fn(&Tensor) -> Result<Tensor>) -> Result<Tensor> {
    if state == 0 {
        return features(obs);
    }
    let (image, state) = split(obs, state)?;
    Tensor::cat(&[features(&image.contiguous()?)?, state.to_dtype(DType::F32)?], 1)
}

/// The convolutions' numbers (named `<prefix>features.<i>`) and what follows them, for an
/// exporter.
fn conv_encoder(convs: &[Conv2d], head: ConvHead, state: usize, prefix: &str) -> Result<ConvEncoder> {
    let first = convs[0].patches;
    let convs = convs
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let d = c.dense.values(&format!("{prefix}features.{i}"))?;
            Ok(ConvLayer {
                name: d.name,
                kernel: c.patches.kernel,
                stride: c.patches.stride,
                in_channels: c.patches.channels,
                filters: d.outputs,
                weight: d.weight,
                bias: d.bias,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(ConvEncoder {
        height: first.height,
        width: first.width,
        channels: first.channels,
        scale: 1.0 / 255.0,
        convs,
        head,
        state,
    })
}

/// An error naming `<algo>.policy = "<name>"` unless an `h × w` image is large enough for
/// the convolutions (`needs`: what needs it, for the message).
fn fits(h: usize, w: usize, name: &str, needs: &str, algo: &str, space: &Space) -> anyhow::Result<()> {
    anyhow::ensure!(
        h >= CNN_MIN_SIZE && w >= CNN_MIN_SIZE,
        "{algo}.policy = \"{name}\": {needs} images of at least {CNN_MIN_SIZE}×{CNN_MIN_SIZE}, the observation is {space}"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn nature_cnn_maps_64x64_images_to_features_and_refuses_small_or_flat_inputs() {
        let dev = Device::Cpu;
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let space = Space::Image { height: 64, width: 64, channels: 6 };
        let encoder = Encoder::new(PolicyKind::Auto, &space, 128, "ppo", &mut rng, &dev).unwrap();
        assert_eq!(encoder.dim(), 128);
        assert_eq!(encoder.named_vars().len(), 8);
        let obs = Tensor::full(200f32, (3, space.dim()), &dev).unwrap();
        let features = encoder.forward(&obs).unwrap();
        assert_eq!(features.dims(), &[3, 128]);
        let values = features.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(values.iter().all(|v| *v >= 0.0) && values.iter().any(|v| *v > 0.0), "ReLU features, not all dead");

        let small = Space::Image { height: 32, width: 64, channels: 3 };
        let e = Encoder::new(PolicyKind::Cnn, &small, 512, "ppo", &mut rng, &dev).err().unwrap().to_string();
        assert!(e.starts_with("ppo.policy = \"cnn\": NatureCNN needs images of at least 36×36"), "{e}");
        let e = Encoder::new(PolicyKind::Cnn, &Space::uniform_box(4, -1.0, 1.0), 512, "sac", &mut rng, &dev)
            .err()
            .unwrap()
            .to_string();
        assert!(e.starts_with("sac.policy = \"cnn\": the observation Box(4) is not an image"), "{e}");
        assert!(matches!(
            Encoder::new(PolicyKind::Mlp, &small, 512, "ppo", &mut rng, &dev).unwrap(),
            Encoder::ScaledImage { dim: 6144, state: 0 }
        ));
    }

    #[test]
    fn keypoints_hand_on_two_coordinates_a_map_then_the_state_export_and_refuse_what_they_cannot_read() {
        let dev = Device::Cpu;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let space = Space::ImageAndState { height: 40, width: 40, channels: 3, low: vec![-1.0; 2], high: vec![1.0; 2] };
        let encoder = Encoder::new(PolicyKind::Keypoints, &space, 512, "sac", &mut rng, &dev).unwrap();
        assert_eq!(
            (encoder.dim(), encoder.named_vars().len()),
            (64 + 2, 6),
            "32 keypoints and the state; 3 convolutions"
        );
        let mut row = vec![7.0f32; 40 * 40 * 3];
        row.extend([0.25, -0.5]);
        let out =
            encoder.forward(&Tensor::from_vec(row, (1, space.dim()), &dev).unwrap()).unwrap().to_vec2::<f32>().unwrap();
        assert_eq!(out[0][64..], [0.25, -0.5]);
        assert!(out[0][..64].iter().all(|v| (-1.0..=1.0).contains(v)));
        let copy = encoder.deep_copy().unwrap();
        assert_eq!(
            copy.named_vars()[0].1.as_tensor().to_vec2::<f32>().unwrap(),
            encoder.named_vars()[0].1.as_tensor().to_vec2::<f32>().unwrap()
        );
        let first = copy.named_vars()[0].1.clone();
        first.set(&first.as_tensor().zeros_like().unwrap()).unwrap();
        assert!(
            encoder.named_vars()[0].1.as_tensor().abs().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap() > 0.0,
            "the copy shares nothing"
        );

        let InputEncoding::Cnn(exported) = encoder.export("pi.").unwrap() else {
            panic!("keypoints export as convolutions")
        };
        assert_eq!((exported.head, exported.convs.len(), exported.state), (ConvHead::Keypoints, 3, 2));
        assert_eq!(exported.convs[2].name, "pi.features.2");
        let e = Encoder::new(PolicyKind::Keypoints, &Space::uniform_box(4, -1.0, 1.0), 512, "ppo", &mut rng, &dev)
            .err()
            .unwrap()
            .to_string();
        assert!(e.starts_with("ppo.policy = \"keypoints\": the observation Box(4) is not an image"), "{e}");
        let small = Space::Image { height: 30, width: 64, channels: 3 };
        let e = Encoder::new(PolicyKind::Keypoints, &small, 512, "ppo", &mut rng, &dev).err().unwrap().to_string();
        assert!(e.contains("at least 36×36"), "{e}");
    }

    #[test]
    fn state_values_after_an_image_pass_beside_its_features_as_they_are() {
        let dev = Device::Cpu;
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let space = Space::ImageAndState { height: 40, width: 40, channels: 3, low: vec![-1.0; 2], high: vec![1.0; 2] };
        let image = 40 * 40 * 3;
        let mut one: Vec<f32> = (0..image).map(|i| (i % 256) as f32).collect();
        one.extend([0.25, -0.5]);
        let obs = Tensor::from_vec(one.repeat(2), (2, space.dim()), &dev).unwrap();

        let encoder = Encoder::new(PolicyKind::Auto, &space, 16, "ppo", &mut rng, &dev).unwrap();
        assert_eq!(encoder.dim(), 18);
        let out = encoder.forward(&obs).unwrap().to_vec2::<f32>().unwrap();
        let Encoder::Cnn { cnn, .. } = &encoder else { panic!("a CNN for an image and state") };
        let features =
            cnn.forward(&obs.narrow(1, 0, image).unwrap().contiguous().unwrap()).unwrap().to_vec2::<f32>().unwrap();
        assert_eq!(out[1][..16], features[1][..], "the image's features first");
        assert_eq!(out[1][16..], [0.25, -0.5], "then the state as it is");

        let mlp = Encoder::new(PolicyKind::Mlp, &space, 16, "ppo", &mut rng, &dev).unwrap();
        let out = mlp.forward(&obs).unwrap().to_vec2::<f32>().unwrap();
        assert_eq!(
            (mlp.dim(), out[0][255], out[0][image..].to_vec()),
            (image + 2, 1.0, vec![0.25, -0.5]),
            "pixels scaled, the state not"
        );
        let e = mlp.export("").err().unwrap().to_string();
        assert!(e.contains("cannot be exported to ONNX yet: use policy = \"cnn\""), "{e}");
    }
}
