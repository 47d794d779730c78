//! A trained model's deterministic policy as an ONNX graph (docs/export.md draws it):
//!
//! ```text
//! obs [batch, n] float ─▶ normalise (if trained so) ─▶ [CNN] ─▶ MLP ─▶ ArgMax                           ─▶ action [batch] int64
//!                                                        └▶ Max(low), Min(high)                     ─▶ action [batch, m] float
//!                                                        └▶ Tanh ─▶ rescale to [low, high]          ─▶ action [batch, m] float
//! ```
//!
//! Normalising is `((x − mean) / √(var + 1e-8))` computed in double precision, as
//! `RunningMeanStd::normalize` does, then clipped to ±10. Each layer is a `Gemm` (x Wᵀ + b). The
//! graph is built from the model's `PolicyNet` (its layers, hidden activation and head), so it
//! knows no algorithm by name; the heads are those of the algorithms so far. PPO's
//! hidden layers are followed by `Tanh`; a discrete policy's mode is the arg max of its logits
//! (the last of equal ones, as the model's own arg max takes); a Gaussian's mode is its mean,
//! clipped to the action box as the env receives it (PPO neither squashes nor rescales). SAC's
//! hidden layers are followed by `Relu`; its mode is tanh of its Gaussian's mean, rescaled from
//! [−1, 1] to the box (`low + (a + 1) · (high − low) / 2`, as the model hands actions to the env).
//!
//! A policy on camera images reads them flat, `height × width × channels` values per row
//! (channels last, as the env hands them over): the graph reshapes them to `[batch, H, W, C]`,
//! transposes to ONNX's `NCHW`, scales by 1/255, and runs NatureCNN's `Conv` + `Relu` layers
//! (each convolution's weights reordered from the learner's (row, column, channel) patches to
//! `OIHW`), then transposes back and flattens as the learner does, into the features' `Gemm` +
//! `Relu`. Keypoints end instead at their last `Conv` (no `Relu`): its maps reshaped to
//! `[batch, maps, pixels]`, a `Softmax` over the pixels, a `MatMul` with the pixels' (x, y)
//! (`keypoint_grid`, `[pixels, 2]`), flattened to each map's x then y. An MLP on pixels only
//! scales them.

use std::path::Path;

use prost::Message;
use tract_onnx::pb;
use tract_onnx::pb::tensor_proto::DataType;
use twinbots_api::Space;
use twinbots_api::files::write_atomic;
use twinbots_learn::Agent;
use twinbots_learn::nn::Patches;
use twinbots_learn::normalize::CLIP;
use twinbots_learn::policy_net::{
    Activation, ConvEncoder, ConvHead, ConvLayer, DenseLayer, InputEncoding, PolicyHead, keypoint_grid,
};

use crate::metadata::PolicyMetadata;

/// ONNX IR version 8 (ONNX 1.10+) and operator set 17: read by onnxruntime ≥ 1.13 and tract.
pub const IR_VERSION: i64 = 8;
pub const OPSET: i64 = 17;
pub const INPUT: &str = "obs";
pub const OUTPUT: &str = "action";

/// The ONNX model of `model`'s deterministic policy, described by `metadata` (whose spaces
/// must be the model's).
pub fn policy_model(agent: &dyn Agent, metadata: &PolicyMetadata) -> anyhow::Result<pb::ModelProto> {
    anyhow::ensure!(
        metadata.observation_space.dim() == agent.observation_space().dim()
            && metadata.action_space == *agent.action_space(),
        "the model's spaces ({} observations, {}) differ from the description's ({} observations, {})",
        agent.observation_space().dim(),
        agent.action_space(),
        metadata.observation_space.dim(),
        metadata.action_space
    );
    let graph = policy_graph(agent)?;
    Ok(pb::ModelProto {
        ir_version: IR_VERSION,
        opset_import: vec![pb::OperatorSetIdProto { domain: String::new(), version: OPSET }],
        producer_name: "twinbots".into(),
        producer_version: metadata.twinbots_version.clone(),
        doc_string: format!(
            "{} ({}): the deterministic policy of a {} model; see docs/export.md",
            metadata.robot,
            metadata.task,
            agent.algorithm()
        ),
        graph: Some(graph),
        metadata_props: metadata
            .to_props()
            .into_iter()
            .map(|(key, value)| pb::StringStringEntryProto { key, value })
            .collect(),
        ..Default::default()
    })
}

/// The policy's ONNX file, as bytes.
pub fn policy_bytes(model: &dyn Agent, metadata: &PolicyMetadata) -> anyhow::Result<Vec<u8>> {
    Ok(policy_model(model, metadata)?.encode_to_vec())
}

