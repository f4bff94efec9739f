#!/usr/bin/env python3
"""Real time at the sequence's own frame rate (10 Hz for KITTI): the daemon with a profile,
three runs per sequence, against the lossless run of the same configuration.

For every KITTI clip of ../shared and the synthetic `urban-loop` (rendered once into
--synth if missing), it runs

  * the lossless reference: `supermvo run SEQ --profile P --mode inprocess` (the lossless
    daemon gives the same trajectory bit for bit; tests check it), and the default
    configuration the same way, for what the profile costs in accuracy;
  * `--runs` times `supermvo run SEQ --profile P` (the daemon, in real time),

and reads from each real-time run's metrics.json and report.json: frames dropped at ingest,
capture-to-pose p50 and p99, frames posed and the APE after Sim(3). Prints one markdown table
(min / median / max over the runs) and writes the rows to --json. The real-time runs must be
alone on the machine: they measure what the cores allow.

    python3 tools/bench_realtime.py [--profile realtime] [--runs 3] [--clips 00,07]
                                    [--json out.json] [--synth /tmp/synth] [--speed 2]

`--profile FILE.toml` measures a configuration file as the profile (a candidate change).

`--speed 2` replays twice as fast as the sequence's own rate (KITTI at 20 Hz): the profile's
file with `pipeline.speed` set, given as `--config` (the lossless runs do not change).
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import clip_study  # noqa: E402  (the clips, with 00_long's linked frames resolved)


def run(cmd):
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"bench_realtime: `{' '.join(cmd)}` failed ({r.returncode}):\n{r.stderr[-2000:]}")


def ape(out):
    with open(os.path.join(out, "report.json")) as f:
        rep = json.load(f)
    ev = rep.get("eval") or {}
    return rep, ev.get("ape", {}).get("trans", {}).get("rmse")


def realtime_run(binary, seq, out, profile):
    """`profile` is the arguments that choose the configuration (`--profile P` or
    `--config FILE`)."""
    run([binary, "run", seq] + profile + ["--quiet", "--out", out])
    rep, a = ape(out)
    with open(os.path.join(out, "metrics.json")) as f:
        m = json.load(f)
    frames = sum(m["frames"].values())
    dropped = m["frames"].get("dropped", 0)
    return {
        "frames": frames,
        "dropped_pct": 100.0 * dropped / max(frames, 1),
        "posed": rep["estimated"],
        "p50": m["end_to_end_ms"]["p50"],
        "p99": m["end_to_end_ms"]["p99"],
        "ape": a,
    }


def spread(values, fmt):
    v = sorted(values)
    return " / ".join(fmt.format(x) for x in (v[0], statistics.median(v), v[-1]))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("--profile", default="realtime",
                    help="a profile's name, or a configuration file (FILE.toml) to measure as one")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--clips", default=",".join(clip_study.CLIPS))
    ap.add_argument("--synth", default=os.path.join(tempfile.gettempdir(), "supermvo-bench-synth"))
    ap.add_argument("--json")
    ap.add_argument("--speed", type=float, default=1.0, help="replay speed factor (2: KITTI at 20 Hz)")
    args = ap.parse_args()

    work = tempfile.mkdtemp(prefix="bench_realtime_")
    is_file = args.profile.endswith(".toml")
    profile_file = args.profile if is_file else os.path.join(ROOT, "config", f"{args.profile}.toml")
    chosen = ["--config", profile_file] if is_file else ["--profile", args.profile]
    realtime = chosen
    if args.speed != 1.0:
        with open(profile_file) as f:
            text = f.read()
        if "[pipeline]" not in text or "speed" in text:
            sys.exit(f"bench_realtime: {profile_file}: expected a [pipeline] table without `speed`")
        fast = os.path.join(work, f"{os.path.basename(profile_file)[:-5]}_speed.toml")
        with open(fast, "w") as f:
            f.write(text.replace("[pipeline]", f"[pipeline]\nspeed = {args.speed}", 1))
        realtime = ["--config", fast]
    seqs = [(c, clip_study.subsample(c, 1, work)) for c in args.clips.split(",") if c]
    urban = os.path.join(args.synth, "sequences", "urban-loop")
    if not os.path.isdir(urban):
        run([args.bin, "synth", "--preset", "urban-loop", "--out", args.synth])
    seqs.append(("urban-loop", urban))

    rows = []
    for name, seq in seqs:
        lossless_out = os.path.join(work, name, "lossless")
        run([args.bin, "run", seq] + chosen + ["--mode", "inprocess", "--quiet", "--out", lossless_out])
        _, lossless = ape(lossless_out)
        default_out = os.path.join(work, name, "default")
        run([args.bin, "run", seq, "--mode", "inprocess", "--quiet", "--out", default_out])
        _, default = ape(default_out)
        runs = [realtime_run(args.bin, seq, os.path.join(work, name, f"rt{i}"), realtime)
                for i in range(args.runs)]
        row = {"sequence": name, "lossless_ape": lossless, "default_ape": default, "runs": runs}
        rows.append(row)
        print(f"{name}: lossless {lossless:.3f} m (default {default:.3f}); real time "
              + "; ".join(f"dropped {r['dropped_pct']:.1f} % p50 {r['p50']:.0f} p99 {r['p99']:.0f} ms "
                          f"APE {r['ape']:.3f}" for r in runs), flush=True)

    print()
    print(f"| sequence | frames | dropped % | capture->pose p50 (ms) | p99 (ms) | posed | APE real time (m) "
          f"| APE lossless, same profile | median / lossless | APE default, lossless |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        r = row["runs"]
        med = statistics.median(x["ape"] for x in r)
        print(f"| {row['sequence']} | {r[0]['frames']} | {spread([x['dropped_pct'] for x in r], '{:.1f}')} "
              f"| {spread([x['p50'] for x in r], '{:.0f}')} | {spread([x['p99'] for x in r], '{:.0f}')} "
              f"| {spread([x['posed'] for x in r], '{}')} | {spread([x['ape'] for x in r], '{:.3f}')} "
              f"| {row['lossless_ape']:.3f} | {med / row['lossless_ape']:.2f}x | {row['default_ape']:.3f} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"profile": args.profile, "speed": args.speed, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
