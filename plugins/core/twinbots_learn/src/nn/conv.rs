//! Convolutions as patches times a matrix: [`unfold`] cuts a batch of images (channels last)
//! into one row per output pixel, and a [`Dense`] layer over those rows is the convolution.
//! The work is then one gemm forward and two backward, where candle's own `conv2d` backward
//! runs a transposed convolution element by element. Channels stay last throughout (the
//! camera's own layout), so no layer transposes.

use candle_core::{CpuStorage, CustomOp1, Device, Layout, Result, Shape, Tensor};
use rand_chacha::ChaCha8Rng;

use super::Dense;

/// ReLU layers start with He's uniform bound √(6 / fan_in) (√6 times PyTorch's default), so
/// activations keep their scale through the stack (SB3 gets the same from orthogonal √2).
pub(super) const RELU_GAIN: f64 = 2.449_489_742_783_178;

/// The geometry of one convolution over `height × width × channels` images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Patches {
    pub height: usize,
    pub width: usize,
    pub channels: usize,
    pub kernel: usize,
    pub stride: usize,
}

impl Patches {
    /// Output height and width (no padding).
    pub fn output(&self) -> (usize, usize) {
        ((self.height - self.kernel) / self.stride + 1, (self.width - self.kernel) / self.stride + 1)
    }

    /// Values in one patch: `kernel × kernel × channels`.
    pub fn patch_len(&self) -> usize {
        self.kernel * self.kernel * self.channels
    }

    fn fits(&self) -> bool {
        self.kernel >= 1
            && self.stride >= 1
            && self.height >= self.kernel
            && self.width >= self.kernel
            && self.channels >= 1
    }
}

/// `[batch, height, width, channels]` (any shape with that many elements per image) →
/// `[batch · out_h · out_w, kernel · kernel · channels]`, each row one output pixel's patch
/// (kernel row, kernel column, channel order). Its gradient folds the rows back, summing
/// where patches overlap.
pub fn unfold(images: &Tensor, patches: Patches) -> Result<Tensor> {
    if !patches.fits() {
        candle_core::bail!("unfold: a {}×{} kernel does not fit {patches:?}", patches.kernel, patches.kernel);
    }
    images.contiguous()?.apply_op1(Unfold(patches))
}

struct Unfold(Patches);
struct Fold(Patches);

fn slice<'a>(storage: &'a CpuStorage, layout: &Layout, op: &str) -> Result<&'a [f32]> {
    match (storage, layout.contiguous_offsets()) {
        (CpuStorage::F32(data), Some((start, end))) => Ok(&data[start..end]),
        _ => candle_core::bail!("{op} takes contiguous f32 tensors"),
    }
}

/// Calls `f(row, image offset)` for each (output pixel, kernel row, kernel column): the patch's
/// `channels` values sit at `row` in the unfolded matrix and at `image offset` in the batch.
fn for_each_patch(p: &Patches, batch: usize, mut f: impl FnMut(usize, usize)) {
    let (out_h, out_w) = p.output();
    let c = p.channels;
    let mut row = 0;
    for b in 0..batch {
        let image = b * p.height * p.width * c;
        for oy in 0..out_h {
            for ox in 0..out_w {
                for ky in 0..p.kernel {
                    let line = image + ((oy * p.stride + ky) * p.width + ox * p.stride) * c;
                    for kx in 0..p.kernel {
                        f(row, line + kx * c);
                        row += c;
                    }
                }
            }
        }
    }
}

impl CustomOp1 for Unfold {
    fn name(&self) -> &'static str {
        "unfold"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let p = self.0;
        let data = slice(storage, layout, "unfold")?;
        let image_len = p.height * p.width * p.channels;
        if data.len() % image_len != 0 {
            candle_core::bail!(
                "unfold: {} values are not whole {}×{}×{} images",
                data.len(),
                p.height,
                p.width,
                p.channels
            );
        }
        let batch = data.len() / image_len;
        let (out_h, out_w) = p.output();
        let rows = batch * out_h * out_w;
        let mut out = vec![0f32; rows * p.patch_len()];
        let c = p.channels;
        for_each_patch(&p, batch, |row, at| out[row..row + c].copy_from_slice(&data[at..at + c]));
        Ok((CpuStorage::F32(out), Shape::from((rows, p.patch_len()))))
    }

    fn bwd(&self, arg: &Tensor, _res: &Tensor, grad_res: &Tensor) -> Result<Option<Tensor>> {
        let folded = grad_res.contiguous()?.apply_op1(Fold(self.0))?;
        Ok(Some(folded.reshape(arg.shape())?))
    }
}

