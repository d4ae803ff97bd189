//! `apfn eval --figures N`: one PNG per cell and episode, decodable, named after the cell.

use apfn::cli::{Cli, run};
use clap::Parser;

const SCHEDULE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/systems/random.ron");

#[test]
fn eval_figures_writes_one_png_per_episode() {
    let dir = tempfile::tempdir().expect("temp dir");
    let config = dir.path().join("eval.ron");
    let text = format!(
        "Eval(schedules: [{SCHEDULE:?}], tasks: [tracking], maps: [Apartments(split: seen, count: 1)], \
         episodes: 2, robots_per_map: 2, episode: (steps: 10))"
    );
    std::fs::write(&config, text).expect("write config");
    let out = dir.path().join("out");
    let args = ["apfn", "eval", "--config", config.to_str().expect("utf-8 path"), "--figures", "2"];
    let cli = Cli::try_parse_from(args.into_iter().chain(["--out", out.to_str().expect("utf-8 path")]))
        .expect("--figures parses");
    run(cli).expect("eval with figures runs");
    let mut names: Vec<String> = std::fs::read_dir(out.join("figures"))
        .expect("a figures folder")
        .map(|e| e.expect("dir entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["mcl_random_tracking_seen_ep0.png", "mcl_random_tracking_seen_ep1.png"],
        "first 2 episodes"
    );
    for name in &names {
        let img =
            image::open(out.join("figures").join(name)).unwrap_or_else(|e| panic!("{name} decodes: {e}"));
        assert!(
            img.width() > 600 && img.height() > 300,
            "{name} is a full figure: {}×{}",
            img.width(),
            img.height()
        );
    }
}
