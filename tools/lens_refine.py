#!/usr/bin/env python3
"""Refine a camera's radial coefficient k1 from a drive, without ground truth.

`supermvo run --lens-check` reports the radial coefficient that the local bundle
adjustments ask for beyond the lens they were given. The reading is attenuated (each window's
fixed keyframes were posed with the lens given), but it is zero where the lens is right and
changes sign across it. So this runs the sequence with one k1, then another, and moves k1 to
where the reading crosses zero (the secant method), until it reads within `--tol`. It writes
the refined camera file, which `supermvo run --camera FILE` then uses.

    python3 tools/lens_refine.py SEQ --out camera.yaml [--camera BASE.yaml] [--step 0.01]
                                 [--iterations 4] [--tol 0.0002] [-- RUN ARGS]

The starting lens is BASE.yaml (ORB-SLAM3 layout, pinhole with k1 k2 p1 p2 k3) or the KITTI
`calib.txt` of SEQ (k1 = 0). The drive must turn: on a straight road the radial term and
the depths cannot be told apart, and the reading is noise
(docs/decisions/2026-12-07-kitti-lens-residual-and-turn-scale.md). It is not reliable
everywhere: on the synthetic `lighting` drive, whose exposure changes, the reading is +0.004
at the exact lens. Check a refined lens against ground truth where there is some. `--self-test` checks the
root finding on a made-up reading.
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KEYS = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]


def read_lens(seq, base):
    """The starting lens: {key: value} with the pinhole intrinsics and k1 k2 p1 p2 k3."""
    if base:
        with open(base) as f:
            text = f.read()
        if not re.search(r'Camera\.type:\s*"?PinHole', text):
            sys.exit(f"lens_refine: {base}: only a PinHole camera (radial-tangential) is refined")
        lens = {}
        for k in KEYS:
            m = re.search(rf"^Camera\.{k}:\s*([-+0-9.eE]+)", text, re.M)
            if m is None and k in ("fx", "fy", "cx", "cy"):
                sys.exit(f"lens_refine: {base}: no Camera.{k}")
            lens[k] = float(m.group(1)) if m else 0.0
        return lens
    calib = os.path.join(seq, "calib.txt")
    try:
        with open(calib) as f:
            p0 = next(line.split()[1:] for line in f if line.startswith("P0:"))
        fx, cx, fy, cy = (float(p0[i]) for i in (0, 2, 5, 6))
    except (OSError, StopIteration, IndexError, ValueError):
        sys.exit(f"lens_refine: {calib}: no P0 line; give the starting lens with --camera")
    return dict(fx=fx, fy=fy, cx=cx, cy=cy, k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0)


def png_size(path):
    """Width and height of a PNG file, or None when it is not one."""
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def image_size(seq):
    """Width and height of the first PNG frame of a KITTI-layout sequence."""
    folder = os.path.join(seq, "image_0")
    for name in sorted(os.listdir(folder)) if os.path.isdir(folder) else []:
        size = png_size(os.path.join(folder, name))
        if size:
            return size
    sys.exit(f"lens_refine: {folder}: no PNG frame to read the image size from")


def write_lens(path, lens, size, note="refined by tools/lens_refine.py (k1 from the local BAs' lens check)"):
    """An ORB-SLAM3 camera file (PinHole, radial-tangential) with `lens` and image `size`."""
    with open(path, "w") as f:
        f.write(f"%YAML:1.0\n# {note}\n")
        f.write(f'Camera.type: "PinHole"\nCamera.width: {size[0]}\nCamera.height: {size[1]}\n')
        for k in KEYS:
            f.write(f"Camera.{k}: {lens[k]!r}\n")


def refine(read, k1, step, iterations, tol):
    """Secant steps on `read(k1)` (the reading at k1) towards its zero: the list of
    (k1, reading) tried, the last one the refined lens."""
    tried = [(k1, read(k1))]
    if abs(tried[0][1]) <= tol:
        return tried
    # the reading points where the lens lies: step that way first
    k_next = k1 + (step if tried[0][1] > 0 else -step)
    for _ in range(iterations):
        tried.append((k_next, read(k_next)))
        (ka, ra), (kb, rb) = tried[-2], tried[-1]
        if abs(rb) <= tol or rb == ra:
            break
        k_next = kb - rb * (kb - ka) / (rb - ra)
    return tried


def self_test():
    truth, seen = 0.0123, []

    def reading(k1):
        seen.append(k1)
        return 0.27 * (truth - k1) + 0.3 * (truth - k1) ** 2

    tried = refine(reading, 0.0, 0.01, 6, 1e-6)
    assert abs(tried[-1][0] - truth) < 1e-4, tried
    assert len(seen) <= 6, seen
    assert refine(lambda k: 0.0, 0.005, 0.01, 4, 1e-4) == [(0.005, 0.0)]
    print("lens_refine self-test: ok")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("seq", nargs="?", help="a KITTI-layout sequence that turns")
    ap.add_argument("--out", help="the refined camera file")
    ap.add_argument("--camera", help="the starting lens (ORB-SLAM3 YAML); default: SEQ/calib.txt, k1 0")
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("--step", type=float, default=0.01, help="the first change of k1")
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--tol", type=float, default=0.0002, help="stop when the reading is within this")
    ap.add_argument("--self-test", action="store_true")
    # what follows `--` goes to every `supermvo run`
    args, extra = ap.parse_known_args()
    args.extra = [a for a in extra if a != "--"]
    if args.self_test:
        return self_test()
    if not args.seq or not args.out:
        ap.error("give SEQ and --out (or --self-test)")
    if not os.access(args.bin, os.X_OK):
        sys.exit(f"lens_refine: {args.bin} not found; run `cargo build --release --workspace --bins` first")
    lens, size = read_lens(args.seq, args.camera), image_size(args.seq)

    with tempfile.TemporaryDirectory() as tmp:
        def reading(k1):
            cam, out = os.path.join(tmp, f"lens_{k1:+.6f}.yaml"), os.path.join(tmp, f"run_{k1:+.6f}")
            write_lens(cam, dict(lens, k1=k1), size)
            # the reading beyond this camera file's lens, not beyond a lens learnt on the way
            cmd = [args.bin, "run", args.seq, "--mode", "inprocess", "--quiet", "--lens-check",
                   "--no-lens-self-calibration", "--camera", cam, "--out", out] + args.extra
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                sys.exit(f"lens_refine: `{' '.join(cmd)}` failed:\n{r.stderr[-2000:]}")
            with open(os.path.join(out, "report.json")) as f:
                rep = json.load(f)
            lr = rep.get("lens_residual")
            if not lr:
                sys.exit("lens_refine: no local BA read the lens (too few keyframes?)")
            ape = ((rep.get("eval") or {}).get("ape") or {}).get("trans", {}).get("rmse")
            print(f"k1 {k1:+.5f}: reading {lr['k1']:+.5f} over {lr['windows']} windows"
                  + (f", APE {ape:.3f} m" if ape is not None else ""), flush=True)
            return lr["k1"]

        tried = refine(reading, lens["k1"], args.step, args.iterations, args.tol)
    k1 = tried[-1][0]
    write_lens(args.out, dict(lens, k1=k1), size)
    print(f"refined k1 {k1:+.5f} (reading {tried[-1][1]:+.5f}); written to {args.out}")


if __name__ == "__main__":
    main()
