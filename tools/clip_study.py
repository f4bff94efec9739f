#!/usr/bin/env python3
"""Every KITTI clip at full rate and sub-sampled to every 2nd and 3rd frame: one table.

Issue 21 judges a tracker change on 18 runs, not on one clip: the six clips of
../shared/data/kitti at full rate, and each one with only every 2nd and every 3rd frame
(5 Hz and 3.3 Hz, so twice and three times the motion between frames). The sub-sampled
sequences are built in a temporary folder as symbolic links to the clip's images, with the
matching lines of times.txt and of the ground truth, so nothing is copied.

For each run it reads `report.json` and prints: frames, frames posed (and the share), APE
RMSE after Sim(3), median tracked landmarks per posed frame (the pose's inliers), the share of
posed frames that became keyframes, the KITTI
metric where the ground truth covers 100 m, and the median time per frame. Any further
arguments go to every `supermvo run` (for example `--frontend orb`), and `--bin` runs
another build. `--peer ARGS` runs every sequence a second time, right after, with those
arguments instead (for example `--peer=--keyframe-matching`, the matcher only for keyframes), and
adds the peer's posed frames, APE and time per frame and the ratio of the times: a speed
comparison on the same machine in the same minutes. `--peer-bin PATH` runs the peer with
another build (for example one of the main before a change), with `--peer` arguments or the
same ones.

    python3 tools/clip_study.py [--strides 1,2,3] [--clips 00,03] [--json out.json]
                                [--seeds 0,1,2] [--jobs 2] [--peer=ARGS] [--peer-bin PATH]
                                [-- ARGS]

`--lens-k1 K` gives every sequence a camera file (`camera.yaml` beside `calib.txt`) with the
clip's own intrinsics and the radial coefficient K, so the tracker undistorts the keypoints
with it: a lens-model study (docs/decisions/2026-12-07-kitti-lens-residual-and-turn-scale.md).
The tracker still learns a lens beyond it while driving (the default); add
`-- --no-lens-self-calibration` to study the camera file's lens alone.

`--seeds` runs every sequence with each RANSAC seed and reports the run with the median
APE; `--jobs` runs that many at once (for accuracy; timing needs one at a time). With
`SUPERMVO_NETWORK_CACHE=DIR` the in-process runs keep the networks' results in DIR, so a
tracker study that repeats the table computes features and matches only once
(shared/inference/src/cache.rs).

A full table takes about 15 minutes on a 2-core machine (learned front end).
"""
import argparse
import concurrent.futures
import json
import os
import statistics
import subprocess
import sys
import tempfile

import lens_refine

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KITTI = os.path.normpath(os.path.join(ROOT, "..", "shared", "data", "kitti"))
CLIPS = ["00", "00_long", "01", "03", "06", "07"]


def image_target(path):
    """The image file `path` stands for. In ../shared, 00_long's frames 0-159 are links to
    the 00 clip's files, but where the data was unpacked without symbolic links each is a
    small text file holding the link's relative target: follow it."""
    if os.path.getsize(path) < 256:
        with open(path, "rb") as f:
            target = f.read().decode("utf-8", "replace").strip()
        resolved = os.path.normpath(os.path.join(os.path.dirname(path), target))
        if os.path.isfile(resolved):
            return resolved
    return path


