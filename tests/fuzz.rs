//! Smoke test of `apfn fuzz`: 1,000 mutated inputs per target, loaded as the CLI loads them, must
//! end without a panic or a hang (the full run, `apfn fuzz`, takes 100,000 per target).

use apfn::fuzz::{FuzzOptions, TARGETS, fuzz_target};
use std::path::PathBuf;
use std::time::Duration;

#[test]
fn fuzz_smoke_every_target_survives_1000_inputs() {
    let options = FuzzOptions {
        inputs: 1_000,
        seed: 1,
        budget: Duration::from_secs(2),
        root: PathBuf::from(env!("CARGO_MANIFEST_DIR")),
        findings: None,
    };
    for target in TARGETS {
        let report = fuzz_target(target, &options).expect("corpus and scratch folder");
        assert_eq!(report.inputs, 1_000, "{}: every input ran", target.name);
        assert_eq!((report.panics, report.hangs), (0, 0), "{}: {:#?}", target.name, report.findings);
        assert!(
            report.ok > 0 && report.clean_errors > 0,
            "{}: mutations both keep and break inputs: {report:?}",
            target.name
        );
    }
}
