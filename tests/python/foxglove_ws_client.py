"""A Foxglove WebSocket client (protocol foxglove.websocket.v1, written from the protocol's
specification with the `websockets` package, independent of the Rust server): connects to ADDR
(retrying while the server comes up), subscribes to every advertised channel, and collects
message frames until it has a scene and MIN_POSES poses or TIMEOUT_S passes. Poses are decoded
with the protobuf schema the server advertised. Prints one JSON object: the advertised channels
(topic -> schema name and encoding), messages per topic, the decoded poses' positions and log
times.

Usage: foxglove_ws_client.py HOST:PORT MIN_POSES TIMEOUT_S
"""

import asyncio
import base64
import json
import struct
import sys
import time

import websockets
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01


async def connect(uri, deadline):
    while True:
        try:
            return await websockets.connect(uri, subprotocols=[SUBPROTOCOL], max_size=None)
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.1)


async def main(addr, min_poses, timeout_s):
    deadline = time.monotonic() + timeout_s
    ws = await connect(f"ws://{addr}", deadline)
    assert ws.subprotocol == SUBPROTOCOL, ws.subprotocol
    channels = {}  # channel id -> advertisement
    subscriptions = {}  # subscription id -> channel id
    counts = {}
    poses = []
    decoders = {}
    server_name = None
    try:
        while time.monotonic() < deadline:
            if counts.get("/scene", 0) >= 1 and len(poses) >= min_poses:
                break
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.0, deadline - time.monotonic()))
            except asyncio.TimeoutError:
                break
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "serverInfo":
                    server_name = msg.get("name")
                elif msg["op"] == "advertise":
                    new = []
                    for ch in msg["channels"]:
                        channels[ch["id"]] = ch
                        sub_id = len(subscriptions) + 1
                        subscriptions[sub_id] = ch["id"]
                        new.append({"id": sub_id, "channelId": ch["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                continue
            if frame[0] != MESSAGE_DATA:
                continue
            sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
            payload = frame[13:]
            ch = channels[subscriptions[sub_id]]
            topic = ch["topic"]
            counts[topic] = counts.get(topic, 0) + 1
            if topic == "/pose":
                if topic not in decoders:
                    schema = Schema(
                        id=1,
                        name=ch["schemaName"],
                        encoding=ch["schemaEncoding"],
                        data=base64.b64decode(ch["schema"]),
                    )
                    decoders[topic] = DecoderFactory().decoder_for(ch["encoding"], schema)
                p = decoders[topic](payload).pose.position
                poses.append({"log_time": log_time, "position": [p.x, p.y, p.z]})
    finally:
        await ws.close()
    print(
        json.dumps(
            {
                "server_name": server_name,
                "channels": {
                    ch["topic"]: {"schema": ch["schemaName"], "encoding": ch["encoding"]} for ch in channels.values()
                },
                "messages": counts,
                "poses": poses,
            }
        )
    )


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))
