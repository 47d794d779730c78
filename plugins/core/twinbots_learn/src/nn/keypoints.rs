//! Keypoints of a camera image (Levine, Finn, Darrell & Abbeel 2016, "End-to-end training of
//! deep visuomotor policies"; robomimic's `SpatialSoftmax`): convolutions, then per channel of
//! the last one a softmax over the image's pixels, and the expected image coordinates under
//! it. Each channel becomes one point, (x, y) in [−1, 1]: where in the image the thing that
//! channel responds to is. A policy that must find an object and move to it reads a few such
//! coordinates where NatureCNN hands it hundreds of features, which is what the reach needs
//! (docs/pixels.md).

use candle_core::{CpuStorage, CustomOp1, Device, Layout, Result, Shape, Tensor};
use rand_chacha::ChaCha8Rng;

use super::conv::{Conv2d, Patches, RELU_GAIN};
use crate::policy_net::keypoint_grid as grid;

/// The convolutions: (filters, kernel, stride). A 64×64 image → 31×31 → 15×15 → 13×13 maps,
/// 32 keypoints; fewer multiply-adds than NatureCNN's (3.3 M against 3.7 M an image).
pub const LAYERS: [(usize, usize, usize); 3] = [(16, 4, 2), (32, 3, 2), (32, 3, 1)];

/// Convolutions with ReLU, then a last one whose maps are softmaxed into keypoints.
pub struct KeypointCnn {
    pub convs: Vec<Conv2d>,
}

impl KeypointCnn {
    pub fn new(height: usize, width: usize, channels: usize, rng: &mut ChaCha8Rng, dev: &Device) -> Result<Self> {
        let mut convs = Vec::new();
        let (mut h, mut w, mut c) = (height, width, channels);
        for (filters, kernel, stride) in LAYERS {
            let patches = Patches { height: h, width: w, channels: c, kernel, stride };
            (h, w) = patches.output();
            c = filters;
            convs.push(Conv2d::new(patches, filters, RELU_GAIN, rng, dev)?);
        }
        Ok(Self { convs })
    }

    /// A copy sharing no variable with this one.
    pub fn deep_copy(&self) -> Result<Self> {
        let convs = self
            .convs
            .iter()
            .map(|c| Ok(Conv2d { patches: c.patches, dense: c.dense.deep_copy()? }))
            .collect::<Result<_>>()?;
        Ok(Self { convs })
    }

    /// Values per image it hands on: (x, y) per keypoint.
    pub fn dim(&self) -> usize {
        2 * LAYERS[LAYERS.len() - 1].0
    }

    /// `[batch, image]` (0–255) → `[batch, 2 · keypoints]`: keypoint k's x, then its y.
    pub fn forward(&self, obs: &Tensor) -> Result<Tensor> {
        let mut x = (obs * (1.0 / 255.0))?;
        let last = self.convs.len() - 1;
        for (i, conv) in self.convs.iter().enumerate() {
            // The observations need no gradient: the first layer's products skip it.
            x = if i == last { conv.forward_linear(&x, i == 0)? } else { conv.forward(&x, i == 0)? };
        }
        let (_, h, w, _) = x.dims4()?;
        x.contiguous()?.apply_op1(SpatialSoftmax { grid: grid(h, w) })
    }
}

/// `[batch, h, w, k]` maps → `[batch, 2k]`: per map, a softmax over its pixels and the expected
/// (x, y) under it. One op with its own backward pass: made of candle's broadcast ops it cost
/// more than the convolutions (a batched product with two columns, its zeros and its sums).
struct SpatialSoftmax {
    /// Each pixel's (x, y), row by row.
    grid: Vec<f32>,
}

impl SpatialSoftmax {
    /// Calls `f(image, keypoint, pixel, its weight)` for every weight of every map's softmax,
    /// image by image; each map's maximum is taken out first, so no exponential overflows.
    fn softmax(&self, data: &[f32], maps: usize, mut f: impl FnMut(usize, usize, usize, f32)) {
        let pixels = self.grid.len() / 2;
        let per_image = pixels * maps;
        let (mut max, mut sum) = (vec![f32::NEG_INFINITY; maps], vec![0f32; maps]);
        for (b, image) in data.chunks_exact(per_image).enumerate() {
            max.fill(f32::NEG_INFINITY);
            sum.fill(0.0);
            for row in image.chunks_exact(maps) {
                max.iter_mut().zip(row).for_each(|(m, &v)| *m = m.max(v));
            }
            for row in image.chunks_exact(maps) {
                sum.iter_mut().zip(row).zip(&max).for_each(|((s, &v), &m)| *s += (v - m).exp());
            }
            for (p, row) in image.chunks_exact(maps).enumerate() {
                for k in 0..maps {
                    f(b, k, p, (row[k] - max[k]).exp() / sum[k]);
                }
            }
        }
    }
}

