//! Hard routing of samples to F_face and F_hands: a sample goes to a part's net when the
//! sampler's capsules made it a candidate of the part (host data) and F_body's segmentation labels it
//! that part (a device tensor).
//!
//! Two ways to read the labels, with the same outputs and gradients:
//! - on the host ([`Routing::OnHost`], the CPU's): the labels are read back and only the
//!   routed rows run the part's net;
//! - on the device ([`Routing::OnDevice`], a GPU's): every candidate row runs the part's
//!   net and the label picks, per row, the part's output or the body's. Nothing is read
//!   back mid-forward, at the price of the candidates the label turns away.

use burn::prelude::*;

use super::{argmax_rows, replace_rows};
use crate::rows::gather_rows;
use crate::util::{host, ints};

/// Where the routing labels are read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Routing {
    OnHost,
    OnDevice,
}

impl Routing {
    /// On the host for burn's CPU backend (a readback is a copy there, and fewer rows
    /// through the part nets is the saving), on the device for every other.
    pub fn for_device(device: &Device) -> Routing {
        if device.clone().without_autodiff() == Device::flex() {
            Routing::OnHost
        } else {
            Routing::OnDevice
        }
    }
}

/// One batch's candidates and labels.
pub(super) struct Router<'a> {
    part_masks: &'a [u8],
    labels: Labels,
}

/// Every sample's segmentation label, where [`Routing`] reads it.
enum Labels {
    OnHost(Vec<usize>),
    /// `[n]` (boxed: a tensor handle is ten times a `Vec`'s size).
    OnDevice(Box<Tensor<1, Int>>),
}

/// The rows one part's net runs on.
pub(super) struct Routed {
    /// Ascending sample indices.
    pub rows: Vec<usize>,
    /// `None` when every row is routed (the host read the labels); otherwise every
    /// sample's device label `[n]` and the part's: a row whose label is not the part's
    /// keeps the body's output.
    labels: Option<(Tensor<1, Int>, usize)>,
    /// On a CubeCL device, each sample's row among `rows` (`rows.len()` for none) `[n]`,
    /// uploaded once for all of the part's replaces.
    #[cfg(feature = "wgpu")]
    slot: std::cell::OnceCell<Tensor<1, Int>>,
}

impl<'a> Router<'a> {
    /// `seg_logits`: `[n, classes]`, one row per entry of `part_masks`.
    pub fn new(part_masks: &'a [u8], seg_logits: &Tensor<2>, routing: Routing) -> Router<'a> {
        let [n, classes] = seg_logits.dims();
        let labels = match routing {
            Routing::OnHost => Labels::OnHost(argmax_rows(&host(seg_logits), classes)),
            Routing::OnDevice => {
                Labels::OnDevice(Box::new(seg_logits.clone().detach().argmax(1).reshape([n])))
            }
        };
        Router { part_masks, labels }
    }

    /// The rows of the part with candidate bit `bit` and segmentation label `label`.
    pub fn rows(&self, bit: u8, label: usize) -> Routed {
        let candidates = (0..self.part_masks.len()).filter(|&i| self.part_masks[i] & bit != 0);
        match &self.labels {
            Labels::OnHost(labels) => Routed {
                rows: candidates.filter(|&i| labels[i] == label).collect(),
                labels: None,
                #[cfg(feature = "wgpu")]
                slot: Default::default(),
            },
            Labels::OnDevice(labels) => Routed {
                rows: candidates.collect(),
                labels: Some((labels.as_ref().clone(), label)),
                #[cfg(feature = "wgpu")]
                slot: Default::default(),
            },
        }
    }
}

impl Routed {
    /// The rows as a device index tensor.
    pub fn indices(&self, device: &Device) -> Tensor<1, Int> {
        index_tensor(&self.rows, device)
    }

    /// Per row, whether the part's output replaces the body's (`[rows]`, on the device;
    /// `None` when every row is routed).
    fn keep(&self) -> Option<Tensor<1, Bool>> {
        let (labels, label) = self.labels.as_ref()?;
        let rows = self.indices(&labels.device());
        Some(labels.clone().select(0, rows).equal_elem(*label as i64))
    }

    /// `base` with the routed rows' values from `values` (`[rows, ..]`); a candidate the
    /// label turned away keeps `base`'s.
    pub fn replace<const D: usize>(&self, base: Tensor<D>, values: Tensor<D>) -> Tensor<D> {
        #[cfg(feature = "wgpu")]
        if let Some((labels, label)) = &self.labels
            && !crate::device::is_cpu(&base.device())
        {
            // One device op reads the labels and puts the rows back
            // (`kernels::cube::routed`).
            let slot = self.slot.get_or_init(|| {
                let (n, h) = (base.dims()[0], self.rows.len());
                let mut slot = vec![h as i32; n];
                for (k, &i) in self.rows.iter().enumerate() {
                    slot[i] = k as i32;
                }
                ints(slot, &base.device())
            });
            return crate::kernels::cube::routed::replace(
                base,
                values,
                slot.clone(),
                labels.clone(),
                *label as i32,
            );
        }
        let values = match self.keep() {
            None => values,
            Some(keep) => {
                let device = base.device();
                let old = gather_rows(base.clone(), self.indices(&device));
                old.mask_where(broadcast(&keep, &values), values)
            }
        };
        replace_rows(base, &self.rows, values)
    }

