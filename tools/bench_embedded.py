#!/usr/bin/env python3
"""What an embedded board would see: one clip run in process and as the daemon, on two cores
and pinned to one (`taskset -c 0`, ONNX Runtime with one thread per network), with frames/s,
APE and peak memory. Frames/s: the daemon's own (metrics.json); in process, 1000 / the
median time per frame. Peak RSS: per stage process from the daemon's metrics.json, and the
in-process run's from its report.json (`peak_rss_kb`, the process's own getrusage).

    python3 tools/bench_embedded.py [--seq DIR]
"""
import argparse
import json
import os
import subprocess
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "supermvo")


def run(seq, out, mode, cores, config):
    cmd = [BIN, "run", seq, "--out", out, "-q", "--mode", mode, "--config", config,
           "--name", f"embedded-{os.getpid()}"]
    if cores == 1:
        cmd = ["taskset", "-c", "0"] + cmd
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "report.json")) as f:
        report = json.load(f)
    ape = report.get("eval", {}).get("ape", {}).get("full", {}).get("rmse")
    if mode == "inprocess":
        fps = 1000.0 / report["timing_ms"]["frame_median"]
        rss = {"supermvo (one process)": report["peak_rss_kb"]}
    else:
        with open(os.path.join(out, "metrics.json")) as f:
            m = json.load(f)
        fps, rss = m["fps"], m["peak_rss_kb"]
    return fps, ape, rss


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seq", default=os.path.join(ROOT, "..", "shared", "data", "kitti", "sequences", "07"))
    args = ap.parse_args()
    print("| cores | mode | threads per network | frames/s | APE (m) | peak RSS (MB) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for cores, threads in [(2, 2), (1, 1)]:
            config = os.path.join(tmp, f"threads{threads}.toml")
            with open(config, "w") as f:
                f.write(f"[pipeline]\nthreads = {threads}\n")
            for mode in ["inprocess", "multiprocess"]:
                out = os.path.join(tmp, f"{mode}-{cores}")
                fps, ape, rss = run(args.seq, out, mode, cores, config)
                parts = ", ".join(f"{k} {v / 1024:.0f}" for k, v in rss.items() if v)
                total = sum(v for v in rss.values() if v) / 1024
                ape_s = f"{ape:.3f}" if ape is not None else "-"
                print(f"| {cores} | {mode} | {threads} | {fps:.2f} | {ape_s} | {total:.0f} ({parts}) |",
                      flush=True)


if __name__ == "__main__":
    main()
