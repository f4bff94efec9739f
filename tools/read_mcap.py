#!/usr/bin/env python3
"""Reads a SuPerMVO MCAP recording back with the independent `mcap` package and its
protobuf decoders (and Pillow for the images), and prints one JSON summary:

    {"channels": {topic: {"schema": name, "schema_encoding": ..., "message_encoding": ...,
                          "messages": n}},
     "poses": [[sec, nsec, x, y, z, qx, qy, qz, qw], ...],     # /camera/pose, in log order
     "frames": [{"frame": i, "state": ..., ...}, ...],          # /supermvo/frame
     "images": {"decoded": n, "failed": n, "size": [w, h]},
     "map_points": n, "log": [text, ...]}

The test tools/supermvo/tests/record_mcap.rs compares it with the run's own outputs.

    PYTHONPATH=$(cache)/python-tools python3 tools/read_mcap.py FILE.mcap
(tools/python_tools.sh installs the pinned readers into the cache.)
"""
import io
import json
import sys

from mcap.decoder import DecoderFactory as BaseDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
from PIL import Image


class JsonDecoderFactory(BaseDecoderFactory):
    """Decodes channels whose message encoding is `json`."""

    def decoder_for(self, message_encoding, schema):
        if message_encoding == "json":
            return lambda data: json.loads(data)
        return None


def main(path):
    out = {"channels": {}, "poses": [], "frames": [], "map_points": 0, "log": [],
           "images": {"decoded": 0, "failed": 0, "size": None}}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[ProtobufDecoderFactory(), JsonDecoderFactory()])
        summary = reader.get_summary()
        for ch in summary.channels.values():
            schema = summary.schemas[ch.schema_id]
            out["channels"][ch.topic] = {"schema": schema.name, "schema_encoding": schema.encoding,
                                         "message_encoding": ch.message_encoding, "messages": 0}
        for _schema, channel, _message, msg in reader.iter_decoded_messages(log_time_order=True):
            out["channels"][channel.topic]["messages"] += 1
            if channel.topic == "/camera/pose":
                p, q = msg.pose.position, msg.pose.orientation
                out["poses"].append([msg.timestamp.seconds, msg.timestamp.nanos,
                                     p.x, p.y, p.z, q.x, q.y, q.z, q.w])
            elif channel.topic == "/supermvo/frame":
                out["frames"].append(msg)
            elif channel.topic == "/camera/image":
                try:
                    img = Image.open(io.BytesIO(msg.data))
                    img.load()
                    out["images"]["decoded"] += 1
                    out["images"]["size"] = list(img.size)
                except Exception:  # noqa: BLE001 - any decoder failure counts
                    out["images"]["failed"] += 1
            elif channel.topic == "/map/points":
                out["map_points"] = max(out["map_points"], len(msg.data) // max(msg.point_stride, 1))
            elif channel.topic == "/log":
                out["log"].append(msg.message)
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
