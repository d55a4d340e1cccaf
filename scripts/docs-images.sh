#!/bin/sh
# Redraws the pictures in docs/ with the current code: the park world, the maps of
# paper_park (combined) and laser_only, and the built-in study's plots. About 10 minutes
# on 2 cores. Run from the repository root: scripts/docs-images.sh
set -eu
cargo build --release
objslam=target/release/objslam
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT

# `objslam run` exits 1 when a criterion fails (paper_park fails its recall today), 2 on an error.
run() {
    status=0
    "$objslam" run "$1" --seed 1 --out "$scratch/$1" > "$scratch/$1.txt" || status=$?
    if [ "$status" -gt 1 ]; then cat "$scratch/$1.txt"; exit "$status"; fi
}

"$objslam" world generate --preset park --seed 3 --out "$scratch/park.toml"
"$objslam" world plot "$scratch/park.toml" --out docs/park_world.png
run paper_park
cp "$scratch/paper_park/map.png" docs/paper_park_combined_map.png
run laser_only
cp "$scratch/laser_only/map.png" docs/laser_only_map.png
"$objslam" montecarlo study --runs 4 --out "$scratch/study"
cp "$scratch/study/odometry/failure_rate.png" docs/study_odometry.png
cp "$scratch/study/post_distance/failure_rate.png" docs/study_post_distance.png
echo "docs images redrawn"
