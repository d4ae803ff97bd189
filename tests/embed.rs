//! Runs the logic of `examples/embed.rs`: a user's bevy app with `ApfnPlugin` and its own policy.

#[path = "../examples/embed.rs"]
mod embed;

#[test]
fn embedded_app_localizes_with_a_user_policy() {
    let errors = embed::run(40);
    assert_eq!(errors.len(), 40, "one error per agent step");
    assert!(errors.iter().all(|e| e.is_finite()), "errors must stay finite: {errors:?}");
    let late = &errors[30..];
    let mean_late = late.iter().sum::<f32>() / late.len() as f32;
    assert!(mean_late < 0.5, "the filter should have converged from a semi-global start: {errors:?}");
}
