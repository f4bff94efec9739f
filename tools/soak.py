#!/usr/bin/env python3
"""Soak test of the multi-process daemon: replays a KITTI-layout sequence in real time (its own
frame rate, 10 Hz for KITTI), looping it for the given duration, then checks

  * every frame is accounted for: each sequence number recorded exactly once by the back end,
    as processed or as a reported drop (no unreported drop);
  * the resident memory of every process is flat after warm-up: the median over the last
    minute is within 5 % of the median over the minute after warm-up;

and reports latency percentiles per stage and end to end. Writes soak_report.json and
soak_report.md to the output directory; exits 1 when a check fails.

    tools/soak.py ../shared/data/kitti/sequences/03 --minutes 10 --out out/soak
"""
import argparse
import json
import math
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("seq", type=Path)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--warmup-s", type=float, default=60.0)
    ap.add_argument("--window-s", type=float, default=60.0)
    ap.add_argument("--out", type=Path, default=ROOT / "out/soak")
    ap.add_argument("--bin", type=Path, default=ROOT / "target/release/supermvo")
    ap.add_argument("--config", type=Path)
    args = ap.parse_args()

    times = [float(t) for t in (args.seq / "times.txt").read_text().split()]
    period = (times[-1] - times[0]) * len(times) / max(len(times) - 1, 1)
    loops = max(1, math.ceil(args.minutes * 60.0 / period))
    cmd = [str(args.bin), "run", str(args.seq), "--realtime", "--loops", str(loops),
           "--name", "soak", "--out", str(args.out), "-q"]
    if args.config:
        cmd += ["--config", str(args.config)]
    print("running:", " ".join(cmd), flush=True)
    r = subprocess.run(cmd)
    if r.returncode != 0:
        print("the run failed", file=sys.stderr)
        return 1

    m = json.loads((args.out / "metrics.json").read_text())
    lines = (args.out / "frames.csv").read_text().splitlines()[1:]
    # one row per frame: the later lines that give an earlier frame's final pose are not frames
    rows = [r for r in (l.split(",") for l in lines if l) if r[3] not in ("backfilled", "loop_corrected")]
    seqs = [int(r[0]) for r in rows]
    total = loops * len(times)
    expected = list(range(total + 1))
    statuses = {}
    for r in rows:
        if r[3] != "end":
            statuses[r[3]] = statuses.get(r[3], 0) + 1
    unreported = len(set(expected) - set(seqs))
    duplicates = len(seqs) - len(set(seqs))

    rss = {}
    ok_rss = True
    end = m["duration_s"]
    for proc, samples in sorted(m["rss_samples"].items()):
        base = [kb for t, kb in samples if args.warmup_s <= t < args.warmup_s + args.window_s]
        last = [kb for t, kb in samples if t >= end - args.window_s]
        if not base or not last:
            continue
        b, l = statistics.median(base), statistics.median(last)
        growth = 100.0 * (l - b) / b
        ok_rss &= growth < 5.0
        rss[proc] = {"after_warmup_kb": b, "last_minute_kb": l, "growth_percent": round(growth, 2)}

    # capture-to-pose latency per minute of the replay (frame seq times the frame interval)
    interval = period / len(times)
    per_minute = {}
    for r in rows:
        if r[3] == "ok" and r[7]:
            per_minute.setdefault(int(int(r[0]) * interval // 60), []).append(float(r[7]))
    minutes = []
    for minute, lat in sorted(per_minute.items()):
        lat.sort()
        q = lambda f: lat[min(len(lat) - 1, int(f * len(lat)))]
        minutes.append({"minute": minute, "frames": len(lat), "p50": q(0.5), "p95": q(0.95), "p99": q(0.99)})

    report = {
        "sequence": str(args.seq), "loops": loops, "frames": total, "duration_s": round(end, 1),
        "latency_per_minute_ms": minutes,
        "statuses": statuses, "unreported_drops": unreported, "duplicates": duplicates,
        "restarts": len(m["restarts"]), "rss": rss,
        "end_to_end_ms": m["end_to_end_ms"], "stage_latency_ms": m["stage_latency_ms"],
    }
    (args.out / "soak_report.json").write_text(json.dumps(report, indent=1))
    md = [f"Soak: {args.seq.name} looped {loops}x in real time, {end / 60:.1f} min, {total} frames",
          f"frames: {statuses}; unreported drops {unreported}; duplicates {duplicates}; restarts {len(m['restarts'])}",
          "", "| process | RSS after warm-up (kB) | RSS last minute (kB) | growth |", "|---|---|---|---|"]
    md += [f"| {p} | {v['after_warmup_kb']:.0f} | {v['last_minute_kb']:.0f} | {v['growth_percent']:+.2f} % |"
           for p, v in rss.items()]
    md += ["", "| latency (ms) | p50 | p95 | p99 | max |", "|---|---|---|---|---|"]
    lat = dict(m["stage_latency_ms"])
    lat["capture -> pose"] = m["end_to_end_ms"]
    md += [f"| {k} | {v['p50']:.1f} | {v['p95']:.1f} | {v['p99']:.1f} | {v['max']:.1f} |" for k, v in lat.items()]
    md += ["", "| minute | frames posed | capture -> pose p50 (ms) | p95 | p99 |", "|---|---|---|---|---|"]
    md += [f"| {x['minute']} | {x['frames']} | {x['p50']:.0f} | {x['p95']:.0f} | {x['p99']:.0f} |" for x in minutes]
    steady = [x["p50"] for x in minutes[1:-1]] or [x["p50"] for x in minutes]
    if steady:
        md += ["", f"p50 per minute after the first: {min(steady):.0f}-{max(steady):.0f} ms "
                   f"({max(steady) / max(min(steady), 1e-9):.2f}x from the lowest to the highest)"]
    text = "\n".join(md)
    (args.out / "soak_report.md").write_text(text + "\n")
    print(text)
    ok = unreported == 0 and duplicates == 0 and ok_rss and len(rss) > 0
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
