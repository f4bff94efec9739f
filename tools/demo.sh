#!/usr/bin/env bash
# The main job. For now: evaluate the seed paper's published KITTI 00 trajectory and the
# ORB baseline against ground truth, with plots, into out/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
cargo build --release -p supermvo
DATA=${SUPERMVO_SHARED:-../shared}/data/trajectories/supermvo-paper
if [ ! -d "$DATA" ]; then
  echo "demo: $DATA not found: it holds the published KITTI 00 trajectories (set SUPERMVO_SHARED)" >&2
  exit 1
fi
mkdir -p out/demo
./target/release/supermvo eval --format tum --t-max-diff 0.02 --align sim3 \
  --gt "$DATA/00_gt_tum.txt" \
  --est "supermvo-paper=$DATA/00_supermvo_tum.txt" \
  --est "orb-baseline=$DATA/00_orb_tum.txt" \
  --json out/demo/eval.json --plot out/demo
echo
echo "demo: results in out/demo/eval.json, figures in out/demo/*.png"
