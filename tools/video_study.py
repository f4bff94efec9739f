#!/usr/bin/env python3
"""A KITTI clip as H.264 video against its PNG frames, over many RANSAC seeds.

Issue 23: a video encoded from a KITTI clip should give a trajectory within 10 % of the PNG
run's APE. The seed alone moves a clip's APE by up to 30 %, so this compares medians over
many seeds. Per clip it encodes `image_0/` with Debian's ffmpeg (libx264, `--crf`, yuv420p; an odd
side is made even by dropping the last column or row with `--even crop`, the default, or by
adding a black one with `--even pad`; either leaves the intrinsics unchanged),
writes the camera file from `calib.txt`, runs `supermvo run` in process on the PNG clip and
on the video with every seed (ground truth from `poses/`), and prints the median APE of each
and their ratio. `--json-png` / `--json-video` write the runs in `clip_study.py`'s format, so
`tools/clip_compare.py PNG.json VIDEO.json` adds the per-clip z-score.

    python3 tools/video_study.py [--clips 00,03,07] [--seeds 0-8] [--crf 18] [--even crop] [--jobs 2]
"""
import argparse
import concurrent.futures
import json
import os
import statistics
import subprocess
import tempfile

import clip_study

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def seeds_of(text):
    if "-" in text:
        lo, hi = text.split("-")
        return list(range(int(lo), int(hi) + 1))
    return [int(s) for s in text.split(",")]


EVEN = {
    "crop": "crop=trunc(iw/2)*2:trunc(ih/2)*2:0:0",
    "pad": "pad=ceil(iw/2)*2:ceil(ih/2)*2",
}


def encode(clip, crf, work, even="crop"):
    """`work/CLIP.mp4` and `work/CLIP.yaml` (the video's camera file, found by its name)."""
    seq = os.path.join(clip_study.KITTI, "sequences", clip)
    video = os.path.join(work, f"{clip}.mp4")
    subprocess.run(["ffmpeg", "-loglevel", "error", "-y", "-framerate", "10", "-i",
                    os.path.join(seq, "image_0", "%06d.png"), "-c:v", "libx264", "-crf", str(crf),
                    "-pix_fmt", "yuv420p", "-vf", EVEN[even], video], check=True)
    with open(os.path.join(seq, "calib.txt")) as f:
        p0 = next(line for line in f if line.startswith("P0:")).split()[1:]
    fx, cx, fy, cy = p0[0], p0[2], p0[5], p0[6]
    with open(os.path.join(work, f"{clip}.yaml"), "w") as f:
        f.write(f'%YAML:1.0\nCamera.type: "PinHole"\nCamera.fx: {fx}\nCamera.fy: {fy}\n'
                f"Camera.cx: {cx}\nCamera.cy: {cy}\n")
    return video


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("--clips", default="00,03,07")
    ap.add_argument("--seeds", default="0-8", help="a range (0-8) or a list (0,1,2)")
    ap.add_argument("--crf", type=int, default=18)
    ap.add_argument("--even", choices=sorted(EVEN), default="crop",
                    help="how an odd side becomes even for yuv420p: drop the last column or row, or pad")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--json-png")
    ap.add_argument("--json-video")
    args = ap.parse_args()
    seeds = seeds_of(args.seeds)
    rows = {"png": [], "video": []}
    with tempfile.TemporaryDirectory(prefix="video_study_") as work:
        jobs = []
        for clip in args.clips.split(","):
            video = encode(clip, args.crf, work, args.even)
            gt = os.path.join(clip_study.KITTI, "poses", f"{clip}.txt")
            png = os.path.join(clip_study.KITTI, "sequences", clip)
            for kind, src in (("png", png), ("video", video)):
                for seed in seeds:
                    out = os.path.join(work, f"{clip}-{kind}-{seed}")
                    jobs.append((clip, kind, seed, src, out, ["--gt", gt, "--seed", str(seed)]))
        with concurrent.futures.ThreadPoolExecutor(max_workers=args.jobs) as pool:
            done = list(pool.map(lambda j: (j, clip_study.run_one(args.bin, j[3], j[4], j[5])), jobs))
    print(f"{'clip':6} {'PNG median':>11} {'video median':>13} {'video / PNG':>12}  per seed PNG | video")
    for clip in args.clips.split(","):
        per = {}
        for kind in ("png", "video"):
            runs = [dict(r, seed=j[2], clip=clip, stride=1) for j, r in done if j[0] == clip and j[1] == kind]
            per[kind] = runs
            rows[kind].append(dict(runs[0], seeds=runs))
        mp = statistics.median(r["ape"] for r in per["png"])
        mv = statistics.median(r["ape"] for r in per["video"])
        apes = {kind: " ".join("%.3f" % r["ape"] for r in runs) for kind, runs in per.items()}
        print(f"{clip:6} {mp:11.3f} {mv:13.3f} {mv / mp:11.2f}x  {apes['png']} | {apes['video']}")
    for kind, path in (("png", args.json_png), ("video", args.json_video)):
        if path:
            with open(path, "w") as f:
                json.dump({"rows": rows[kind]}, f, indent=1)


if __name__ == "__main__":
    main()