/// Writes the policy to `path` (through a temporary file and a rename).
pub fn write_policy(path: &Path, model: &dyn Agent, metadata: &PolicyMetadata) -> anyhow::Result<()> {
    write_atomic(path, &policy_bytes(model, metadata)?).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

fn policy_graph(model: &dyn Agent) -> anyhow::Result<pb::GraphProto> {
    let (observation_space, action_space) = (model.observation_space(), model.action_space());
    let net = model.policy_net()?;
    let mut g = GraphBuilder::default();
    let mut x = INPUT.to_string();
    if let Some(rms) = &net.obs_rms {
        let std: Vec<f64> = rms.var.iter().map(|v| (v + 1e-8).sqrt()).collect();
        let mean = g.constant_f64("obs_mean", &rms.mean);
        let std = g.constant_f64("obs_std", &std);
        let wide = g.node("Cast", &[&x], vec![int_attr("to", DataType::Double as i64)]);
        let centred = g.node("Sub", &[&wide, &mean], vec![]);
        let scaled = g.node("Div", &[&centred, &std], vec![]);
        let narrow = g.node("Cast", &[&scaled], vec![int_attr("to", DataType::Float as i64)]);
        let (low, high) = (g.scalar_f32("obs_clip_low", -CLIP), g.scalar_f32("obs_clip_high", CLIP));
        x = g.node("Clip", &[&narrow, &low, &high], vec![]);
    }
    match &net.encoding {
        InputEncoding::Flat => {}
        InputEncoding::Scaled { scale } => {
            let scale = g.scalar_f32("obs_scale", *scale);
            x = g.node("Mul", &[&x, &scale], vec![]);
        }
        InputEncoding::Cnn(cnn) => x = conv_features(&mut g, cnn, &x)?,
    }
    anyhow::ensure!(!net.layers.is_empty(), "the policy has no layers");
    for (i, layer) in net.layers.iter().enumerate() {
        x = g.dense(layer, &x);
        if i + 1 < net.layers.len() {
            x = g.node(
                match net.hidden {
                    Activation::Tanh => "Tanh",
                    Activation::Relu => "Relu",
                },
                &[&x],
                vec![],
            );
        }
    }
    let output_type = match net.head {
        PolicyHead::ArgMax => {
            anyhow::ensure!(
                matches!(action_space, Space::Discrete { .. }),
                "an arg-max head needs discrete actions, not {action_space}"
            );
            g.output_node(
                "ArgMax",
                &[&x],
                vec![int_attr("axis", 1), int_attr("keepdims", 0), int_attr("select_last_index", 1)],
            );
            tensor_type(DataType::Int64, &[batch_dim()])
        }
        PolicyHead::ClipToBox => clip_head(&mut g, &x, action_space)?,
        PolicyHead::TanhToBox => {
            let squashed = g.node("Tanh", &[&x], vec![]);
            squash_head(&mut g, &squashed, action_space)?
        }
    };
    Ok(pb::GraphProto {
        name: "twinbots_policy".into(),
        node: g.nodes,
        initializer: g.initializers,
        input: vec![value_info(
            INPUT,
            tensor_type(DataType::Float, &[batch_dim(), fixed_dim(observation_space.dim())]),
        )],
        output: vec![value_info(OUTPUT, output_type)],
        ..Default::default()
    })
}

/// The image encoder on flat rows of `H·W·C` image values: its features (NatureCNN's
/// `fc.outputs`, or two per keypoint); with state values after the image, the features and
/// then those.
fn conv_features(g: &mut GraphBuilder, cnn: &ConvEncoder, x: &str) -> anyhow::Result<String> {
    if cnn.state == 0 {
        return image_features(g, cnn, x);
    }
    let pixels = (cnn.height * cnn.width * cnn.channels) as i64;
    let axes = g.constant_i64("split_axis", &[1]);
    let (start, split, end) = (
        g.constant_i64("image_start", &[0]),
        g.constant_i64("state_start", &[pixels]),
        g.constant_i64("state_end", &[pixels + cnn.state as i64]),
    );
    let image = g.node("Slice", &[x, &start, &split, &axes], vec![]);
    let state = g.node("Slice", &[x, &split, &end, &axes], vec![]);
    let features = image_features(g, cnn, &image)?;
    Ok(g.node("Concat", &[&features, &state], vec![int_attr("axis", 1)]))
}

fn image_features(g: &mut GraphBuilder, cnn: &ConvEncoder, x: &str) -> anyhow::Result<String> {
    let image = g.constant_i64("image_shape", &[-1, cnn.height as i64, cnn.width as i64, cnn.channels as i64]);
    let x = g.node("Reshape", &[x, &image], vec![]);
    let x = g.node("Transpose", &[&x], vec![ints_attr("perm", &[0, 3, 1, 2])]);
    let scale = g.scalar_f32("image_scale", cnn.scale);
    let mut x = g.node("Mul", &[&x, &scale], vec![]);
    let (mut h, mut w) = (cnn.height, cnn.width);
    let last = cnn.convs.len().saturating_sub(1);
    for (i, conv) in cnn.convs.iter().enumerate() {
        let (k, c) = (conv.kernel, conv.in_channels);
        anyhow::ensure!(
            conv.weight.len() == conv.filters * k * k * c,
            "{}: {} weights for {} filters of {k}×{k}×{c}",
            conv.name,
            conv.weight.len(),
            conv.filters
        );
        anyhow::ensure!(h >= k && w >= k, "{}: a {k}×{k} kernel on a {h}×{w} map", conv.name);
        let name = &conv.name;
        let weight = g.constant_f32(
            &format!("{name}.weight"),
            &[conv.filters as i64, c as i64, k as i64, k as i64],
            &oihw(conv),
        );
        let bias = g.constant_f32(&format!("{name}.bias"), &[conv.filters as i64], &conv.bias);
        let attributes = vec![
            ints_attr("kernel_shape", &[k as i64, k as i64]),
            ints_attr("strides", &[conv.stride as i64, conv.stride as i64]),
        ];
        x = g.node("Conv", &[&x, &weight, &bias], attributes);
        (h, w) = Patches { height: h, width: w, channels: c, kernel: k, stride: conv.stride }.output();
        if !(i == last && cnn.head == ConvHead::Keypoints) {
            x = g.node("Relu", &[&x], vec![]);
        }
    }
    match &cnn.head {
        ConvHead::Dense(fc) => {
            // Back to channels last, flattened per row as the learner's features layer reads them.
            let x = g.node("Transpose", &[&x], vec![ints_attr("perm", &[0, 2, 3, 1])]);
            let x = g.node("Flatten", &[&x], vec![int_attr("axis", 1)]);
            let x = g.dense(fc, &x);
            Ok(g.node("Relu", &[&x], vec![]))
        }
        ConvHead::Keypoints => {
            // [batch, maps, h, w] → a softmax over each map's pixels → their weighted (x, y).
            let maps = cnn.convs.last().map_or(cnn.channels, |c| c.filters) as i64;
            let shape = g.constant_i64("keypoint_maps_shape", &[0, maps, (h * w) as i64]);
            let x = g.node("Reshape", &[&x, &shape], vec![]);
            let attention = g.node("Softmax", &[&x], vec![int_attr("axis", -1)]);
            let grid = g.constant_f32("keypoint_grid", &[(h * w) as i64, 2], &keypoint_grid(h, w));
            let points = g.node("MatMul", &[&attention, &grid], vec![]);
            Ok(g.node("Flatten", &[&points], vec![int_attr("axis", 1)]))
        }
    }
}

/// A convolution's weights in ONNX's order: the learner's are `weight[o][(ky·k + kx)·C + ch]`,
/// ONNX's `W[o][ch][ky][kx]`.
fn oihw(conv: &ConvLayer) -> Vec<f32> {
    let (k, c) = (conv.kernel, conv.in_channels);
    let mut out = vec![0f32; conv.weight.len()];
    for o in 0..conv.filters {
        for ky in 0..k {
            for kx in 0..k {
                for ch in 0..c {
                    out[((o * c + ch) * k + ky) * k + kx] = conv.weight[o * k * k * c + (ky * k + kx) * c + ch];
                }
            }
        }
    }
    out
}

/// A Gaussian's mode: its mean, clipped to the box.
fn clip_head(g: &mut GraphBuilder, x: &str, action_space: &Space) -> anyhow::Result<pb::TypeProto> {
    let Space::Box { low, high } = action_space else {
        anyhow::bail!("a clipped head acts in a box, not {action_space}")
    };
    let low = g.constant_f32("action_low", &[low.len() as i64], low);
    let high = g.constant_f32("action_high", &[high.len() as i64], high);
    let floor = g.node("Max", &[x, &low], vec![]);
    g.output_node("Min", &[&floor, &high], vec![]);
    Ok(tensor_type(DataType::Float, &[batch_dim(), fixed_dim(action_space.dim())]))
}

/// A squashed mode, tanh(μ) in [−1, 1], rescaled to the box: low + (a + 1) · (high − low) / 2.
fn squash_head(g: &mut GraphBuilder, squashed: &str, action_space: &Space) -> anyhow::Result<pb::TypeProto> {
    let Space::Box { low, high } = action_space else {
        anyhow::bail!("a squashed policy acts in a box, not {action_space}")
    };
    let half_range: Vec<f32> = low.iter().zip(high).map(|(l, h)| 0.5 * (h - l)).collect();
    let one = g.scalar_f32("one", 1.0);
    let half_range = g.constant_f32("action_half_range", &[low.len() as i64], &half_range);
    let low = g.constant_f32("action_low", &[low.len() as i64], low);
    let shifted = g.node("Add", &[squashed, &one], vec![]);
    let scaled = g.node("Mul", &[&shifted, &half_range], vec![]);
    g.output_node("Add", &[&low, &scaled], vec![]);
    Ok(tensor_type(DataType::Float, &[batch_dim(), fixed_dim(action_space.dim())]))
}

/// Nodes and constants, named as they are added.
#[derive(Default)]
struct GraphBuilder {
    nodes: Vec<pb::NodeProto>,
    initializers: Vec<pb::TensorProto>,
}

impl GraphBuilder {
    /// A `Gemm` (x Wᵀ + b) with the layer's tensors as constants `<name>.weight`, `<name>.bias`.
    fn dense(&mut self, layer: &DenseLayer, x: &str) -> String {
        let name = &layer.name;
        let w =
            self.constant_f32(&format!("{name}.weight"), &[layer.outputs as i64, layer.inputs as i64], &layer.weight);
        let b = self.constant_f32(&format!("{name}.bias"), &[layer.outputs as i64], &layer.bias);
        self.node("Gemm", &[x, &w, &b], vec![int_attr("transB", 1)])
    }

    /// Adds a node; returns the name of its output.
    fn node(&mut self, op: &str, inputs: &[&str], attribute: Vec<pb::AttributeProto>) -> String {
        let output = format!("{}_{}", op.to_lowercase(), self.nodes.len());
        self.push(op, inputs, attribute, output.clone());
        output
    }

    /// Adds the node whose output is the graph's.
    fn output_node(&mut self, op: &str, inputs: &[&str], attribute: Vec<pb::AttributeProto>) {
        self.push(op, inputs, attribute, OUTPUT.into());
    }

    fn push(&mut self, op: &str, inputs: &[&str], attribute: Vec<pb::AttributeProto>, output: String) {
        self.nodes.push(pb::NodeProto {
            name: format!("{op}_{}", self.nodes.len()),
            op_type: op.into(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output],
            attribute,
            ..Default::default()
        });
    }

    fn constant_f32(&mut self, name: &str, dims: &[i64], values: &[f32]) -> String {
        self.initializers.push(pb::TensorProto {
            name: name.into(),
            dims: dims.to_vec(),
            data_type: DataType::Float as i32,
            float_data: values.to_vec(),
            ..Default::default()
        });
        name.into()
    }

    fn scalar_f32(&mut self, name: &str, value: f32) -> String {
        self.constant_f32(name, &[], &[value])
    }

    fn constant_i64(&mut self, name: &str, values: &[i64]) -> String {
        self.initializers.push(pb::TensorProto {
            name: name.into(),
            dims: vec![values.len() as i64],
            data_type: DataType::Int64 as i32,
            int64_data: values.to_vec(),
            ..Default::default()
        });
        name.into()
    }

    fn constant_f64(&mut self, name: &str, values: &[f64]) -> String {
        self.initializers.push(pb::TensorProto {
            name: name.into(),
            dims: vec![values.len() as i64],
            data_type: DataType::Double as i32,
            double_data: values.to_vec(),
            ..Default::default()
        });
        name.into()
    }
}

fn int_attr(name: &str, value: i64) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Int as i32,
        i: value,
        ..Default::default()
    }
}

fn ints_attr(name: &str, values: &[i64]) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Ints as i32,
        ints: values.to_vec(),
        ..Default::default()
    }
}

fn batch_dim() -> pb::tensor_shape_proto::Dimension {
    pb::tensor_shape_proto::Dimension {
        value: Some(pb::tensor_shape_proto::dimension::Value::DimParam("batch".into())),
        ..Default::default()
    }
}

fn fixed_dim(size: usize) -> pb::tensor_shape_proto::Dimension {
    pb::tensor_shape_proto::Dimension {
        value: Some(pb::tensor_shape_proto::dimension::Value::DimValue(size as i64)),
        ..Default::default()
    }
}

fn tensor_type(elem_type: DataType, dims: &[pb::tensor_shape_proto::Dimension]) -> pb::TypeProto {
    pb::TypeProto {
        value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
            elem_type: elem_type as i32,
            shape: Some(pb::TensorShapeProto { dim: dims.to_vec() }),
        })),
        ..Default::default()
    }
}

fn value_info(name: &str, r#type: pb::TypeProto) -> pb::ValueInfoProto {
    pb::ValueInfoProto { name: name.into(), r#type: Some(r#type), ..Default::default() }
}
