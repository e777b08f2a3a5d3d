//! A field whose parameters are fresh autodiff leaves: the same ids, values and device,
//! for one chunk of a batch's forward and backward beside another's.
//!
//! burn's `Module::fork` moves every parameter with `to_device`, which autodiff records as
//! an op on the original leaf even when the device does not change. A parameter with no
//! gradient keeps its leaf from step to step (Adam replaces only what it updates), so each
//! fork left one more node in a graph that a live tensor holds and burn's sweep never
//! frees, while every backward's sweep walks all of them. With D_nr switched off for the
//! first quarter of a run, its six tensors grew a training step from ~35 to ~130 ms over
//! 2000 steps. `detach` makes the new leaf without recording anything on the old one.

use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;

use super::TalkinField;

/// Replaces every float parameter with a detached copy (tracked where it was tracked).
struct FreshLeaves;

impl ModuleMapper for FreshLeaves {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        // `detach` keeps `require_grad`: a trained parameter stays trained, a frozen one
        // frozen.
        param.map(|t| t.detach())
    }
}

/// `module` with fresh autodiff leaves for its parameters (see the module doc).
fn fork_leaves<M: Module>(module: &M) -> M {
    module.clone().map(&mut FreshLeaves)
}

impl TalkinField {
    /// This field with fresh autodiff leaves for its parameters (see the module doc): its
    /// gradients are keyed by the same parameter ids, and nothing is recorded on `self`'s
    /// graph, so two forks run forward and backward on two threads without their graphs
    /// merging or leaving nodes behind.
    pub fn fork_leaves(&self) -> TalkinField {
        fork_leaves(self)
    }
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use burn::module::{ModuleVisitor, ParamId};

    use super::super::tests::tiny_fast;
    use super::*;
    use crate::init::WeightRng;
    use crate::skinning::ladder_prior;

    /// A trained parameter that gets no gradient (D_nr before its start step) keeps its
    /// leaf for thousands of steps. Forking beside it must not make each backward slower:
    /// with burn's `fork`, the leaf's graph gained a node per fork and every backward's
    /// sweep walked them all (the median backward went from 77 us over the first 500 to
    /// 10.6 ms over the last 500).
    #[test]
    fn forks_leave_nothing_on_a_parameter_without_gradient() {
        #[derive(Module, Debug)]
        struct Two {
            used: Param<Tensor<1>>,
            unused: Param<Tensor<1>>,
        }
        let device = Device::flex().autodiff();
        let leaf = |v: f32| {
            Param::initialized(
                ParamId::new(),
                Tensor::<1>::full([4], v, &device).require_grad(),
            )
        };
        let two = Two {
            used: leaf(1.0),
            unused: leaf(2.0),
        };
        let (n, window) = (4000, 500);
        let mut seconds = Vec::with_capacity(n);
        for _ in 0..n {
            let fork = fork_leaves(&two);
            assert!(fork.unused.val().is_require_grad());
            let loss = fork.used.val().mul_scalar(3.0).sum();
            let start = Instant::now();
            let grads = loss.backward();
            seconds.push(start.elapsed().as_secs_f64());
            assert!(fork.used.val().grad(&grads).is_some());
        }
        let median = |s: &[f64]| {
            let mut s = s.to_vec();
            s.sort_by(f64::total_cmp);
            s[s.len() / 2]
        };
        let (first, last) = (median(&seconds[..window]), median(&seconds[n - window..]));
        assert!(
            last < 3.0 * first,
            "backward went from {:.1} to {:.1} us",
            first * 1e6,
            last * 1e6
        );
    }

    /// Every parameter of the fork holds the original's values under its id, tracked
    /// where the original is: a trained field's fork is trained, a frozen one's frozen.
    #[test]
    fn fork_keeps_ids_values_and_tracking() {
        struct Params(Vec<(ParamId, Vec<f32>, bool)>);
        impl ModuleVisitor for Params {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                let t = param.val();
                let tracked = t.is_require_grad();
                self.0
                    .push((param.id, t.try_to_vec_as::<f32>().unwrap(), tracked));
            }
        }
        let params = |field: &TalkinField| {
            let mut p = Params(Vec::new());
            field.visit(&mut p);
            p.0
        };
        let device = Device::flex().autodiff();
        let field = tiny_fast()
            .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
            .unwrap();
        let (a, b) = (params(&field), params(&field.fork_leaves()));
        assert!(
            a.len() > 10 && a.iter().all(|p| p.2),
            "{} parameters",
            a.len()
        );
        assert_eq!(a, b);
        let frozen = field.no_grad();
        let (a, b) = (params(&frozen), params(&frozen.fork_leaves()));
        assert!(a.iter().all(|p| !p.2));
        assert_eq!(a, b);
    }
}
