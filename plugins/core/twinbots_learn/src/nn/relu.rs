//! ReLU as a candle op whose gradient is one pass.
//!
//! candle's `Tensor::relu` computes its gradient as `grad · (x ≥ 0)` from a zero tensor, a
//! comparison into bytes, a conversion to floats and a product: four allocations and passes
//! over every activation, for each ReLU of each backward pass (SAC's gradient step has ten on
//! 256×64 activations). [`relu`] gives the same values and the same gradient, the gradient in
//! one pass.

use candle_core::{CpuStorage, CustomOp1, CustomOp2, Layout, Result, Shape, Tensor};

/// max(x, 0) of every element (0 for NaN, as candle's), with the gradient 1 where x ≥ 0.
pub fn relu(x: &Tensor) -> Result<Tensor> {
    // The op reads its input as one slice; `contiguous` is free when it already is one.
    x.contiguous()?.apply_op1(Relu)
}

struct Relu;

/// `storage` under `layout` as one f32 slice, or an error naming `op`.
fn floats<'a>(storage: &'a CpuStorage, layout: &Layout, op: &str) -> Result<&'a [f32]> {
    match (storage, layout.contiguous_offsets()) {
        (CpuStorage::F32(data), Some((start, end))) => Ok(&data[start..end]),
        _ => candle_core::bail!("{op} takes contiguous f32 tensors"),
    }
}

impl CustomOp1 for Relu {
    fn name(&self) -> &'static str {
        "relu-one-pass"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let out: Vec<f32> = floats(storage, layout, self.name())?.iter().map(|&x| x.max(0.0)).collect();
        Ok((CpuStorage::F32(out), layout.shape().clone()))
    }

    fn bwd(&self, arg: &Tensor, _res: &Tensor, grad_res: &Tensor) -> Result<Option<Tensor>> {
        Ok(Some(grad_res.contiguous()?.apply_op2_no_bwd(&arg.contiguous()?, &ReluGrad)?))
    }
}

/// grad · (x ≥ 0), element by element.
struct ReluGrad;

impl CustomOp2 for ReluGrad {
    fn name(&self) -> &'static str {
        "relu-grad"
    }

    fn cpu_fwd(
        &self,
        grad: &CpuStorage,
        grad_layout: &Layout,
        x: &CpuStorage,
        x_layout: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (grad, x) = (floats(grad, grad_layout, self.name())?, floats(x, x_layout, self.name())?);
        if grad.len() != x.len() {
            candle_core::bail!("relu-grad: {} gradients for {} inputs", grad.len(), x.len());
        }
        let out: Vec<f32> = grad.iter().zip(x).map(|(&g, &x)| if x >= 0.0 { g } else { 0.0 }).collect();
        Ok((CpuStorage::F32(out), grad_layout.shape().clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};

    #[test]
    fn relu_and_its_gradient_match_candles() {
        let values = [-2.0f32, -0.5, 0.0, 0.25, 3.0, f32::NAN, -1e-30, 7.5];
        let x = Var::from_tensor(&Tensor::new(&values, &Device::Cpu).unwrap().reshape((2, 4)).unwrap()).unwrap();
        let weights = Tensor::new(&[[1.0f32, -2.0, 3.0, 0.5], [2.0, 1.5, -1.0, 4.0]], &Device::Cpu).unwrap();
        let ours = relu(x.as_tensor()).unwrap();
        let theirs = x.as_tensor().relu().unwrap();
        let bits = |t: &Tensor| {
            t.flatten_all().unwrap().to_vec1::<f32>().unwrap().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        };
        assert_eq!(bits(&ours), bits(&theirs));
        let grad = |y: Tensor| {
            let g = (y * &weights).unwrap().sum_all().unwrap().backward().unwrap();
            bits(g.get(x.as_tensor()).unwrap())
        };
        assert_eq!(grad(ours), grad(theirs));
        // Through a transposed (non-contiguous) input, too.
        let t = x.as_tensor().t().unwrap();
        assert_eq!(bits(&relu(&t).unwrap()), bits(&t.relu().unwrap()));
    }
}
