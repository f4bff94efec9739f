#!/usr/bin/env python3
"""Prints the poses and latency of a running SuPerMVO pipeline, read over iceoryx2.

A diagnostic subscriber written with the official iceoryx2 Python bindings and ctypes only:
nothing from the SuPerMVO workspace is imported. It opens the pipeline's `poses` service
(payload `supermvo::PoseMsg`, user header `supermvo::FrameHeader`; layouts in
docs/daemon.md, "Message layouts") and prints one line per frame:

    seq frame state has_pose latency_ms r00 r01 r02 tx r10 r11 r12 ty r20 r21 r22 tz

where the 12 numbers are `T_world_cam` (row-major, KITTI's order) in Python's shortest
round-trip form, and latency is capture (ingest) to pose (tracking). The frame whose
initialisation built the map also poses the frames seen while initialising; each of those
follows it as one line

    seq backfilled r00 r01 r02 tx r10 r11 r12 ty r20 r21 r22 tz
 It ends when the
pipeline's end of stream arrives, or after --timeout seconds without a message.

    python3 -m pip install iceoryx2==0.10.0
    python3 examples/python/pose_subscriber.py [--name PIPELINE] [--timeout 60]
"""
import argparse
import ctypes
import sys
import time

import iceoryx2 as iox2

SCHEMA_VERSION = 4
MAX_BACKFILLED = 16
STATUS_END_OF_STREAM = 4
STAGE_INGEST, STAGE_TRACKING = 0, 3


class FrameHeader(ctypes.Structure):
    """The user header of every data message (96 bytes)."""

    _fields_ = [
        ("schema", ctypes.c_uint32),
        ("status", ctypes.c_uint32),
        ("seq", ctypes.c_uint64),
        ("frame", ctypes.c_uint64),
        ("stamp", ctypes.c_double),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("reference", ctypes.c_int64),
        ("count", ctypes.c_uint32),
        ("dim", ctypes.c_uint32),
        ("t_ns", ctypes.c_uint64 * 5),
    ]

    @staticmethod
    def type_name():
        return "supermvo::FrameHeader"


class BackfilledPose(ctypes.Structure):
    """An earlier frame's pose, sent with the frame that made it known (104 bytes)."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("t_world_cam", ctypes.c_double * 12),
    ]


class PoseMsg(ctypes.Structure):
    """The tracker's result for one frame (1824 bytes)."""

    _fields_ = [
        ("state", ctypes.c_uint32),
        ("has_pose", ctypes.c_uint32),
        ("t_world_cam", ctypes.c_double * 12),
        ("keyframe", ctypes.c_uint32),
        ("keypoints", ctypes.c_uint32),
        ("matches", ctypes.c_uint32),
        ("inliers", ctypes.c_uint32),
        ("landmarks", ctypes.c_uint64),
        ("reference", ctypes.c_int64),
        ("match_next", ctypes.c_uint32),
        ("scale", ctypes.c_double),
        ("backfilled_count", ctypes.c_uint32),
        ("corrections", ctypes.c_uint32),
        ("backfilled", BackfilledPose * MAX_BACKFILLED),
    ]

    @staticmethod
    def type_name():
        return "supermvo::PoseMsg"


# the sizes docs/daemon.md gives and the Rust build checks; a mismatch here means this file
# and the pipeline disagree about the layout
assert ctypes.sizeof(FrameHeader) == 96, ctypes.sizeof(FrameHeader)
assert ctypes.sizeof(PoseMsg) == 1824, ctypes.sizeof(PoseMsg)
assert PoseMsg.scale.offset == 144 and FrameHeader.t_ns.offset == 56
assert PoseMsg.backfilled.offset == 160 and ctypes.sizeof(BackfilledPose) == 104


def open_poses(node, pipeline, timeout):
    """The pipeline's `poses` service, waiting up to `timeout` s for it to appear."""
    name = iox2.ServiceName.new(f"supermvo/{pipeline}/poses")
    deadline = time.monotonic() + timeout
    while True:
        try:
            return (
                node.service_builder(name)
                .publish_subscribe(PoseMsg)
                .user_header(FrameHeader)
                .open()
            )
        except iox2.PublishSubscribeOpenError as e:
            if time.monotonic() > deadline:
                sys.exit(f"pose_subscriber: pipeline '{pipeline}' is not running ({e}); "
                         "start it with `supermvo run SEQ --name {pipeline}`")
            time.sleep(0.05)


def lines(h, p):
    """The output lines for a frame: its own, then one per earlier frame it posed."""
    t_cap, t_pose = h.t_ns[STAGE_INGEST], h.t_ns[STAGE_TRACKING]
    latency = (t_pose - t_cap) * 1e-6 if t_cap and t_pose >= t_cap else float("nan")
    pose = " ".join(repr(v) for v in p.t_world_cam) if p.has_pose else "-"
    out = [f"{h.seq} {h.frame} {p.state} {p.has_pose} {latency:.1f} {pose}"]
    for b in p.backfilled[:min(p.backfilled_count, MAX_BACKFILLED)]:
        out.append(f"{b.seq} backfilled " + " ".join(repr(v) for v in b.t_world_cam))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--name", default="supermvo", help="pipeline name (pipeline.name)")
    ap.add_argument("--timeout", type=float, default=60.0,
                    help="give up after this many seconds without a message")
    args = ap.parse_args()

    iox2.set_log_level(iox2.LogLevel.Error)
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    service = open_poses(node, args.name, args.timeout)
    subscriber = service.subscriber_builder().create()
    last = time.monotonic()
    while True:
        sample = subscriber.receive()
        if sample is None:
            if time.monotonic() - last > args.timeout:
                sys.exit(f"pose_subscriber: no pose for {args.timeout} s")
            time.sleep(0.002)
            continue
        last = time.monotonic()
        h = sample.user_header().contents
        if h.schema != SCHEMA_VERSION:
            sys.exit(f"pose_subscriber: schema version {h.schema}, this script reads "
                     f"{SCHEMA_VERSION}")
        if h.status == STATUS_END_OF_STREAM:
            print(f"end of stream after {h.seq} frames", flush=True)
            return
        print("\n".join(lines(h, sample.payload().contents)), flush=True)


if __name__ == "__main__":
    main()
