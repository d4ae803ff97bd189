//! PF-net against the independent Keras implementation in `../shared/reference/pfnet_oracle`:
//! same weights, same case → the same log-likelihoods, loss and gradient of every weight.
//! Skips with a message when `../shared` is absent.

use apfn::nn::pfnet::{PfNet, PfNetConfig, verify};
use std::path::Path;

const REFERENCE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/reference/pfnet_oracle");

#[test]
fn pfnet_matches_the_keras_reference_forward_and_backward() {
    let dir = Path::new(REFERENCE);
    if !dir.join("case.safetensors").exists() {
        eprintln!("skipping: {REFERENCE} is absent (the Keras reference lives in ../shared)");
        return;
    }
    let report = verify(dir).expect("the reference folder loads");
    assert!(report.loglik_max_abs_err <= 1e-4, "log-likelihoods off by {}", report.loglik_max_abs_err);
    assert!(report.loss_rel_err <= 1e-4, "loss off by {} (relative)", report.loss_rel_err);
    assert!(
        report.grad_rel_err_max <= 1e-3,
        "gradient of {} off by {} (relative)",
        report.worst_grad,
        report.grad_rel_err_max
    );
}

#[test]
fn pfnet_paper_configuration_has_the_papers_parameter_count() {
    let model = PfNet::new(PfNetConfig::paper(), 0).unwrap();
    assert_eq!(model.param_counts().total, 1_017_497, "the paper's PF-net has 1,017,497 parameters");
    let compact = PfNet::new(PfNetConfig::compact(), 0).unwrap();
    assert!(compact.param_counts().total * 4 < 2_000_000, "a compact checkpoint must stay under 2 MB");
}
