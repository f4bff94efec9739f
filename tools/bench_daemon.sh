#!/usr/bin/env bash
# Benchmarks of the multi-process daemon on this machine (numbers in docs/daemon.md):
# 1. one hop of an image and of 2048 keypoints: iceoryx2 between processes vs a crossbeam
#    channel between threads (p50, p99);
# 2. lossless throughput with one and two feature workers, with the real front end and with
#    a front end that waits 250 ms per frame on an (emulated) accelerator;
# 3. end-to-end latency per frame when KITTI is replayed in real time (10 Hz).
# Usage: tools/bench_daemon.sh [SEQ_DIR_SHORT] [SEQ_DIR_REALTIME]
set -euo pipefail
cd "$(dirname "$0")/.."
SHARED=${SUPERMVO_SHARED:-../shared}
SHORT=${1:-$SHARED/data/kitti/sequences/06}
LONG=${2:-$SHARED/data/kitti/sequences/03}
BIN=./target/release/supermvo
OUT=out/bench_daemon
mkdir -p "$OUT"
cargo build --release --workspace --bins -q
summary() {  # name, dir
  python3 - "$1" "$2" <<'PY'
import json, sys
name, d = sys.argv[1], sys.argv[2]
m = json.load(open(f"{d}/metrics.json"))
lat = m["stage_latency_ms"]
stages = ", ".join(f"{k} {v['p50']:.0f}" for k, v in lat.items())
e = m["end_to_end_ms"]
print(f"| {name} | {sum(m['frames'].values())} | {m['frames']} | {m['fps']:.2f} | {e['p50']:.0f} / {e['p95']:.0f} / {e['p99']:.0f} / {e['max']:.0f} | {stages} |")
PY
}
echo "== one hop"
$BIN bench ipc --samples 2000 | grep -v '^\['
echo
echo "| run | frames | status | fps | capture->pose p50 / p95 / p99 / max (ms) | stage p50 (ms) |"
echo "|---|---|---|---|---|---|"
for w in 1 2; do
  $BIN run "$SHORT" --out $OUT/real-w$w --workers $w --name bench -q > /dev/null
  summary "$(basename "$SHORT") lossless, real front end, $w feature worker(s)" $OUT/real-w$w
done
printf '[pipeline]\nthreads = 1\ntop_k = 512\nfeatures_extra_latency_ms = 250\n' > $OUT/slow.toml
for w in 1 2; do
  $BIN run "$SHORT" --out $OUT/slow-w$w --config $OUT/slow.toml --workers $w --name bench -q > /dev/null
  summary "$(basename "$SHORT") lossless, front end waiting 250 ms/frame, $w worker(s)" $OUT/slow-w$w
done
if cmp -s $OUT/slow-w1/trajectory.tum.txt $OUT/slow-w2/trajectory.tum.txt; then
  echo "(one and two workers give the same trajectory, byte for byte)"
fi
$BIN run "$LONG" --out $OUT/realtime --realtime --name bench -q > /dev/null
summary "$(basename "$LONG") real time (10 Hz)" $OUT/realtime
