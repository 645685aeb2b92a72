"""An independent MAVLink implementation (pymavlink) plays the autopilot for the gateway.

Usage: autopilot_gateway.py PORT YAW_RAD SECONDS

Sends to the gateway's `udpin` port, as PX4 does: HEARTBEAT (PX4, disarmed, POSCTL) at 1 Hz,
ATTITUDE (level, at YAW_RAD) and LOCAL_POSITION_NED (paper-2's start) at 50 Hz, and answers
TIMESYNC. Records everything the gateway sends until it has seen a commanded phase followed by
one second of hover (or SECONDS pass), and prints one JSON line of what it saw; the Rust test
asserts on it (the rate, the type mask, the quaternions and the direction they tilt the thrust
in, the thrust range, the heartbeats, that no command or mode change came unasked: no
COMMAND_LONG, COMMAND_INT or SET_MODE, and the hover hold after the controller fell silent).
"""

import json
import math
import os
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402  (the environment variable must come first)
from px4_stream import Px4Stream  # noqa: E402

mavutil.set_dialect("common")

port, yaw, seconds = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
start = time.monotonic()
px4 = Px4Stream(start)
setpoints = []  # (t, q, thrust, type_mask, target_system, target_component)
heartbeats = []
unasked = []  # COMMAND_LONG / COMMAND_INT commands and SET_MODE modes, as sent
timesync_requests = 0
hover_since = None
commanded_seen = False


def thrust_axis_ned(q):
    """The thrust's direction in NED (the body's -z axis rotated by q): north, east, down."""
    w, x, y, z = q
    return (-2.0 * (x * z + w * y), 2.0 * (w * x - y * z), -(1.0 - 2.0 * (x * x + y * y)))


def tilt_and_yaw(q):
    w, x, y, z = q
    tilt = math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (x * x + y * y))))
    qyaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return tilt, qyaw


while time.monotonic() - start < seconds:
    now = time.monotonic() - start
    px4.send_due(conn.mav, now, yaw)
    msg = conn.recv_match(blocking=True, timeout=0.005)
    if msg is None:
        continue
    t = time.monotonic() - start
    kind = msg.get_type()
    if kind == "SET_ATTITUDE_TARGET":
        q = list(msg.q)
        setpoints.append((t, q, msg.thrust, msg.type_mask, msg.target_system, msg.target_component))
        tilt, _ = tilt_and_yaw(q)
        hover = abs(msg.thrust - 0.5) < 1e-6 and tilt < 1e-6
        if not hover:
            commanded_seen = True
            hover_since = None
        elif commanded_seen and hover_since is None:
            hover_since = t
        if hover_since is not None and t - hover_since > 1.0:
            break
    elif kind == "HEARTBEAT":
        heartbeats.append((t, msg.type, msg.autopilot))
    elif kind in ("COMMAND_LONG", "COMMAND_INT"):
        unasked.append(f"{kind} {msg.command}")
    elif kind == "SET_MODE":
        unasked.append(f"SET_MODE {msg.base_mode} {msg.custom_mode}")
    elif kind == "TIMESYNC" and msg.tc1 == 0:
        timesync_requests += 1
        px4.answer_timesync(conn.mav, msg)

times = [s[0] for s in setpoints]
# Setpoints per whole second of the observation (the rate PX4 sees).
windows = []
if times:
    w = times[0]
    while w + 1.0 <= times[-1]:
        windows.append(sum(1 for t in times if w <= t < w + 1.0))
        w += 1.0
quat_norm_err = max((abs(math.sqrt(sum(v * v for v in s[1])) - 1.0) for s in setpoints), default=None)
yaw_err = max((abs(tilt_and_yaw(s[1])[1] - yaw) for s in setpoints), default=None)
commanded = [s for s in setpoints if not (abs(s[2] - 0.5) < 1e-6 and tilt_and_yaw(s[1])[0] < 1e-6)]
last_commanded_t = commanded[-1][0] if commanded else None
after = [s for s in setpoints if last_commanded_t is not None and s[0] > last_commanded_t]
report = {
    "setpoints": len(setpoints),
    "setpoints_per_second_min": min(windows) if windows else 0,
    "type_masks": sorted({s[3] for s in setpoints}),
    "targets": sorted({(s[4], s[5]) for s in setpoints}),
    "quat_norm_err_max": quat_norm_err,
    "yaw_err_max": yaw_err,
    "thrust_min": min((s[2] for s in setpoints), default=None),
    "thrust_max": max((s[2] for s in setpoints), default=None),
    "commanded": len(commanded),
    "commanded_thrust": sorted({round(s[2], 6) for s in commanded}),
    "commanded_tilt_min": min((tilt_and_yaw(s[1])[0] for s in commanded), default=None),
    # Where the commanded setpoints point the thrust, whatever the yaw: north and east.
    "commanded_thrust_north_abs_max": max((abs(thrust_axis_ned(s[1])[0]) for s in commanded), default=None),
    "commanded_thrust_east_min": min((thrust_axis_ned(s[1])[1] for s in commanded), default=None),
    "commanded_thrust_east_max": max((thrust_axis_ned(s[1])[1] for s in commanded), default=None),
    "after_commanded": len(after),
    "after_commanded_all_level_hover": all(abs(s[2] - 0.5) < 1e-6 and tilt_and_yaw(s[1])[0] < 1e-6 for s in after),
    "hover_held_s": (times[-1] - hover_since) if hover_since is not None else 0.0,
    "gateway_heartbeats": len(heartbeats),
    "gateway_heartbeat_types": sorted({h[1] for h in heartbeats}),
    "unasked": unasked,
    "timesync_requests": timesync_requests,
}
print(json.dumps(report))