impl CustomOp1 for SpatialSoftmax {
    fn name(&self) -> &'static str {
        "spatial-softmax"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let (data, (batch, maps)) = maps_of(storage, layout, self.grid.len() / 2)?;
        let mut out = vec![0f32; batch * maps * 2];
        self.softmax(data, maps, |b, k, p, a| {
            out[(b * maps + k) * 2] += a * self.grid[2 * p];
            out[(b * maps + k) * 2 + 1] += a * self.grid[2 * p + 1];
        });
        Ok((CpuStorage::F32(out), Shape::from((batch, 2 * maps))))
    }

    /// ∂x̄/∂v_p = a_p (x_p − x̄) (and the same for y): a softmax's weights a times the pixel's
    /// coordinate less the expected one.
    fn bwd(&self, arg: &Tensor, res: &Tensor, grad_res: &Tensor) -> Result<Option<Tensor>> {
        let data = arg.flatten_all()?.to_vec1::<f32>()?;
        let (mean, grad) = (res.flatten_all()?.to_vec1::<f32>()?, grad_res.flatten_all()?.to_vec1::<f32>()?);
        let maps = mean.len() / 2 / arg.dim(0)?;
        let mut out = vec![0f32; data.len()];
        let pixels = self.grid.len() / 2;
        self.softmax(&data, maps, |b, k, p, a| {
            let i = (b * maps + k) * 2;
            let along = grad[i] * (self.grid[2 * p] - mean[i]) + grad[i + 1] * (self.grid[2 * p + 1] - mean[i + 1]);
            out[(b * pixels + p) * maps + k] = a * along;
        });
        Ok(Some(Tensor::from_vec(out, arg.shape(), arg.device())?))
    }
}

/// The contiguous f32 values of `[batch, pixels, maps]` and (batch, maps).
fn maps_of<'a>(storage: &'a CpuStorage, layout: &Layout, pixels: usize) -> Result<(&'a [f32], (usize, usize))> {
    let (CpuStorage::F32(data), Some((start, end))) = (storage, layout.contiguous_offsets()) else {
        candle_core::bail!("spatial softmax takes contiguous f32 maps")
    };
    let dims = layout.shape().dims();
    let (batch, maps) = (dims[0], dims[dims.len() - 1]);
    if batch * pixels * maps != end - start {
        candle_core::bail!("spatial softmax: {dims:?} are not {pixels}-pixel maps");
    }
    Ok((&data[start..end], (batch, maps)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn keypoints_follow_a_bright_spot_across_the_image() {
        let dev = Device::Cpu;
        let net = KeypointCnn::new(64, 64, 3, &mut ChaCha8Rng::seed_from_u64(5), &dev).unwrap();
        assert_eq!(net.dim(), 64);
        // A 6×6 white square on black, once left-top and once right-bottom.
        let image = |x0: usize, y0: usize| -> Vec<f32> {
            (0..64 * 64 * 3)
                .map(|i| {
                    let (y, x) = (i / 192, i / 3 % 64);
                    if (x0..x0 + 6).contains(&x) && (y0..y0 + 6).contains(&y) { 255.0 } else { 0.0 }
                })
                .collect()
        };
        let obs = Tensor::from_vec([image(4, 6), image(52, 50)].concat(), (2, 64 * 64 * 3), &dev).unwrap();
        let points = net.forward(&obs).unwrap().to_vec2::<f32>().unwrap();
        assert!(points.iter().flatten().all(|v| (-1.0..=1.0).contains(v)), "coordinates in [-1, 1]");
        // Averaged over the keypoints, the spot's move to the right and down shows.
        let mean = |row: &[f32], axis: usize| row.iter().skip(axis).step_by(2).sum::<f32>() / 32.0;
        assert!(mean(&points[1], 0) > mean(&points[0], 0) && mean(&points[1], 1) > mean(&points[0], 1), "{points:?}");
    }

    #[test]
    fn a_loss_on_the_keypoints_reaches_every_convolution() {
        let dev = Device::Cpu;
        let net = KeypointCnn::new(40, 40, 3, &mut ChaCha8Rng::seed_from_u64(6), &dev).unwrap();
        let obs = Tensor::rand(0f32, 255.0, (2, 40 * 40 * 3), &dev).unwrap();
        let grads = net.forward(&obs).unwrap().sum_all().unwrap().backward().unwrap();
        for conv in &net.convs {
            let g = grads.get(conv.dense.weight.as_tensor()).expect("a gradient for every layer");
            assert!(g.abs().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap() > 0.0);
        }
    }

    #[test]
    fn the_spatial_softmax_is_candles_softmax_and_expectation_with_its_gradient() {
        let dev = Device::Cpu;
        let (h, w, k) = (3, 4, 5);
        let maps = candle_core::Var::from_tensor(&(Tensor::randn(0f32, 2.0, (2, h, w, k), &dev).unwrap())).unwrap();
        let weights = Tensor::randn(0f32, 1.0, (2, 2 * k), &dev).unwrap();
        let ours = maps.as_tensor().apply_op1(SpatialSoftmax { grid: grid(h, w) }).unwrap();
        let flat = maps.as_tensor().reshape((2, h * w, k)).unwrap().transpose(1, 2).unwrap().contiguous().unwrap();
        let attention = candle_nn::ops::softmax(&flat, candle_core::D::Minus1).unwrap();
        let grid = Tensor::from_vec(grid(h, w), (h * w, 2), &dev).unwrap();
        let theirs = attention.broadcast_matmul(&grid).unwrap().reshape((2, 2 * k)).unwrap();
        let diff =
            |a: &Tensor, b: &Tensor| (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(diff(&ours, &theirs) < 1e-5, "values differ by {}", diff(&ours, &theirs));
        let gradient = |y: &Tensor| {
            (y * &weights).unwrap().sum_all().unwrap().backward().unwrap().get(maps.as_tensor()).unwrap().clone()
        };
        assert!(diff(&gradient(&ours), &gradient(&theirs)) < 1e-5, "gradients differ");
    }

    #[test]
    fn the_grid_runs_from_minus_one_to_one_row_by_row() {
        assert_eq!(grid(2, 3), vec![-1.0, -1.0, 0.0, -1.0, 1.0, -1.0, -1.0, 1.0, 0.0, 1.0, 1.0, 1.0]);
    }
}
