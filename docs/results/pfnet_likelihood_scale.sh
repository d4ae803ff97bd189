#!/usr/bin/env bash
# PF-net's likelihood temperature (`pfnet_likelihood`'s `likelihood_scale`): the shipped compact
# checkpoint, exact features, goalnav driving, tracking and semi-global on the seen apartments
# (the split we tune on; the passive table reports both), 50 episodes of 50 steps per cell, the
# same episodes for every scale. Prints the mean position error per scale as a markdown table.
#
#   cargo build --release && bash docs/results/pfnet_likelihood_scale.sh [OUT_DIR]
set -euo pipefail
apfn=${APFN:-${CARGO_TARGET_DIR:-target}/release/apfn}
out=${1:-results/pfnet_likelihood_scale}
scales=(${SCALES:-0.25 0.5 0.75 1.0 1.5})
mkdir -p "$out"
systems=$(cd systems && pwd)
echo "| likelihood_scale | tracking · seen (cm) | semi-global · seen (cm) |"
echo "|---|---|---|"
for scale in "${scales[@]}"; do
  config="$out/scale_$scale.ron"
  cat >"$config" <<RON
Eval(
    schedules: ["$systems/pfnet_passive.ron"],
    tasks: [tracking, semi_global],
    maps: [Apartments(split: seen, count: 10, params: (min_side_m: 5.0, max_side_m: 10.0, max_rooms: 5, mean_room_area_m2: 15.0, realism: ()))],
    episodes: 50,
    robots_per_map: 5,
    episode: (steps: 50),
    seed: 0,
    overrides: [("pfnet_likelihood", (checkpoint: Some("models/pfnet_compact.safetensors"), features: exact, likelihood_scale: $scale))],
)
RON
  "$apfn" eval --config "$config" --out "$out/scale_$scale" >/dev/null 2>&1
  # results.csv: …,task,split,…,mean_pos_err_m (column 9)
  row=$(awk -F, 'NR > 1 { printf " %.1f |", 100 * $9 }' "$out/scale_$scale/results.csv")
  echo "| $scale |$row"
done
