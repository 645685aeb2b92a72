"""Reads bfsim's pose stream (MAVLink 2 frames, concatenated in a file) with pymavlink and
prints: `count=N`, the last ODOMETRY's fields as key=value, and every time_usec."""
import math
import sys

from pymavlink.dialects.v20 import common as mavlink2

data = open(sys.argv[1], "rb").read()
mav = mavlink2.MAVLink(None)
msgs = mav.parse_buffer(data) or []
odo = [m for m in msgs if m.get_type() == "ODOMETRY"]
print(f"count={len(odo)}")
m = odo[-1]
r = lambda v: round(v, 3) + 0.0
fields = {
    "frame_id": m.frame_id,
    "child_frame_id": m.child_frame_id,
    "estimator_type": m.estimator_type,
    "quality": m.quality,
    "reset_counter": m.reset_counter,
    "x": r(m.x),
    "y": r(m.y),
    "z": r(m.z),
    "q": ",".join(str(r(c)) for c in m.q),
    "v": ",".join(str(r(c)) for c in (m.vx, m.vy, m.vz)),
    "cov0_nan": math.isnan(m.pose_covariance[0]) and math.isnan(m.velocity_covariance[0]),
    "sysid": m.get_srcSystem(),
    "compid": m.get_srcComponent(),
}
print(" ".join(f"{k}={v}" for k, v in fields.items()))
print(",".join(str(m.time_usec) for m in odo))
