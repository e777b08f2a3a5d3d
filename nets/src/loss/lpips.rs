use std::path::{Path, PathBuf};

use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{PaddingConfig2d, Relu};
use burn::tensor::{Device, Tensor, TensorData};
use safetensors::{Dtype, SafeTensors};

use super::LossError;

/// The LPIPS backbone. Both use the LPIPS v0.1 linear heads of the same file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backbone {
    /// AlexNet taps relu1..relu5 (~2.5M parameters, the LPIPS default).
    Alex,
    /// VGG16 taps relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 (~14.7M parameters).
    Vgg,
}

/// One backbone convolution: input/output channels, square kernel, stride, padding.
struct ConvSpec {
    c_in: usize,
    c_out: usize,
    kernel: usize,
    stride: usize,
    padding: usize,
}

const fn conv(c_in: usize, c_out: usize, kernel: usize, stride: usize, padding: usize) -> ConvSpec {
    ConvSpec {
        c_in,
        c_out,
        kernel,
        stride,
        padding,
    }
}

/// One stage: an optional max-pool, convolutions each followed by ReLU, then a tap.
struct StageSpec {
    pool_before: bool,
    convs: &'static [ConvSpec],
}

const ALEX: &[StageSpec] = &[
    StageSpec {
        pool_before: false,
        convs: &[conv(3, 64, 11, 4, 2)],
    },
    StageSpec {
        pool_before: true,
        convs: &[conv(64, 192, 5, 1, 2)],
    },
    StageSpec {
        pool_before: true,
        convs: &[conv(192, 384, 3, 1, 1)],
    },
    StageSpec {
        pool_before: false,
        convs: &[conv(384, 256, 3, 1, 1)],
    },
    StageSpec {
        pool_before: false,
        convs: &[conv(256, 256, 3, 1, 1)],
    },
];

const VGG: &[StageSpec] = &[
    StageSpec {
        pool_before: false,
        convs: &[conv(3, 64, 3, 1, 1), conv(64, 64, 3, 1, 1)],
    },
    StageSpec {
        pool_before: true,
        convs: &[conv(64, 128, 3, 1, 1), conv(128, 128, 3, 1, 1)],
    },
    StageSpec {
        pool_before: true,
        convs: &[
            conv(128, 256, 3, 1, 1),
            conv(256, 256, 3, 1, 1),
            conv(256, 256, 3, 1, 1),
        ],
    },
    StageSpec {
        pool_before: true,
        convs: &[
            conv(256, 512, 3, 1, 1),
            conv(512, 512, 3, 1, 1),
            conv(512, 512, 3, 1, 1),
        ],
    },
    StageSpec {
        pool_before: true,
        convs: &[
            conv(512, 512, 3, 1, 1),
            conv(512, 512, 3, 1, 1),
            conv(512, 512, 3, 1, 1),
        ],
    },
];

/// ImageNet-normalising shift and scale of the LPIPS `ScalingLayer`, for inputs in [-1, 1].
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// Added inside the square root of the channel norm so that its gradient stays finite at
/// all-zero feature columns (frequent after ReLU on 32x32 patches). Invisible in f32 for
/// any non-zero column; the original's `eps = 1e-10` outside the root is kept as well.
const NORM_EPS_SQ: f64 = 1e-20;
const NORM_EPS: f64 = 1e-10;

impl Backbone {
    fn stages(self) -> &'static [StageSpec] {
        match self {
            Backbone::Alex => ALEX,
            Backbone::Vgg => VGG,
        }
    }

    /// The pooling between stages: 3x3 stride 2 for AlexNet, 2x2 stride 2 for VGG16.
    fn pool_size(self) -> (usize, usize) {
        match self {
            Backbone::Alex => (3, 2),
            Backbone::Vgg => (2, 2),
        }
    }

    /// File name that `scripts/lpips_weights.py` writes for this backbone.
    pub fn file_name(self) -> &'static str {
        match self {
            Backbone::Alex => "alex.safetensors",
            Backbone::Vgg => "vgg.safetensors",
        }
    }

    /// Lower-case name (`"alex"`, `"vgg"`).
    pub fn name(self) -> &'static str {
        match self {
            Backbone::Alex => "alex",
            Backbone::Vgg => "vgg",
        }
    }

    /// Channels of the five feature taps (= inputs of the linear heads).
    pub fn tap_channels(self) -> [usize; 5] {
        let mut out = [0; 5];
        for (o, stage) in out.iter_mut().zip(self.stages()) {
            *o = stage.convs.last().map_or(0, |c| c.c_out);
        }
        out
    }
}