    /// `values` (`[rows]`) with `fill` where the label turned a candidate away.
    pub fn keep_or(&self, values: Tensor<1>, fill: f32) -> Tensor<1> {
        match self.keep() {
            None => values,
            Some(keep) => values.mask_fill(keep.bool_not(), fill),
        }
    }
}

fn index_tensor(rows: &[usize], device: &Device) -> Tensor<1, Int> {
    ints(rows.iter().map(|&i| i as i32).collect(), device)
}

/// `keep` (`[h]`) shaped like `like` (`[h, ..]`).
fn broadcast<const D: usize>(keep: &Tensor<1, Bool>, like: &Tensor<D>) -> Tensor<D, Bool> {
    let dims = like.dims();
    let mut shape = [1usize; D];
    shape[0] = dims[0];
    keep.clone().reshape(shape).expand(dims)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::{PART_BIT_HANDS, PART_BIT_HEAD, SEG_HANDS, SEG_HEAD};

    /// The replaced rows, the filled rows' weighted sum, the points' gradient and each
    /// part's row count, for twelve samples (each part's candidates, some labelled the
    /// part and some not) routed as `routing` says on `device`.
    fn route_twelve(device: &Device, routing: Routing) -> RoutedCase {
        let n = 12;
        let parts: Vec<u8> = (0..n)
            .map(|i| {
                [
                    PART_BIT_HEAD,
                    PART_BIT_HANDS,
                    PART_BIT_HEAD | PART_BIT_HANDS,
                    0,
                ][i % 4]
            })
            .collect();
        let logits: Vec<f32> = (0..n)
            .flat_map(|i| {
                let mut row = [0.0f32; 5];
                row[[SEG_HEAD, SEG_HANDS, 0][i % 3]] = 1.0;
                row
            })
            .collect();
        let seg = Tensor::<2>::from_data(TensorData::new(logits, [n, 5]), device);
        let x: Vec<f32> = (0..n * 3).map(|k| k as f32 * 0.1 - 1.0).collect();
        let x = Tensor::<2>::from_data(TensorData::new(x, [n, 3]), device).require_grad();
        let router = Router::new(&parts, &seg, routing);
        let head = router.rows(PART_BIT_HEAD, SEG_HEAD);
        let hands = router.rows(PART_BIT_HANDS, SEG_HANDS);
        // A part's "net": doubles (head) or squares (hands) its rows.
        let part = |r: &Routed| x.clone().select(0, r.indices(device));
        let y = head.replace(x.clone(), part(&head) * 2.0);
        let y = hands.replace(y, part(&hands).powf_scalar(2.0));
        // A one-column replace too (the densities'), through the rows' sums.
        let y1 = head.replace(
            x.clone().sum_dim(1).reshape([n]),
            part(&head).sum_dim(1).reshape([head.rows.len()]) * 3.0,
        );
        let filled = hands.keep_or(part(&hands).sum_dim(1).reshape([hands.rows.len()]), 0.0);
        let total = hands.indices(device).float().mul(filled.clone()).sum();
        let loss = y.clone().sum() + (y1.clone() * y1.clone()).sum() + total.clone();
        let g = x.grad(&loss.backward()).unwrap();
        (
            [host(&y), host(&y1), host(&total.reshape([1])), host(&g)],
            (head.rows.len(), hands.rows.len()),
        )
    }

    type RoutedCase = ([Vec<f32>; 4], (usize, usize));

    /// Replacing rows and filling turned-away rows gives the same values and gradients
    /// with the labels read on the host and on the device.
    #[test]
    fn replace_and_fill_agree_on_host_and_device() {
        let device = Device::flex().autodiff();
        let (host_out, rows_h) = route_twelve(&device, Routing::OnHost);
        let (device_out, rows_d) = route_twelve(&device, Routing::OnDevice);
        assert!(
            rows_h.0 > 0 && rows_h.0 < rows_d.0,
            "{rows_h:?} vs {rows_d:?}"
        );
        assert!(
            rows_h.1 > 0 && rows_h.1 < rows_d.1,
            "{rows_h:?} vs {rows_d:?}"
        );
        assert_eq!(host_out, device_out);
    }

    /// The routed replace's device op (`kernels::cube::routed`) against the host-routed
    /// CPU: values and the points' gradient, several columns and one.
    #[cfg(feature = "wgpu")]
    #[test]
    #[ignore = "needs a Vulkan adapter (lavapipe will do): \
                cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
    fn device_op_routes_like_the_host() {
        let gpu = crate::device::test_wgpu().autodiff();
        let (cpu, _) = route_twelve(&Device::flex().autodiff(), Routing::OnHost);
        let (dev, _) = route_twelve(&gpu, Routing::for_device(&gpu));
        assert_eq!(Routing::for_device(&gpu), Routing::OnDevice);
        let names = ["rows", "one column", "filled", "gradient"];
        for (what, (a, b)) in names.into_iter().zip(dev.iter().zip(&cpu)) {
            crate::util::assert_close_to(what, a, b, 1e-6);
        }
    }
}
