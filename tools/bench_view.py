#!/usr/bin/env python3
"""Does a live view slow the daemon? Lossless daemon runs of one clip, alternately alone and
with `supermvo view` attached and a Foxglove WebSocket client (tools/ws_view_client.py)
subscribed to every channel (images included); prints the daemon's frames/s of each run
(from its metrics.json), the medians and their ratio. Same machine, same minutes, runs
interleaved so that drift in the machine's load hits both.

    PYTHONPATH=$(cache)/python-tools python3 tools/bench_view.py [--seq DIR] [--rounds 3]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "supermvo")


def run_daemon(seq, out, name):
    subprocess.run([BIN, "run", seq, "--out", out, "--name", name, "-q"], check=True,
                   stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "metrics.json")) as f:
        return json.load(f)["fps"]


def run_viewed(seq, out, name):
    view = subprocess.Popen([BIN, "view", "--name", name, "--port", "0", "--wait", "120"],
                            stdout=subprocess.PIPE, text=True)
    daemon = subprocess.Popen([BIN, "run", seq, "--out", out, "--name", name, "-q"],
                              stdout=subprocess.DEVNULL)
    url = next(w for w in view.stdout.readline().split() if w.startswith("ws://"))
    client = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "ws_view_client.py"), url],
                            capture_output=True, text=True, check=True)
    if daemon.wait() != 0 or view.wait() != 0:
        sys.exit("bench_view: a run failed")
    got = json.loads(client.stdout)
    received = sum(c["messages"] for c in got["channels"].values())
    with open(os.path.join(out, "metrics.json")) as f:
        return json.load(f)["fps"], received, len(got["poses"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seq", default=os.path.join(ROOT, "..", "shared", "data", "kitti", "sequences", "07"))
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    alone, viewed = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            name = f"benchview-{os.getpid()}-{r}"
            fps = run_daemon(args.seq, os.path.join(tmp, f"alone{r}"), name + "a")
            alone.append(fps)
            fps_v, messages, poses = run_viewed(args.seq, os.path.join(tmp, f"viewed{r}"), name + "v")
            viewed.append(fps_v)
            print(f"round {r}: alone {fps:.2f} frames/s, with the view {fps_v:.2f} frames/s "
                  f"(client received {messages} messages, {poses} poses)", flush=True)
            time.sleep(1)
    a, v = statistics.median(alone), statistics.median(viewed)
    print(f"median frames/s: alone {a:.2f}, with the view {v:.2f}; ratio {v / a:.3f}")


if __name__ == "__main__":
    main()
