"""Reads a run's MCAP file with the Python `mcap` package (an implementation independent of the
Rust writer), decodes every message (protobuf through the schemas the file carries, JSON), and
prints what the Rust test compares with summary.json and the CSV log, as one JSON object:
channels (topic -> schema name and encodings), messages per topic, the cycles seen on each
per-cycle topic, whether log times never go back in the file's order, the scene's cylinders,
the plan's lines per cycle, and the last pose.

Usage: read_mcap.py RUN.mcap
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main(path):
    out = {
        "channels": {},
        "messages": {},
        "cycles": {},
        "log_times_monotonic": True,
        "metadata": {},
    }
    last_log_time = -1
    plan_lines = []
    plan_weights = []
    poses = []
    scene = None
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for ch in summary.channels.values():
            schema = summary.schemas[ch.schema_id]
            out["channels"][ch.topic] = {
                "schema": schema.name,
                "schema_encoding": schema.encoding,
                "message_encoding": ch.message_encoding,
            }
        for record in reader.iter_metadata():
            out["metadata"][record.name] = dict(record.metadata)
        # In the order written (not sorted by log time), to check that log time never goes back.
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            topic = channel.topic
            out["messages"][topic] = out["messages"].get(topic, 0) + 1
            if message.log_time < last_log_time:
                out["log_times_monotonic"] = False
            last_log_time = message.log_time
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
                out["cycles"].setdefault(topic, []).append(decoded["cycle"])
                continue
            decoded = DecoderFactory().decoder_for(channel.message_encoding, schema)(message.data)
            if topic == "/pose":
                p = decoded.pose.position
                poses.append({"log_time": message.log_time, "position": [p.x, p.y, p.z]})
            elif topic == "/plan":
                plan_lines.append(sum(len(e.lines) for e in decoded.entities))
                plan_weights.append([float(kv.value) for e in decoded.entities for kv in e.metadata if kv.key == "weight"])
            elif topic == "/scene" and scene is None:
                scene = {
                    "entities": sorted(e.id for e in decoded.entities),
                    "cylinders": [
                        {"x": c.pose.position.x, "y": c.pose.position.y, "diameter": c.size.x, "height": c.size.z}
                        for e in decoded.entities
                        for c in e.cylinders
                    ],
                }
    out["scene"] = scene
    out["plan_lines"] = plan_lines
    out["plan_weights"] = plan_weights
    out["poses"] = len(poses)
    out["last_pose"] = poses[-1] if poses else None
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