def subsample(clip, stride, root, lens_k1=None):
    """A KITTI-layout copy of `clip` with every `stride`-th frame, as links; returns its dir.
    With `lens_k1`, the copy also gets a camera file with that radial coefficient."""
    src = os.path.join(KITTI, "sequences", clip)
    images = sorted(os.listdir(os.path.join(src, "image_0")))
    targets = [image_target(os.path.join(src, "image_0", i)) for i in images]
    plain = all(t == os.path.join(src, "image_0", i) for t, i in zip(targets, images))
    if stride == 1 and plain and lens_k1 is None:
        return src
    name = f"{clip}_every{stride}"
    dst = os.path.join(root, "sequences", name)
    os.makedirs(os.path.join(dst, "image_0"), exist_ok=True)
    os.makedirs(os.path.join(root, "poses"), exist_ok=True)
    os.symlink(os.path.join(src, "calib.txt"), os.path.join(dst, "calib.txt"))
    with open(os.path.join(src, "times.txt")) as f:
        times = [line for line in f if line.strip()]
    with open(os.path.join(KITTI, "poses", f"{clip}.txt")) as f:
        poses = [line for line in f if line.strip()]
    if not (len(images) == len(times) == len(poses)):
        sys.exit(f"clip_study: {clip}: {len(images)} images, {len(times)} times, {len(poses)} poses")
    kept = range(0, len(images), stride)
    for j, i in enumerate(kept):
        ext = os.path.splitext(images[i])[1]
        os.symlink(targets[i], os.path.join(dst, "image_0", f"{j:06d}{ext}"))
    with open(os.path.join(dst, "times.txt"), "w") as f:
        f.writelines(times[i] for i in kept)
    with open(os.path.join(root, "poses", f"{name}.txt"), "w") as f:
        f.writelines(poses[i] for i in kept)
    if lens_k1 is not None:
        write_camera_file(dst, targets[0], lens_k1)
    return dst


def write_camera_file(seq, image, k1):
    """`camera.yaml` in `seq`: the intrinsics of its calib.txt (P0) and radial coefficient
    `k1` (ORB-SLAM3's layout, which `supermvo run` reads beside calib.txt)."""
    size = lens_refine.png_size(image)
    if size is None:
        sys.exit(f"clip_study: {image} is not a PNG; --lens-k1 reads the image size from it")
    lens = dict(lens_refine.read_lens(seq, None), k1=k1)
    lens_refine.write_lens(os.path.join(seq, "camera.yaml"), lens, size, f"clip_study --lens-k1 {k1!r}")


def run_one(binary, seq, out, extra):
    cmd = [binary, "run", seq, "--mode", "inprocess", "--quiet", "--out", out] + extra
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"clip_study: `{' '.join(cmd)}` failed:\n{r.stderr[-2000:]}")
    with open(os.path.join(out, "report.json")) as f:
        rep = json.load(f)
    ev = rep.get("eval") or {}
    posed = [d for d in rep["frames_detail"] if d.get("pose") is not None]
    tracked = [d["inliers"] for d in posed if d.get("state") == "tracking"]
    kitti = ev.get("kitti")
    return {
        "frames": rep["frames"],
        "posed": rep["estimated"],
        "ape": ev.get("ape", {}).get("trans", {}).get("rmse"),
        "tracked_median": statistics.median(tracked) if tracked else 0,
        # keyframes per posed frame: with a thin map nearly every frame becomes one
        "keyframes_pct": 100.0 * sum(1 for d in posed if d.get("keyframe")) / max(len(posed), 1),
        "t_err": kitti["t_err_pct"] if kitti else None,
        "r_err": kitti["r_err_deg_per_100m"] if kitti else None,
        "ms": rep["timing_ms"]["frame_median"],
        # the radial k1 learnt beyond the calibration (--lens-self-calibration)
        "learnt_k1": (rep.get("lens_residual") or {}).get("learnt_k1"),
    }


