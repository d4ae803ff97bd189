//! The shipped real-map configs end to end on short runs: `scenes/eval_shared_maps_nav2.ron`
//! (12 m LiDAR, KLD-sampling 500–2,000) tracks within nav2's accuracy on two real ROS maps.
//! Skips (with a message) when `../shared/maps` is absent, as in a fresh clone.

use apfn::compose::read_ron;
use apfn::eval::{CellSpec, EvalConfig, run_cell};
use apfn::particles::Task;
use std::path::Path;

#[test]
fn nav2_config_tracks_within_ten_centimetres_on_real_maps() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    if !root.join("../shared/maps").is_dir() {
        eprintln!("skipping: ../shared/maps not found (real ROS maps live beside the project)");
        return;
    }
    let path = root.join("scenes/eval_shared_maps_nav2.ron");
    let mut config: EvalConfig = read_ron(&path).unwrap_or_else(|e| panic!("{e}"));
    // depot and turtlebot3_world, 10 episodes of 30 steps each, instead of 4 maps × 150 × 50.
    config
        .maps
        .retain(|group| ["nav2_depot", "nav2_turtlebot3_world"].contains(&group.split_label().as_str()));
    assert_eq!(config.maps.len(), 2, "the config lists the depot and the TurtleBot3 world");
    (config.episodes, config.robots_per_map, config.episode.steps) = (10, 5, 30);
    let eval = config.into_loaded(&path).unwrap_or_else(|e| panic!("{e}"));
    let goalnav =
        eval.schedules.iter().position(|(p, _)| p.ends_with("goalnav.ron")).expect("goalnav schedule");
    for group in 0..eval.scenes.len() {
        let cell = CellSpec { schedule: goalnav, task: Task::Tracking, group };
        let row = run_cell(&eval, &cell, || {}).unwrap_or_else(|e| panic!("{e}")).row;
        assert_eq!((row.localizer.as_str(), row.particles), ("mcl_kld", 2000), "{row:?}");
        assert!(row.final_pos_err_m < 0.10 && row.success_rate == 1.0, "{}: {row:?}", row.split);
    }
}
