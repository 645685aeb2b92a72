"""What the test autopilots play alike (autopilot_gateway.py over UDP, autopilot_serial.py
behind a pty): PX4's boot clock, and the stream a hovering PX4 sends in POSCTL: HEARTBEAT at
1 Hz, ATTITUDE (level, at a yaw) and LOCAL_POSITION_NED (paper-2's start, 3.2 m north) at
50 Hz, and its TIMESYNC answer. Import it after setting MAVLINK20 and importing pymavlink."""

import time

from pymavlink import mavutil

m = mavutil.mavlink
PX4_POSCTL = 3 << 16


class Px4Stream:
    def __init__(self, start):
        self.start = start
        self.restart()

    def restart(self):
        """Sends everything at the next call of send_due (a link just opened)."""
        self.next_state = self.next_heartbeat = 0.0

    def boot_ms(self):
        return int((time.monotonic() - self.start) * 1000) + 1

    def send_due(self, mav, now, yaw=0.0):
        """Sends on `mav` what is due at `now` (seconds since start)."""
        if now >= self.next_heartbeat:
            self.next_heartbeat = now + 1.0
            mav.heartbeat_send(
                m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_PX4, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4_POSCTL, m.MAV_STATE_STANDBY
            )
        if now >= self.next_state:
            self.next_state = now + 0.02
            mav.attitude_send(self.boot_ms(), 0.0, 0.0, yaw, 0.0, 0.0, 0.0)
            mav.local_position_ned_send(self.boot_ms(), 3.2, 0.0, 0.0, 0.0, 0.0, 0.0)

    def answer_timesync(self, mav, msg):
        """PX4's answer to a TIMESYNC request: its clock in ns, the request's ts1."""
        mav.timesync_send(int((time.monotonic() - self.start) * 1e9) + 1, msg.ts1)