def main():
    global KITTI
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("--kitti", default=KITTI, help="root of the KITTI layout (e.g. `supermvo synth --out`)")
    ap.add_argument("--strides", default="1,2,3")
    ap.add_argument("--clips", default=",".join(CLIPS))
    ap.add_argument("--json", help="also write the rows here")
    ap.add_argument("--peer", help="arguments of a second run of every sequence (space-separated)")
    ap.add_argument("--peer-bin", help="build that runs the peer (default: --bin)")
    ap.add_argument("--seeds", default="0", help="RANSAC seeds, comma-separated; each row is the median run")
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (accuracy studies; not with --peer)")
    ap.add_argument("--lens-k1", type=float, help="radial coefficient k1 of a camera file given to every sequence")
    ap.add_argument("extra", nargs="*", help="arguments passed on to every `supermvo run`")
    args = ap.parse_args()
    KITTI = os.path.abspath(args.kitti)
    if not os.path.isdir(KITTI):
        sys.exit(f"clip_study: {KITTI} not found (the KITTI clips of ../shared/data)")
    if not os.access(args.bin, os.X_OK):
        sys.exit(f"clip_study: {args.bin} not found; run `cargo build --release --workspace --bins` first")
    strides = [int(s) for s in args.strides.split(",")]
    clips = [c for c in args.clips.split(",") if os.path.isdir(os.path.join(KITTI, "sequences", c))]
    rows = []
    peer = args.peer.split() if args.peer is not None else ([] if args.peer_bin else None)
    peer_bin = args.peer_bin or args.bin
    if not os.access(peer_bin, os.X_OK):
        sys.exit(f"clip_study: {peer_bin} not found")
    seeds = [int(x) for x in args.seeds.split(",")]
    if peer is not None and args.jobs > 1:
        sys.exit("clip_study: --peer compares speed, so its runs go one at a time (no --jobs)")
    header = (f"{'run':<14} {'frames':>6} {'posed':>11} {'APE (m)':>8} {'tracked':>7} {'kf %':>5} "
              f"{'t_err %':>7} {'r_err':>6} {'ms/frame':>8}")
    if len(seeds) > 1:
        header += "  APE per seed " + " / ".join(str(x) for x in seeds) + " (row: median)"
    if peer is not None:
        header += f" | {'peer posed':>10} {'peer APE':>8} {'peer ms':>7} {'speed-up':>8}"
    print(header, flush=True)
    fmt = lambda v, f: "–" if v is None else format(v, f)
    with tempfile.TemporaryDirectory() as tmp:
        tasks = [(c, s, subsample(c, s, tmp, args.lens_k1)) for c in clips for s in strides]

        def one(task, seed):
            c, s, seq = task
            extra = args.extra + (["--seed", str(seed)] if seed else [])
            r = run_one(args.bin, seq, os.path.join(tmp, "out", f"{c}_{s}_{seed}"), extra)
            r.update(clip=c, stride=s, seed=seed)
            if peer is not None:
                out = os.path.join(tmp, "out", f"{c}_{s}_{seed}_peer")
                r["peer"] = run_one(peer_bin, seq, out, extra + peer)
            return r

        with concurrent.futures.ThreadPoolExecutor(max_workers=max(args.jobs, 1)) as pool:
            futures = [[pool.submit(one, t, seed) for seed in seeds] for t in tasks]
            for (c, s, _), fs in zip(tasks, futures):
                runs = [f.result() for f in fs]
                # the row is the run with the median APE (a failed evaluation counts as worst)
                order = sorted(runs, key=lambda r: float("inf") if r["ape"] is None else r["ape"])
                r = dict(order[(len(order) - 1) // 2])
                r["seeds"] = runs
                rows.append(r)
                name = c if s == 1 else f"{c}/{s}"
                share = 100.0 * r["posed"] / max(r["frames"], 1)
                print(f"{name:<14} {r['frames']:>6} {r['posed']:>4} ({share:5.1f}%) {fmt(r['ape'], '8.3f')} "
                      f"{r['tracked_median']:>7.0f} {r['keyframes_pct']:>5.0f} "
                      f"{fmt(r['t_err'], '7.2f')} {fmt(r['r_err'], '6.2f')} "
                      f"{r['ms']:>8.1f}", end="")
                if len(seeds) > 1:
                    print("  " + " / ".join(fmt(q["ape"], ".3f") for q in runs), end="")
                if peer is not None:
                    q = r["peer"]
                    print(f" | {q['posed']:>10} {fmt(q['ape'], '8.3f')} {q['ms']:>7.1f} "
                          f"{q['ms'] / r['ms']:>7.2f}x", end="")
                print(flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"extra": args.extra, "peer": peer, "bin": args.bin, "peer_bin": peer_bin,
                       "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
