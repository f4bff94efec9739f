#!/usr/bin/env python3
"""Writes the demo's report (markdown) from the run folders `supermvo run` left behind.

usage: demo_report.py DEMO_DIR   (reads DEMO_DIR/urban-loop, DEMO_DIR/urban-loop-odometry,
                                  DEMO_DIR/synth; writes DEMO_DIR/report.md)
Standard library only.
"""
import json
import os
import platform
import sys


def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def ape(report):
    return report["eval"]["ape"]["trans"]["rmse"]


def main():
    demo = sys.argv[1]
    run = load(os.path.join(demo, "urban-loop", "report.json"))
    odo = load(os.path.join(demo, "urban-loop-odometry", "report.json"))
    synth = load(os.path.join(demo, "synth", "sequences", "urban-loop", "synth.json"))
    if run is None:
        sys.exit(f"demo_report: {demo}/urban-loop/report.json not found: run tools/demo.sh")
    m = run.get("metrics", {})
    path = run["eval"]["reference_length_m"]
    lines = ["# SuPerMVO demo report", ""]
    if synth:
        lines += [
            f"Sequence: synthetic `{synth['preset']}` (seed {synth['seed']}), {synth['frames']} frames "
            f"{synth['width']}x{synth['height']} at 10 Hz, rendered by `supermvo synth`; the camera drives "
            f"a city block 1.15 times, {path:.0f} m.",
            "",
        ]
    lines += [
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, {platform.system()} {platform.release()}.",
        f"Pipeline: the multi-process daemon (ingest, features, matching, tracking, back end under the "
        f"supervisor, over iceoryx2 shared memory), mode `{m.get('mode', '?')}`.",
        "",
        "## Accuracy (APE after Sim(3) alignment, KITTI metric)",
        "",
        "| run | frames estimated | loops closed | APE RMSE (m) | APE / path | KITTI t_err (%) | r_err (deg/100 m) |",
        "|---|---|---|---|---|---|---|",
    ]

    def row(name, r):
        k = r["eval"]["kitti"]
        loops = len(r.get("loops") or [])
        return (
            f"| {name} | {r['estimated']} / {r['frames']} | {loops} | {ape(r):.3f} | "
            f"{100 * ape(r) / path:.2f} % | {k['t_err_pct']:.2f} | {k['r_err_deg_per_100m']:.2f} |"
        )

    lines.append(row("with loop closure (daemon)", run))
    if odo:
        lines.append(row("odometry only (in process)", odo))
    lines += ["", "## Speed and latency (daemon)", ""]
    lines += [
        f"{sum(m.get('frames', {}).values())} frames in {m.get('duration_s', 0):.1f} s, "
        f"{m.get('fps', 0):.2f} frames/s; restarts: {len(m.get('restarts', []))}.",
        "",
        "| stage | p50 (ms) | p95 (ms) | p99 (ms) | peak RSS (MiB) |",
        "|---|---|---|---|---|",
    ]
    rss = m.get("peak_rss_kb", {})
    for stage, s in m.get("stage_latency_ms", {}).items():
        peak = max((v for k, v in rss.items() if k.startswith(stage + "/")), default=0)
        lines.append(f"| {stage} | {s['p50']:.1f} | {s['p95']:.1f} | {s['p99']:.1f} | {peak / 1024:.0f} |")
    e2e = m.get("end_to_end_ms")
    if e2e:
        lines.append(f"| capture to pose | {e2e['p50']:.0f} | {e2e['p95']:.0f} | {e2e['p99']:.0f} | |")
    if m.get("mode") == "lossless":
        lines += [
            "",
            "Lossless mode feeds every frame as fast as the pipeline takes it, so capture-to-pose "
            "includes the wait in the bounded queues; `DEMO_REALTIME=1 tools/demo.sh` replays at "
            "10 Hz and drops (and reports) what the machine cannot keep up with.",
        ]
    lines += ["", "## Loops", ""]
    for l in run.get("loops") or []:
        lines.append(
            f"- frame {l['query_frame']} recognised frame {l['match_frame']}: {l['inliers']} inliers, "
            f"scale ratio {l['scale']:.3f}"
        )
    lines += ["", "## Figures", ""]
    for fig, title in [
        ("trajectory_xz.png", "Trajectory, top view"),
        ("xyz.png", "Position over time"),
        ("rpy.png", "Orientation over time"),
        ("ape_supermvo.png", "APE over time"),
    ]:
        if os.path.exists(os.path.join(demo, "urban-loop", fig)):
            lines.append(f"![{title}](urban-loop/{fig})")
            lines.append("")
    if odo and os.path.exists(os.path.join(demo, "urban-loop-odometry", "trajectory_xz.png")):
        lines.append("![Odometry only, top view](urban-loop-odometry/trajectory_xz.png)")
        lines.append("")
    out = os.path.join(demo, "report.md")
    with open(out, "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines[: lines.index("## Loops")]))
    print(f"report: {out}")


if __name__ == "__main__":
    main()
