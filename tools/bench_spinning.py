#!/usr/bin/env python3
"""ONNX Runtime thread spinning on and off, measured on the whole pipeline in one script.

XFeat and LighterGlue run one after the other on the same cores. With spinning on (ONNX
Runtime's default) a session's threads busy-wait after each call, taking the cores the
next network needs. This runs `supermvo run SEQ --mode inprocess` (and, with --daemon,
the lossless multi-process daemon) with `pipeline.thread_spinning` off and on, alternating,
ROUNDS times each, and prints the median time per frame of each setting and their ratio
(the peer is the other setting in the same script: the machine is shared and noisy). It
also checks that both settings give the same trajectory: spinning changes speed, not
results.

    python3 tools/bench_spinning.py [--seq DIR] [--rounds 3] [--frames 60] [--daemon]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEQ = os.path.normpath(os.path.join(ROOT, "..", "shared", "data", "kitti", "sequences", "07"))


def config_with(spin, path):
    with open(os.path.join(ROOT, "config", "default.toml")) as f:
        text = f.read()
    key = "thread_spinning = false"
    if key not in text:
        sys.exit(f"bench_spinning: config/default.toml has no '{key}' line")
    with open(path, "w") as f:
        f.write(text.replace(key, f"thread_spinning = {'true' if spin else 'false'}"))


def run(binary, seq, cfg, out, frames, mode):
    cmd = [binary, "run", seq, "--mode", mode, "--quiet", "--config", cfg, "--out", out,
           "--max-frames", str(frames), "--no-loop-closure", "--name", f"spin{os.getpid()}"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"bench_spinning: `{' '.join(cmd)}` failed:\n{r.stderr[-2000:]}")
    with open(os.path.join(out, "report.json")) as f:
        rep = json.load(f)
    with open(os.path.join(out, "trajectory.tum.txt")) as f:
        traj = f.read()
    if mode == "inprocess":
        ms = rep["timing_ms"]["frame_median"]
    else:  # the daemon: wall time per frame of the whole run
        ms = 1000.0 / rep["metrics"]["fps"]
    return ms, traj


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("--seq", default=SEQ)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--daemon", action="store_true", help="also the lossless multi-process daemon")
    args = ap.parse_args()
    if not os.path.isdir(args.seq):
        sys.exit(f"bench_spinning: {args.seq} not found")
    modes = ["inprocess"] + (["multiprocess"] if args.daemon else [])
    with tempfile.TemporaryDirectory() as tmp:
        cfgs = {}
        for spin in (False, True):
            cfgs[spin] = os.path.join(tmp, f"spin_{spin}.toml")
            config_with(spin, cfgs[spin])
        print(f"{os.path.basename(args.seq)}, first {args.frames} frames, {args.rounds} rounds, "
              f"{os.cpu_count()} CPUs; ms per frame (in process: median per frame; daemon: wall / frames)")
        for mode in modes:
            times = {False: [], True: []}
            trajs = {}
            for k in range(args.rounds):
                for spin in (False, True):
                    ms, traj = run(args.bin, args.seq, cfgs[spin], os.path.join(tmp, f"{mode}{spin}{k}"),
                                   args.frames, mode)
                    times[spin].append(ms)
                    trajs.setdefault(spin, traj)
            off, on = statistics.median(times[False]), statistics.median(times[True])
            same = "identical" if trajs[False] == trajs[True] else "DIFFERENT"
            print(f"{mode:<13} spinning off {off:7.1f} ms  on {on:7.1f} ms  on/off {on / off:5.2f}  "
                  f"(runs off {', '.join(f'{t:.1f}' for t in times[False])}; "
                  f"on {', '.join(f'{t:.1f}' for t in times[True])}); trajectories {same}", flush=True)


if __name__ == "__main__":
    main()