impl std::fmt::Display for Backbone {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// LPIPS v0.1 (Zhang et al. 2018): ImageNet scaling, backbone feature taps, channel-unit
/// normalisation, squared difference, non-negative 1x1 linear heads, spatial average, sum
/// over the five taps. Weights are frozen (`no_grad`); gradients flow to the inputs.
///
/// Load with [`Lpips::load`] from the safetensors files of `scripts/lpips_weights.py`.
#[derive(Module, Debug)]
pub struct Lpips {
    /// Backbone convolutions in order, each followed by ReLU.
    convs: Vec<Conv2d>,
    /// The five linear heads, 1x1 convolutions `[1, C_k, 1, 1]` without bias.
    heads: Vec<Conv2d>,
    pool: MaxPool2d,
    relu: Relu,
    /// Number of convolutions of each stage (a tap after each stage).
    stage_convs: Vec<usize>,
    /// Whether each stage starts with the max-pool.
    pool_before: Vec<bool>,
    #[module(skip)]
    backbone: Backbone,
}

impl Lpips {
    /// Loads the weights of `backbone` from a safetensors file.
    ///
    /// Tensor names: `features.conv{i}.weight` `[out, in, k, k]` and `features.conv{i}.bias`
    /// `[out]` for the backbone convolutions in order (5 for AlexNet, 13 for VGG16), and
    /// `lin{k}.weight` `[1, C_k, 1, 1]` for the heads. The module is frozen: on an
    /// autodiff device gradients flow to the images only.
    pub fn load(path: &Path, backbone: Backbone, device: &Device) -> Result<Lpips, LossError> {
        let bytes = std::fs::read(path).map_err(|source| LossError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let file = SafeTensors::deserialize(&bytes).map_err(|e| LossError::Format {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let reader = Reader {
            path,
            file: &file,
            device,
        };

        let mut convs = Vec::new();
        let mut stage_convs = Vec::new();
        let mut pool_before = Vec::new();
        let mut index = 0;
        for stage in backbone.stages() {
            for spec in stage.convs {
                let weight = reader.tensor::<4>(
                    &format!("features.conv{index}.weight"),
                    [spec.c_out, spec.c_in, spec.kernel, spec.kernel],
                    false,
                )?;
                let bias = reader.tensor::<1>(
                    &format!("features.conv{index}.bias"),
                    [spec.c_out],
                    false,
                )?;
                convs.push(conv2d_module(
                    weight,
                    Some(bias),
                    spec.kernel,
                    spec.stride,
                    spec.padding,
                ));
                index += 1;
            }
            stage_convs.push(stage.convs.len());
            pool_before.push(stage.pool_before);
        }
        let mut heads = Vec::new();
        for (k, c) in backbone.tap_channels().into_iter().enumerate() {
            let weight = reader.tensor::<4>(&format!("lin{k}.weight"), [1, c, 1, 1], true)?;
            heads.push(conv2d_module(weight, None, 1, 1, 0));
        }
        let (pool_k, pool_s) = backbone.pool_size();
        let lpips = Lpips {
            convs,
            heads,
            pool: MaxPool2dConfig::new([pool_k, pool_k])
                .with_strides([pool_s, pool_s])
                .init(),
            relu: Relu::new(),
            stage_convs,
            pool_before,
            backbone,
        };
        Ok(lpips.no_grad())
    }

    /// The backbone these weights belong to.
    pub fn backbone(&self) -> Backbone {
        self.backbone
    }

    /// LPIPS distance per image pair, inputs in `[-1, 1]` (the `lpips` package convention).
    /// Differentiable w.r.t. both inputs; `target` is usually a constant.
    ///
    /// The spatial size must survive the backbone: at least 32x32 is safe for both
    /// (AlexNet needs >= 31, VGG16 >= 16).
    ///
    /// # Shapes
    /// - `pred`, `target`: `[N, 3, H, W]`
    /// - output: `[N]`
    pub fn forward(&self, pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        let [n, c, _, _] = pred.dims();
        assert_eq!(pred.dims(), target.dims(), "lpips: shapes differ");
        assert_eq!(c, 3, "lpips: images must have 3 channels");
        let pairs: Vec<(Tensor<4>, Tensor<4>)> = if pred.is_tracked() && !target.is_tracked() {
            // Training: a separate, untracked pass for the constant target keeps the
            // backward pass to the N predictions.
            self.taps(pred).into_iter().zip(self.taps(target)).collect()
        } else {
            // One backbone pass over both images.
            self.taps(Tensor::cat(vec![pred, target], 0)) // [2N, C, h, w] per tap
                .into_iter()
                .map(|f| (f.clone().narrow(0, 0, n), f.narrow(0, n, n)))
                .collect()
        };
        let mut total: Option<Tensor<1>> = None;
        for ((f0, f1), head) in pairs.into_iter().zip(&self.heads) {
            let [_, _, h, w] = f0.dims();
            let diff = f0 - f1;
            let d = head.forward(diff.clone() * diff); // [N, 1, h, w]
            let d = d.reshape([n, h * w]).mean_dim(1).reshape([n]); // [N]
            total = Some(match total {
                Some(t) => t + d,
                None => d,
            });
        }
        total.expect("a backbone has five taps")
    }

    /// The five channel-normalised feature taps of images in `[-1, 1]`.
    ///
    /// # Shapes
    /// - `x`: `[B, 3, H, W]`
    /// - output: five `[B, C_k, h_k, w_k]`
    fn taps(&self, x: Tensor<4>) -> Vec<Tensor<4>> {
        let device = x.device();
        let shift = Tensor::<1>::from_floats(SHIFT, &device).reshape([1, 3, 1, 1]);
        let scale = Tensor::<1>::from_floats(SCALE, &device).reshape([1, 3, 1, 1]);
        let mut x = (x - shift) / scale;
        let mut out = Vec::with_capacity(self.stage_convs.len());
        let mut convs = self.convs.iter();
        for (&count, &pool) in self.stage_convs.iter().zip(&self.pool_before) {
            if pool {
                x = self.pool.forward(x);
            }
            for conv in convs.by_ref().take(count) {
                x = self.relu.forward(conv.forward(x));
            }
            out.push(normalize_channels(x.clone()));
        }
        out
    }

    /// [`forward`](Self::forward) for images in `[0, 1]` (maps them to `[-1, 1]`).
    ///
    /// # Shapes
    /// - `pred`, `target`: `[N, 3, H, W]`
    /// - output: `[N]`
    pub fn forward_unit(&self, pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        self.forward(pred * 2.0 - 1.0, target * 2.0 - 1.0)
    }
}

/// `x / (||x||_channels + eps)` per pixel.
fn normalize_channels(x: Tensor<4>) -> Tensor<4> {
    let norm = (x.clone() * x.clone())
        .sum_dim(1)
        .add_scalar(NORM_EPS_SQ)
        .sqrt(); // [B, 1, h, w]
    x / (norm + NORM_EPS)
}

fn conv2d_module(
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    kernel: usize,
    stride: usize,
    padding: usize,
) -> Conv2d {
    Conv2d {
        weight: Param::from_tensor(weight),
        bias: bias.map(Param::from_tensor),
        stride: [stride, stride],
        kernel_size: [kernel, kernel],
        dilation: [1, 1],
        groups: 1,
        padding: PaddingConfig2d::Explicit(padding, padding, padding, padding),
    }
}

struct Reader<'a> {
    path: &'a Path,
    file: &'a SafeTensors<'a>,
    device: &'a Device,
}

impl Reader<'_> {
    /// Reads an f32 tensor of exactly `expected` shape; `non_negative` also rejects
    /// negative values. Every value must be finite.
    fn tensor<const D: usize>(
        &self,
        name: &str,
        expected: [usize; D],
        non_negative: bool,
    ) -> Result<Tensor<D>, LossError> {
        let path: PathBuf = self.path.to_path_buf();
        let view = self
            .file
            .tensor(name)
            .map_err(|_| LossError::MissingTensor {
                path: path.clone(),
                name: name.to_string(),
                expected: expected.to_vec(),
            })?;
        if view.dtype() != Dtype::F32 {
            return Err(LossError::Dtype {
                path,
                name: name.to_string(),
                found: format!("{:?}", view.dtype()),
                expected: expected.to_vec(),
            });
        }
        if view.shape() != expected {
            return Err(LossError::Shape {
                path,
                name: name.to_string(),
                found: view.shape().to_vec(),
                expected: expected.to_vec(),
            });
        }
        let values: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if let Some((index, &value)) = values
            .iter()
            .enumerate()
            .find(|&(_, &v)| !v.is_finite() || (non_negative && v < 0.0))
        {
            return Err(LossError::BadValue {
                path,
                name: name.to_string(),
                expected: expected.to_vec(),
                index,
                value,
            });
        }
        Ok(Tensor::from_data(
            TensorData::new(values, expected),
            self.device,
        ))
    }
}
