#!/usr/bin/env bash
# Runs every test of the workspace (release build: some tests process whole KITTI files).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
cargo test --workspace --release "$@"
