//! Where the tensors live: `--device cpu|wgpu|wgpu:N` parsed into a [`ComputeDevice`] and
//! opened into burn's [`Device`].
//!
//! `cpu` is burn's Flex backend (the fused kernels of this crate apply there). `wgpu` is
//! burn's wgpu backend on the first adapter wgpu lists, `wgpu:N` on the Nth; it exists
//! only in a build with the `wgpu` feature, and a build without it says so instead of
//! falling back to the CPU. Opening runs one tiny operation, so a machine without a
//! working adapter fails here, with a message, and not inside the first training step.

use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicUsize, Ordering};

use burn::prelude::*;
use burn::tensor::TensorReadError;
use serde::{Deserialize, Serialize};

/// A device named on the command line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ComputeDevice {
    /// burn's Flex CPU backend.
    #[default]
    Cpu,
    /// burn's wgpu backend on adapter `index` of wgpu's list (0: the first).
    Wgpu { index: usize },
}

/// Why a device could not be named or opened.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DeviceError {
    #[error("--device `{given}`: expected `cpu`, `wgpu` or `wgpu:N` (N: an adapter index)")]
    Parse { given: String },
    #[error(
        "--device {0}: this build has no GPU backend; build with `cargo build --release \
         --features wgpu`"
    )]
    NotBuilt(ComputeDevice),
    #[error(
        "--device {device}: wgpu lists {found} adapter(s){names}; on a machine without a GPU, \
         Mesa's lavapipe (Debian: `apt-get install mesa-vulkan-drivers`) provides one"
    )]
    NoAdapter {
        device: ComputeDevice,
        found: usize,
        names: String,
    },
    #[error("--device {device}: the adapter failed to start: {problem}")]
    Start {
        device: ComputeDevice,
        problem: String,
    },
}

impl fmt::Display for ComputeDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ComputeDevice::Cpu => write!(f, "cpu"),
            ComputeDevice::Wgpu { index: 0 } => write!(f, "wgpu"),
            ComputeDevice::Wgpu { index } => write!(f, "wgpu:{index}"),
        }
    }
}

impl FromStr for ComputeDevice {
    type Err = DeviceError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || DeviceError::Parse { given: s.into() };
        match s.trim().to_ascii_lowercase().as_str() {
            "cpu" => Ok(ComputeDevice::Cpu),
            "wgpu" => Ok(ComputeDevice::Wgpu { index: 0 }),
            other => {
                let index = other.strip_prefix("wgpu:").ok_or_else(bad)?;
                let index = index.parse::<usize>().map_err(|_| bad())?;
                Ok(ComputeDevice::Wgpu { index })
            }
        }
    }
}

impl Serialize for ComputeDevice {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for ComputeDevice {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

impl ComputeDevice {
    /// Whether this is a GPU device (its work is asynchronous: time it after a sync).
    pub fn is_gpu(&self) -> bool {
        matches!(self, ComputeDevice::Wgpu { .. })
    }

    /// Opens the device (without autodiff; `.autodiff()` the result to train).
    pub fn open(&self) -> Result<Device, DeviceError> {
        match *self {
            ComputeDevice::Cpu => Ok(Device::flex()),
            ComputeDevice::Wgpu { index } => open_wgpu(*self, index),
        }
    }