impl CustomOp1 for Fold {
    fn name(&self) -> &'static str {
        "fold"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let p = self.0;
        let data = slice(storage, layout, "fold")?;
        let (out_h, out_w) = p.output();
        let per_image = out_h * out_w * p.patch_len();
        if data.len() % per_image != 0 {
            candle_core::bail!("fold: {} values are not whole unfolded images of {per_image}", data.len());
        }
        let batch = data.len() / per_image;
        let mut out = vec![0f32; batch * p.height * p.width * p.channels];
        let c = p.channels;
        for_each_patch(&p, batch, |row, at| {
            for (o, g) in out[at..at + c].iter_mut().zip(&data[row..row + c]) {
                *o += g;
            }
        });
        Ok((CpuStorage::F32(out), Shape::from((batch, p.height, p.width, p.channels))))
    }
}

/// `x Wᵀ` for an `x` that needs no gradient, as an op of `W` alone: candle's matmul backward
/// computes the gradient of both factors, and for the first convolution's patches (a camera
/// batch unfolded: 88 MB for 256 images of 64×64×6) that unwanted product, its zeros and its
/// sum were the largest work of an update.
struct TimesConstant(Tensor);

impl CustomOp1 for TimesConstant {
    fn name(&self) -> &'static str {
        "times-constant"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let weight = Tensor::from_slice(slice(storage, layout, "times-constant")?, layout.shape(), &Device::Cpu)?;
        let y = self.0.matmul(&weight.t()?)?;
        Ok((CpuStorage::F32(y.flatten_all()?.to_vec1()?), y.shape().clone()))
    }

    fn bwd(&self, _weight: &Tensor, _res: &Tensor, grad_res: &Tensor) -> Result<Option<Tensor>> {
        // ∂L/∂W = Gᵀ x
        Ok(Some(grad_res.t()?.matmul(&self.0)?))
    }
}

/// A convolution (with ReLU, or without: [`Self::forward_linear`]): [`unfold`] then a dense
/// layer from patch to output channels.
pub struct Conv2d {
    pub patches: Patches,
    pub dense: Dense,
}

impl Conv2d {
    pub(crate) fn new(patches: Patches, outputs: usize, gain: f64, rng: &mut ChaCha8Rng, dev: &Device) -> Result<Self> {
        Ok(Self { patches, dense: Dense::new(patches.patch_len(), outputs, gain, rng, dev)? })
    }

    /// `[batch, …]` images → `[batch, out_h, out_w, outputs]`, rectified. `constant`: the
    /// images need no gradient (the observations, into the first layer).
    pub fn forward(&self, images: &Tensor, constant: bool) -> Result<Tensor> {
        self.forward_linear(images, constant)?.relu()
    }

    /// The same without the ReLU (a last layer whose maps something else reads: keypoints).
    pub fn forward_linear(&self, images: &Tensor, constant: bool) -> Result<Tensor> {
        let batch = images.dim(0)?;
        let (out_h, out_w) = self.patches.output();
        let outputs = self.dense.weight.as_tensor().dim(0)?;
        let patches = unfold(images, self.patches)?;
        let y = if constant {
            let product = self.dense.weight.as_tensor().contiguous()?.apply_op1(TimesConstant(patches.detach()))?;
            self.dense.add_bias(&product)?
        } else {
            self.dense.forward(&patches)?
        };
        y.reshape((batch, out_h, out_w, outputs))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Var};

    fn numbers(shape: &[usize], scale: f64, dev: &Device) -> Tensor {
        let n: usize = shape.iter().product();
        Tensor::arange(0u32, n as u32, dev)
            .unwrap()
            .to_dtype(DType::F32)
            .unwrap()
            .affine(scale, -0.3)
            .unwrap()
            .sin()
            .unwrap()
            .reshape(shape)
            .unwrap()
    }

