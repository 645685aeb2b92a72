"""pymavlink plays the vehicle (a PX4 in POSCTL, disarmed, at paper-2's start) and an attacker
on another UDP port of the same machine, both talking to the gateway's `udpin` port.

Usage: attacker_gateway.py PORT SECONDS ATTACK_FROM_S ATTACK_TO_S [KEY_HEX]

The vehicle streams as autopilot_gateway.py's does (Px4Stream) and never answers a command.
From ATTACK_FROM_S to ATTACK_TO_S the attacker sends, every 20 ms: a one-byte junk datagram,
LOCAL_POSITION_NED and ATTITUDE 40 m north of the vehicle stamped ahead of its clock (as system
1, and as system 77), a heartbeat of an armed PX4 in OFFBOARD from the next of systems 2..250,
a COMMAND_ACK accepting MAV_CMD_COMPONENT_ARM_DISARM as system 99, a LOCAL_POSITION_NED
stamped 0 ms as system 1 (a "reboot"), and a TIMESYNC answer with a clock gone back (tc1 = 1)
to the gateway's last request.

With KEY_HEX (64 hex digits) the vehicle signs with that key and checks what it hears
(pymavlink's signing: unsigned or otherwise signed frames are not delivered), and the attacker
sends its frames half signed with another key and half unsigned, from the start (to be first).

Prints one JSON line: what the attacker received (it must be nothing), the setpoints the
vehicle received (per second during the attack, their targets), the commands it heard.
"""

import json
import os
import socket
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402  (the environment variable must come first)
from px4_stream import PX4_POSCTL, Px4Stream  # noqa: E402

mavutil.set_dialect("common")
m = mavutil.mavlink

port, seconds = int(sys.argv[1]), float(sys.argv[2])
attack_from, attack_to = float(sys.argv[3]), float(sys.argv[4])
key = bytes.fromhex(sys.argv[5]) if len(sys.argv) > 5 else None

vehicle = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
attacker = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
# A second attacker connection with another key (or unsigned), same port.
if key is not None:
    vehicle.setup_signing(key, sign_outgoing=True)
    attacker.setup_signing(bytes(32 - i for i in range(32)), sign_outgoing=True)
    attack_from = 0.0

start = time.monotonic()
px4 = Px4Stream(start)
setpoints = []  # (t, target_system, target_component)
commands = []
attacker_received = 0
last_timesync_ts1 = None
next_attack = 0.0
attack_sysid = 2
attack_rounds = 0
PX4_OFFBOARD = 6 << 16


def send_attack(now):
    """One round of every attack, from the attacker's port."""
    global attack_sysid, attack_rounds
    attack_rounds += 1
    a = attacker.mav
    dest = ("127.0.0.1", port)
    attacker.port.sendto(b"\x00", dest)
    ahead_ms = px4.boot_ms() + 5
    for sysid in (1, 77):
        a.srcSystem = sysid
        a.local_position_ned_send(ahead_ms, 43.2, 0.0, 0.0, 0.0, 0.0, 0.0)
        a.attitude_send(ahead_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    a.srcSystem = attack_sysid
    a.heartbeat_send(
        m.MAV_TYPE_QUADROTOR,
        m.MAV_AUTOPILOT_PX4,
        m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | m.MAV_MODE_FLAG_SAFETY_ARMED,
        PX4_OFFBOARD,
        m.MAV_STATE_ACTIVE,
    )
    attack_sysid = 2 if attack_sysid >= 250 else attack_sysid + 1
    a.srcSystem = 99
    a.command_ack_send(m.MAV_CMD_COMPONENT_ARM_DISARM, m.MAV_RESULT_ACCEPTED)
    a.srcSystem = 1
    a.local_position_ned_send(0, 3.2, 0.0, 0.0, 0.0, 0.0, 0.0)
    if last_timesync_ts1 is not None:
        a.timesync_send(1, last_timesync_ts1)
    if key is not None:
        # The same, unsigned: the gateway drops it as unsigned (or as from another address).
        signing = a.signing.sign_outgoing
        a.signing.sign_outgoing = False
        a.heartbeat_send(m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_PX4, 0, PX4_POSCTL, m.MAV_STATE_STANDBY)
        a.signing.sign_outgoing = signing


# The vehicle starts after the attacker when signing (the attacker tries to be first).
vehicle_from = 0.5 if key is not None else 0.0
while time.monotonic() - start < seconds:
    now = time.monotonic() - start
    if now >= vehicle_from:
        px4.send_due(vehicle.mav, now)
    if attack_from <= now < attack_to and now >= next_attack:
        next_attack = now + 0.02
        send_attack(now)
    # Whatever reaches the attacker's port.
    attacker.port.setblocking(False)
    while True:
        try:
            attacker.port.recvfrom(65535)
        except (BlockingIOError, socket.error):
            break
        attacker_received += 1
    msg = vehicle.recv_match(blocking=True, timeout=0.005)
    if msg is None:
        continue
    t = time.monotonic() - start
    kind = msg.get_type()
    if kind == "SET_ATTITUDE_TARGET":
        setpoints.append((t, msg.target_system, msg.target_component))
    elif kind in ("COMMAND_LONG", "COMMAND_INT"):
        commands.append(msg.command)
    elif kind == "TIMESYNC" and msg.tc1 == 0:
        last_timesync_ts1 = msg.ts1
        px4.answer_timesync(vehicle.mav, msg)

during = [s[0] for s in setpoints if attack_from + 0.1 <= s[0] < attack_to]
windows = []
w = attack_from + 0.1
while w + 1.0 <= attack_to:
    windows.append(sum(1 for t in during if w <= t < w + 1.0))
    w += 1.0
report = {
    "attacker_received": attacker_received,
    "attack_rounds": attack_rounds,
    "setpoints": len(setpoints),
    "setpoints_during_attack": len(during),
    "setpoints_per_second_min_during_attack": min(windows) if windows else 0,
    "targets": sorted({(s[1], s[2]) for s in setpoints}),
    "commands": commands,
    "vehicle_port": vehicle.port.getsockname()[1],
}
print(json.dumps(report))