    /// What the device is, for reports: `cpu (Flex)` or the adapter's own name.
    pub fn describe(&self, device: &Device) -> String {
        match self {
            ComputeDevice::Cpu => "cpu (burn Flex)".into(),
            ComputeDevice::Wgpu { .. } => adapter_name(device)
                .map(|name| format!("{self} ({name})"))
                .unwrap_or_else(|| self.to_string()),
        }
    }
}

/// The first wgpu adapter, for the device kernels' tests (`device_op_*`).
#[cfg(all(test, feature = "wgpu"))]
pub(crate) fn test_wgpu() -> Device {
    ComputeDevice::Wgpu { index: 0 }
        .open()
        .expect("a wgpu adapter (lavapipe will do)")
}

/// Whether `device` (with or without autodiff) is the CPU backend, Flex: where work is
/// synchronous, the fused CPU kernels apply, and one batch is split over two threads.
pub fn is_cpu(device: &Device) -> bool {
    *device == Device::flex()
}

/// Reads on a GPU so far, by [`read_floats`].
static DEVICE_READBACKS: AtomicUsize = AtomicUsize::new(0);

/// Reads a float tensor back to the host. On a GPU that waits for all the work queued
/// before it, so every read there is counted ([`device_readbacks`]); the engine reads
/// device tensors only through here.
pub fn read_floats<const D: usize>(tensor: Tensor<D>) -> Result<Vec<f32>, TensorReadError> {
    if !is_cpu(&tensor.device()) {
        DEVICE_READBACKS.fetch_add(1, Ordering::Relaxed);
    }
    tensor.try_to_vec_as::<f32>()
}

/// How many times this process read a GPU tensor back ([`read_floats`]).
pub fn device_readbacks() -> usize {
    DEVICE_READBACKS.load(Ordering::Relaxed)
}

/// The most bytes one tensor may hold on `device`: on wgpu, a storage binding's limit
/// (the adapter's: 128 MiB on lavapipe, 4 GiB on NVIDIA's Vulkan driver). `None` on the
/// CPU, where only memory bounds a tensor.
pub fn max_tensor_bytes(device: &Device) -> Option<u64> {
    if is_cpu(device) {
        return None;
    }
    max_binding_bytes(device)
}

#[cfg(feature = "wgpu")]
fn max_binding_bytes(device: &Device) -> Option<u64> {
    use burn::backend::DispatchDevice;
    match device.clone().without_autodiff().as_dispatch() {
        DispatchDevice::Cube(cube) => Some(cube.client().properties().memory.max_page_size),
        _ => None,
    }
}

#[cfg(not(feature = "wgpu"))]
fn max_binding_bytes(_device: &Device) -> Option<u64> {
    None
}

#[cfg(feature = "wgpu")]
fn adapter_name(device: &Device) -> Option<String> {
    device.identity().map(|i| i.name)
}

#[cfg(not(feature = "wgpu"))]
fn adapter_name(_device: &Device) -> Option<String> {
    None
}

#[cfg(not(feature = "wgpu"))]
fn open_wgpu(device: ComputeDevice, _index: usize) -> Result<Device, DeviceError> {
    Err(DeviceError::NotBuilt(device))
}

#[cfg(feature = "wgpu")]
fn open_wgpu(asked: ComputeDevice, index: usize) -> Result<Device, DeviceError> {
    use burn::tensor::DeviceType;
    use std::panic::{AssertUnwindSafe, catch_unwind};

    let listed = catch_unwind(|| Device::enumerate(DeviceType::Wgpu).into_vec())
        .map_err(|e| start_error(asked, e))?;
    let Some(device) = listed.get(index).cloned() else {
        let names: Vec<String> = listed.iter().filter_map(adapter_name).collect();
        return Err(DeviceError::NoAdapter {
            device: asked,
            found: listed.len(),
            names: if names.is_empty() {
                String::new()
            } else {
                format!(" ({})", names.join(", "))
            },
        });
    };
    // One upload and readback: an adapter that lists but cannot run fails here.
    catch_unwind(AssertUnwindSafe(|| {
        let t = Tensor::<1>::from_floats([1.0, 2.0], &device);
        (t * 2.0).try_to_vec_as::<f32>()
    }))
    .map_err(|e| start_error(asked, e))?
    .map_err(|e| DeviceError::Start {
        device: asked,
        problem: format!("{e:?}"),
    })?;
    Ok(device)
}

#[cfg(feature = "wgpu")]
fn start_error(device: ComputeDevice, panic: Box<dyn std::any::Any + Send>) -> DeviceError {
    let problem = panic
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "a panic without a message".into());
    DeviceError::Start { device, problem }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_prints_every_form() {
        for (text, device) in [
            ("cpu", ComputeDevice::Cpu),
            ("CPU", ComputeDevice::Cpu),
            ("wgpu", ComputeDevice::Wgpu { index: 0 }),
            ("wgpu:0", ComputeDevice::Wgpu { index: 0 }),
            ("wgpu:3", ComputeDevice::Wgpu { index: 3 }),
        ] {
            assert_eq!(text.parse::<ComputeDevice>(), Ok(device), "{text}");
            assert_eq!(device.to_string().parse::<ComputeDevice>(), Ok(device));
        }
        for bad in ["", "gpu", "cuda", "wgpu:", "wgpu:-1", "wgpu:x", "cpu:0"] {
            let err = bad.parse::<ComputeDevice>().unwrap_err();
            assert!(
                err.to_string().contains("expected `cpu`, `wgpu`"),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn the_cpu_opens_and_is_flex() {
        let device = ComputeDevice::Cpu.open().unwrap();
        assert_eq!(device, Device::flex());
        assert!(is_cpu(&device) && is_cpu(&device.autodiff()));
    }

    #[cfg(not(feature = "wgpu"))]
    #[test]
    fn wgpu_without_the_feature_is_an_error_naming_the_build_flag() {
        let err = ComputeDevice::Wgpu { index: 0 }.open().unwrap_err();
        assert!(err.to_string().contains("--features wgpu"), "{err}");
    }

    #[cfg(feature = "wgpu")]
    #[test]
    fn an_adapter_past_the_list_is_an_error_not_a_panic() {
        let err = ComputeDevice::Wgpu { index: 999 }.open().unwrap_err();
        assert!(err.to_string().contains("adapter"), "{err}");
    }
}
