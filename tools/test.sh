#!/usr/bin/env bash
# Runs every test of the workspace (release build: some tests process whole KITTI files).
# First obtains ONNX Runtime and the learned models (cached in ~/.cache/supermvo, or
# $SUPERMVO_CACHE; a second run downloads nothing).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
# the binaries and the tests in one build: built apart, the tests' dev-dependencies change
# the features of shared dependencies (faer, nalgebra, image) and compile them all twice
cargo build --release --workspace --bins --tests --examples
./target/release/supermvo models fetch onnxruntime xfeat lighterglue lighterglue-l3 aliked lightglue
# the independent Python readers the diagnostic tests use (iceoryx2 bindings, mcap)
bash tools/python_tools.sh
# SuperPoint and SuperGlue exporters (random weights in the official layout) against NumPy
# forward passes written from the papers
python3 tools/models/test_superpoint_superglue.py
# ALIKED and LightGlue exports (real weights) against NumPy forward passes
python3 tools/models/test_aliked_lightglue.py
# the landmark depth check against a ground truth (docs/vo.md), on constructed landmarks
python3 tools/landmark_depth_check.py --self-test
# the scale per stretch and per N frames of a run (docs/decisions), on constructed drives
python3 tools/drive_scale.py --self-test
# the lens refinement's root finding, on a made-up reading
python3 tools/lens_refine.py --self-test
# the vo crate's long statistical runs too (plain `cargo test` skips them, saying so)
SUPERMVO_LONG_TESTS=1 cargo test --workspace --release "$@"
