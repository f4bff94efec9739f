#!/usr/bin/env python3
"""The lossless daemon against the in-process run, in one script (issue 22).

Runs `supermvo run SEQ --mode inprocess` and the lossless multi-process daemon with ONNX
Runtime's intra-op threads split between the stages in several ways (the configuration's
`features_threads` / `matching_threads`; by default the daemon gives each network half of
`pipeline.threads`, as the two run at the same time), alternating, ROUNDS times each, and prints per
setting the median time per frame and its ratio to the in-process run (the peer, measured in
the same minutes: the machine is shared and noisy).

Time per frame: in process, the median of the per-frame times (`report.json`); in the
daemon, the median time between successive tracking results (`metrics.frame_interval_ms`),
so that neither counts start-up and model loading. The daemon with the in-process run's
threads must give its trajectory byte for byte (lossless hand-off): the script checks it and
says for the other splits whether they do (the thread count may change the networks' last
bits).

    python3 tools/bench_lossless.py [--seq DIR] [--rounds 3] [--frames 80] [--loop-closure]
                                    [--settings 2] [-- RUN ARGS]

Arguments after `--` go to every run (for example `--keyframe-matching`). Loop closure is off
unless `--loop-closure` (then the lossless daemon's tracker waits for the back end's verdict
on every keyframe, and the mean time per frame, which counts those waits, is printed too);
`--settings N` runs only the first N settings.
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
BIN = os.path.join(ROOT, "target", "release", "supermvo")

# (label, mode, features_threads, matching_threads); 0 = automatic: pipeline.threads (2)
# in process, half of them per network in the daemon
SETTINGS = [
    ("in process (2 threads per network)", "inprocess", 0, 0),
    ("daemon, default (1 thread per network)", "multiprocess", 0, 0),
    ("daemon, 2 threads per network", "multiprocess", 2, 2),
    ("daemon, extraction 1 thread, matching 2", "multiprocess", 1, 2),
]


def config_with(features, matching, path):
    with open(os.path.join(ROOT, "config", "default.toml")) as f:
        text = f.read()
    for key, value in (("features_threads", features), ("matching_threads", matching)):
        line = f"{key} = 0"
        if line not in text:
            sys.exit(f"bench_lossless: config/default.toml has no '{line}' line")
        text = text.replace(line, f"{key} = {value}")
    with open(path, "w") as f:
        f.write(text)


def run(seq, mode, cfg, out, frames, extra):
    cmd = [BIN, "run", seq, "--mode", mode, "--quiet", "--config", cfg, "--out", out,
           "--max-frames", str(frames), "--name", f"lossless{os.getpid()}"]
    r = subprocess.run(cmd + extra, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"bench_lossless: `{' '.join(cmd + extra)}` failed:\n{r.stderr[-2000:]}")
    with open(os.path.join(out, "report.json")) as f:
        rep = json.load(f)
    with open(os.path.join(out, "trajectory.tum.txt")) as f:
        traj = f.read()
    if mode == "inprocess":
        ms = rep["timing_ms"]["frame_median"]
        mean = statistics.mean(rep["timing_ms"]["per_frame"])
        cpu = None
    else:
        ms = rep["metrics"]["frame_interval_ms"]["p50"]
        mean = rep["metrics"]["frame_interval_ms"]["mean"]
        cpu = {k: v["p50"] for k, v in rep["metrics"]["stage_cpu_ms"].items()}
    return ms, mean, cpu, traj


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seq", default=SEQ)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=80)
    ap.add_argument("--loop-closure", action="store_true")
    ap.add_argument("--settings", type=int, default=len(SETTINGS))
    ap.add_argument("extra", nargs="*", help="arguments for every run (after --)")
    args = ap.parse_args()
    settings = SETTINGS[:max(2, args.settings)]
    if not args.loop_closure:
        args.extra = ["--no-loop-closure"] + args.extra
    results = {label: [] for label, *_ in settings}
    means = {label: [] for label, *_ in settings}
    cpu = {label: [] for label, *_ in settings}
    reference = None
    same = {label: True for label, *_ in settings}
    with tempfile.TemporaryDirectory(prefix="bench_lossless_") as tmp:
        for rnd in range(args.rounds):
            for k, (label, mode, ft, mt) in enumerate(settings):
                cfg = os.path.join(tmp, f"{k}.toml")
                config_with(ft, mt, cfg)
                ms, mean, c, traj = run(args.seq, mode, cfg, os.path.join(tmp, f"r{rnd}_{k}"),
                                  args.frames, args.extra)
                if reference is None:
                    reference = traj
                same[label] &= traj == reference
                if k == 1 and traj != reference:
                    sys.exit(f"bench_lossless: '{label}' gave another trajectory than in process")
                results[label].append(ms)
                if mean is not None:
                    means[label].append(mean)
                if c:
                    cpu[label].append(c)
                print(f"round {rnd + 1} {label}: {ms:.1f} ms/frame", flush=True)
    peer = statistics.median(results[SETTINGS[0][0]])
    print(f"\n{os.path.basename(os.path.normpath(args.seq))}, {args.frames} frames, "
          f"{args.rounds} rounds, {os.cpu_count()} CPUs, extra args: {' '.join(args.extra) or '-'}")
    print("| setting | ms per frame (median) | / in process | runs | mean ms per frame (median of runs) | stage CPU p50 (core-ms: features, matching, tracking) | trajectory of the in-process run |")
    print("|---|---|---|---|---|---|---|")
    for label, *_ in settings:
        med = statistics.median(results[label])
        runs = ", ".join(f"{v:.1f}" for v in results[label])
        stages = "-"
        if cpu[label]:
            stages = ", ".join(
                f"{statistics.median(c[s] for c in cpu[label]):.0f}"
                for s in ("features", "matching", "tracking"))
        mean = f"{statistics.median(means[label]):.1f}" if means[label] else "-"
        print(f"| {label} | {med:.1f} | {med / peer:.2f} | {runs} | {mean} | {stages} | "
              f"{'byte for byte' if same[label] else 'no'} |")


if __name__ == "__main__":
    main()
