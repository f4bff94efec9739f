#!/usr/bin/env python3
"""Is a tracker change better than the seeds' own spread? Two sets of `clip_study.py` runs.

`tools/clip_study.py --json F` keeps every seed's run of every sequence. This pools the
seeds of one or more such files per side (for example seeds 0-2, 3-5 and 6-8 run as three
files), and prints per sequence: the median APE of each side, their ratio, and a z-score of
the difference of the mean log APE (Welch: the difference over its standard error from the
two sides' spreads over seeds; negative is better), with the fewest frames posed and the
median landmarks tracked. The last line sums it up: the geometric mean of the median
ratios, the runs better and worse by more than 3 %, and the z-scores summed over the
sequences divided by the square root of their number (about normal with spread 1 when the
change does nothing).

Why: on these clips the RANSAC seed alone moves a run's APE by up to 30 %, so a median of
three seeds cannot tell a 10 % change from chance (the same build, seeds 0-2 against 3-5:
7 runs better and 10 worse, up to 1.28x; docs/decisions/2026-12-05-keyframe-on-every-frame.md).

    python3 tools/clip_compare.py BASE.json[,BASE2.json...] CANDIDATE.json[,...]
"""
import argparse
import json
import math
import statistics


def load(paths):
    """{"clip/stride": {seed: run}} pooled over the files."""
    runs = {}
    for path in paths.split(","):
        with open(path) as f:
            for row in json.load(f)["rows"]:
                for run in row.get("seeds", [row]):
                    runs.setdefault(f"{row['clip']}/{row['stride']}", {})[run["seed"]] = run
    return runs


def log_apes(runs):
    return [math.log(r["ape"]) for r in runs.values() if r.get("ape")]


def welch_z(a, b):
    if len(a) < 2 or len(b) < 2:
        return float("nan")
    se = math.sqrt(statistics.variance(a) / len(a) + statistics.variance(b) / len(b))
    return (statistics.mean(b) - statistics.mean(a)) / se if se > 0 else 0.0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("base", help="clip_study JSON files of the baseline, comma-separated")
    ap.add_argument("candidate", help="clip_study JSON files of the change, comma-separated")
    args = ap.parse_args()
    base, cand = load(args.base), load(args.candidate)
    print(f"{'run':12} {'seeds':>5} {'base APE':>9} {'change':>8} {'ratio':>6} {'z':>6} {'posed (min)':>12} {'tracked':>9}")
    ratios, zs = [], []
    for key in base:
        if key not in cand:
            continue
        a, b = base[key], cand[key]
        ma = statistics.median(r["ape"] for r in a.values())
        mb = statistics.median(r["ape"] for r in b.values())
        z = welch_z(log_apes(a), log_apes(b))
        ratios.append(mb / ma)
        if not math.isnan(z):
            zs.append(z)
        posed = f"{min(r['posed'] for r in a.values())}/{min(r['posed'] for r in b.values())}"
        tracked = "{:.0f}/{:.0f}".format(statistics.median(r["tracked_median"] for r in a.values()),
                                         statistics.median(r["tracked_median"] for r in b.values()))
        print(f"{key:12} {len(a):>2}/{len(b):<2} {ma:9.3f} {mb:8.3f} {mb / ma:6.2f} {z:6.1f} {posed:>12} {tracked:>9}")
    if not ratios:
        raise SystemExit("no sequence in both sets")
    geo = math.exp(statistics.mean(math.log(r) for r in ratios))
    summed = sum(zs) / math.sqrt(len(zs)) if zs else float("nan")
    print(f"geometric mean of the median ratios {geo:.3f}; better / worse by more than 3 %: "
          f"{sum(r < 0.97 for r in ratios)} / {sum(r > 1.03 for r in ratios)} of {len(ratios)}; "
          f"summed z {summed:.2f}")


if __name__ == "__main__":
    main()