    #[test]
    fn unfold_then_matmul_is_candles_convolution_and_so_are_the_gradients() {
        let dev = Device::Cpu;
        let p = Patches { height: 9, width: 11, channels: 3, kernel: 3, stride: 2 };
        let (out_h, out_w) = p.output();
        assert_eq!((out_h, out_w), (4, 5));
        let x = Var::from_tensor(&numbers(&[2, 9, 11, 3], 0.37, &dev)).unwrap();
        // 4 output channels; our weight is [out, ky, kx, c], candle's kernel [out, c, ky, kx].
        let w = Var::from_tensor(&numbers(&[4, 3, 3, 3], 0.11, &dev)).unwrap();

        let ours = unfold(x.as_tensor(), p)
            .unwrap()
            .matmul(&w.as_tensor().reshape((4, 27)).unwrap().t().unwrap())
            .unwrap()
            .reshape((2, out_h, out_w, 4))
            .unwrap();
        let nchw = x.as_tensor().permute((0, 3, 1, 2)).unwrap().contiguous().unwrap();
        let kernel = w.as_tensor().permute((0, 3, 1, 2)).unwrap().contiguous().unwrap();
        let theirs = nchw.conv2d(&kernel, 0, 2, 1, 1).unwrap().permute((0, 2, 3, 1)).unwrap();
        let diff =
            |a: &Tensor, b: &Tensor| (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(diff(&ours, &theirs) < 1e-5, "forward differs by {}", diff(&ours, &theirs));

        let weights = numbers(&[2, out_h, out_w, 4], 0.53, &dev);
        let grads = |y: &Tensor| {
            let g = (y * &weights).unwrap().sum_all().unwrap().backward().unwrap();
            (g.get(x.as_tensor()).unwrap().clone(), g.get(w.as_tensor()).unwrap().clone())
        };
        let (gx, gw) = grads(&ours);
        let (tx, tw) = grads(&theirs);
        assert!(diff(&gx, &tx) < 1e-4, "input gradient differs by {}", diff(&gx, &tx));
        assert!(diff(&gw, &tw) < 1e-4, "kernel gradient differs by {}", diff(&gw, &tw));
    }

    #[test]
    fn a_convolution_of_constant_images_has_the_same_values_and_weight_gradients() {
        use rand::SeedableRng;
        let dev = Device::Cpu;
        let p = Patches { height: 12, width: 10, channels: 2, kernel: 4, stride: 2 };
        let conv = Conv2d::new(p, 3, 1.0, &mut ChaCha8Rng::seed_from_u64(4), &dev).unwrap();
        let images = numbers(&[2, 12, 10, 2], 0.7, &dev);
        let (out_h, out_w) = p.output();
        let weights = numbers(&[2, out_h, out_w, 3], 0.29, &dev);
        let run = |constant: bool| {
            let y = conv.forward(&images, constant).unwrap();
            let g = (&y * &weights).unwrap().sum_all().unwrap().backward().unwrap();
            let grad = |v: &Var| g.get(v.as_tensor()).unwrap().clone();
            (y, grad(&conv.dense.weight), grad(&conv.dense.bias))
        };
        let diff =
            |a: &Tensor, b: &Tensor| (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        let (y, gw, gb) = run(false);
        let (yc, gwc, gbc) = run(true);
        assert!(diff(&y, &yc) < 1e-5 && diff(&gw, &gwc) < 1e-4 && diff(&gb, &gbc) < 1e-4);
        assert!(gw.abs().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap() > 0.0);
    }

    #[test]
    fn a_kernel_larger_than_the_image_is_an_error() {
        let dev = Device::Cpu;
        let p = Patches { height: 4, width: 4, channels: 1, kernel: 8, stride: 4 };
        let e = unfold(&Tensor::zeros((1, 4, 4, 1), DType::F32, &dev).unwrap(), p).unwrap_err().to_string();
        assert!(e.contains("does not fit"), "{e}");
    }
}
