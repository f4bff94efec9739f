#!/usr/bin/env python3
"""A Foxglove WebSocket client (the `websockets` package, subprotocol foxglove.sdk.v1)
for `supermvo view`: connects, subscribes to every advertised channel, decodes
/camera/pose with the advertised protobuf schema (mcap_protobuf's decoder), and prints one
JSON summary when the server closes the connection or --timeout passes:

    {"server": name, "channels": {topic: {"schema": name, "encoding": ..., "messages": n}},
     "poses": [[sec, nsec, x, y, z], ...]}

    PYTHONPATH=$(cache)/python-tools python3 tools/ws_view_client.py ws://127.0.0.1:PORT
"""
import argparse
import asyncio
import base64
import json
import struct
import sys
import time

import websockets
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory


async def follow(url, timeout):
    out = {"server": None, "channels": {}, "poses": []}
    by_sub = {}
    decoders = {}
    deadline = time.monotonic() + timeout
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"],
                                  max_size=None) as ws:
        next_id = 1
        while time.monotonic() < deadline:
            try:
                msg = await asyncio.wait_for(ws.recv(), timeout=max(0.1, deadline - time.monotonic()))
            except (asyncio.TimeoutError, websockets.ConnectionClosed):
                break
            if isinstance(msg, str):
                op = json.loads(msg)
                if op.get("op") == "serverInfo":
                    out["server"] = op.get("name")
                elif op.get("op") == "advertise":
                    subs = []
                    for ch in op["channels"]:
                        out["channels"][ch["topic"]] = {"schema": ch.get("schemaName"),
                                                        "encoding": ch.get("encoding"),
                                                        "messages": 0}
                        by_sub[next_id] = ch["topic"]
                        if ch["topic"] == "/camera/pose":
                            schema = Schema(id=1, name=ch["schemaName"], encoding="protobuf",
                                            data=base64.b64decode(ch["schema"]))
                            decoders[next_id] = DecoderFactory().decoder_for("protobuf", schema)
                        subs.append({"id": next_id, "channelId": ch["id"]})
                        next_id += 1
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif msg[0] == 0x01:  # message data: opcode, subscription id, log time, payload
                sub, _log_time = struct.unpack_from("<IQ", msg, 1)
                topic = by_sub.get(sub)
                if topic is None:
                    continue
                out["channels"][topic]["messages"] += 1
                if sub in decoders:
                    p = decoders[sub](msg[13:])
                    pos = p.pose.position
                    out["poses"].append([p.timestamp.seconds, p.timestamp.nanos,
                                         pos.x, pos.y, pos.z])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("url")
    ap.add_argument("--timeout", type=float, default=300.0)
    args = ap.parse_args()
    json.dump(asyncio.run(follow(args.url, args.timeout)), sys.stdout)


if __name__ == "__main__":
    main()
