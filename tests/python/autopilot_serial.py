"""An independent MAVLink implementation (pymavlink) plays a serial autopilot for the gateway.

Usage: autopilot_serial.py LINK SECONDS

Makes a pseudo-terminal and points the symbolic link LINK at its device (as udev's
/dev/serial/by-id/... names a USB autopilot), so that the gateway can open
`serial:LINK:921600`. On the pty's master it talks as PX4 does: HEARTBEAT (PX4, disarmed,
POSCTL) at 1 Hz, ATTITUDE and LOCAL_POSITION_NED (paper-2's start) at 50 Hz, answers TIMESYNC.

Driven by lines on stdin, it reports on stdout, one JSON object a line:
- at start, and after `plug`: {"event": "plugged", "device": "/dev/pts/N"};
- the first SET_ATTITUDE_TARGET that is not level hover at thrust 0.5 (a controller's
  command): {"event": "commanded", "thrust", "type_mask", "target"};
- the first HEARTBEAT heard from the gateway on each device: {"event": "heard"};
- `unplug`: closes the pty (the gateway's end hangs up, as when a USB autopilot is pulled) and
  removes LINK: {"event": "unplugged"};
- `plug`: a new pty behind the same LINK (a USB autopilot re-enumerating);
- `quit`, the end of stdin, or SECONDS passed: exits.
"""

import json
import os
import pty
import select
import sys
import time
import tty

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402  (the environment variable must come first)
from px4_stream import Px4Stream  # noqa: E402

mavutil.set_dialect("common")
m = mavutil.mavlink

link, seconds = sys.argv[1], float(sys.argv[2])
start = time.monotonic()
px4 = Px4Stream(start)


def say(**event):
    print(json.dumps(event), flush=True)


class Pty:
    """One plugged-in autopilot: a pty whose slave the gateway opens through LINK."""

    def __init__(self):
        self.master, self.slave = pty.openpty()
        # Raw, as a serial line: no echo, no line discipline before the gateway opens it.
        tty.setraw(self.slave)
        # A line nobody reads drops bytes rather than blocking the autopilot.
        os.set_blocking(self.master, False)
        self.device = os.ttyname(self.slave)
        tmp = link + ".new"
        os.symlink(self.device, tmp)
        os.replace(tmp, link)
        self.mav = m.MAVLink(self, srcSystem=1, srcComponent=1)
        self.heard = False

    def write(self, data):
        try:
            os.write(self.master, data)
        except (BlockingIOError, OSError):
            pass

    def close(self):
        os.unlink(link)
        os.close(self.master)
        os.close(self.slave)


autopilot = Pty()
say(event="plugged", device=autopilot.device)
commanded = False
stdin_open = True

while time.monotonic() - start < seconds:
    now = time.monotonic() - start
    if autopilot is not None:
        px4.send_due(autopilot.mav, now)
    fds = ([sys.stdin] if stdin_open else []) + ([autopilot.master] if autopilot is not None else [])
    readable, _, _ = select.select(fds, [], [], 0.005)
    if sys.stdin in readable:
        line = sys.stdin.readline()
        command = line.strip()
        if not line or command == "quit":
            break
        if command == "unplug" and autopilot is not None:
            autopilot.close()
            autopilot = None
            say(event="unplugged")
        elif command == "plug" and autopilot is None:
            autopilot = Pty()
            px4.restart()
            say(event="plugged", device=autopilot.device)
        continue
    if autopilot is None or autopilot.master not in readable:
        continue
    try:
        data = os.read(autopilot.master, 4096)
    except (BlockingIOError, OSError):
        continue
    for msg in autopilot.mav.parse_buffer(data) or []:
        kind = msg.get_type()
        if kind == "SET_ATTITUDE_TARGET" and not commanded and abs(msg.thrust - 0.5) > 1e-6:
            commanded = True
            say(event="commanded", thrust=msg.thrust, type_mask=msg.type_mask, target=[msg.target_system, msg.target_component])
        elif kind == "HEARTBEAT" and not autopilot.heard:
            autopilot.heard = True
            say(event="heard", type=msg.type)
        elif kind == "TIMESYNC" and msg.tc1 == 0:
            px4.answer_timesync(autopilot.mav, msg)

if autopilot is not None:
    autopilot.close()
