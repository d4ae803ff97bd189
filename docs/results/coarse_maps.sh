#!/usr/bin/env bash
# Tracking on 0.1 m maps with unknown regions, as older ROS maps are: aws_small_house from
# ../shared/maps resampled to 0.1 m with unknown areas kept, once keeping its walls and once as
# shrinking its image would (thin walls beside unknown space fade into unknown), and the
# procedural apartment 1000003 generated at 0.1 m (unknown beyond its outer walls). For each map and seed 0–9: record
# 50 steps of a randomly driving robot (228-beam 240° LiDAR, rays stop at unknown cells), then
# replay the log with 2,000 particles from a start 0.36 m off the true one (heading true, the
# offset's direction turning 36° per seed), with the likelihood-field and the beam model.
# Prints the final position error of every run as a markdown table.
#
#   cargo build --release && bash docs/results/coarse_maps.sh [OUT_DIR]
#
# Extra `apfn localize` flags go in LOCALIZE_ARGS (e.g. LOCALIZE_ARGS="--alpha 1").
set -euo pipefail
apfn=${APFN:-${CARGO_TARGET_DIR:-target}/release/apfn}
out=${1:-results/coarse_maps}
shared=${SHARED_MAPS:-../shared/maps}
mkdir -p "$out"
"$apfn" map resample "$shared/aws_small_house.yaml" --resolution 0.1 --out "$out/aws_small_house_0.1.yaml" >/dev/null
"$apfn" map resample "$shared/aws_small_house.yaml" --resolution 0.1 --rule average_image \
  --out "$out/aws_small_house_0.1_averaged.yaml" >/dev/null
"$apfn" map export --procedural 1000003 --resolution 0.1 --out "$out" >/dev/null
maps=(aws_small_house_0.1 aws_small_house_0.1_averaged apartment_1000003)
models=(likelihood_field beam)

final_error_cm() { # localize's "vs truth … final X cm" line → X
  sed -n 's/^vs truth.*final \([0-9.]*\) cm$/\1/p'
}

echo "| map | model | final error per seed 0–9, cm | ≤ 10 cm | median cm |"
echo "|---|---|---|---|---|"
for map in "${maps[@]}"; do
  declare -A finals=()
  for seed in {0..9}; do
    scene="$out/${map}_$seed.ron"
    echo "Scene(maps: Ros(path: \"$map.yaml\"), robots_per_map: 1, seed: $seed, episode: (steps: 50))" >"$scene"
    log="$out/${map}_$seed.jsonl"
    "$apfn" record --scene "$scene" --steps 50 --out "$log" >/dev/null
    read -r x y yaw < <(sed -n '1s/.*"truth":\[\([^]]*\)\].*/\1/p' "$log" | tr ',' ' ')
    init=$(awk -v x="$x" -v y="$y" -v yaw="$yaw" -v s="$seed" \
      'BEGIN { a = s * 36 * atan2(0, -1) / 180; printf "%.4f,%.4f,%.4f", x + 0.36 * cos(a), y + 0.36 * sin(a), yaw }')
    for model in "${models[@]}"; do
      # shellcheck disable=SC2086 # LOCALIZE_ARGS holds several flags
      e=$("$apfn" localize --map "$out/$map.yaml" --log "$log" --init "$init" --particles 2000 --model "$model" \
        --seed "$seed" ${LOCALIZE_ARGS:-} --out "$out/${map}_${seed}_$model.est.jsonl" 2>/dev/null | final_error_cm)
      finals[$model]="${finals[$model]:-} $e"
    done
  done
  for model in "${models[@]}"; do
    read -r -a v <<<"${finals[$model]}"
    sorted=$(printf '%s\n' "${v[@]}" | sort -g | tr '\n' ' ')
    awk -v map="$map" -v model="$model" -v all="${v[*]}" -v sorted="$sorted" 'BEGIN {
      n = split(all, a, " "); split(sorted, s, " ");
      for (k = 1; k <= n; k++) ok += (a[k] <= 10.0);
      printf "| %s | %s | %s | %d of %d | %.1f |\n", map, model, all, ok, n, (s[n / 2] + s[n / 2 + 1]) / 2 }'
  done
  unset finals
done
