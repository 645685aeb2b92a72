"""PX4's own client library flies mavsim: MAVSDK (the `mavsdk` wheel and the `mavsdk_server` it
ships) connects to the simulated vehicle, reads its telemetry, arms it, flies OFFBOARD attitude
setpoints (one set before starting, as PX4 requires), checks that the telemetry follows (the
commanded roll, a climb at more than hover thrust), then leaves OFFBOARD (HOLD) and disarms.

usage: mavsdk_mavsim.py SYSTEM_ADDRESS GRPC_PORT
  SYSTEM_ADDRESS  where mavsdk_server listens for the vehicle, e.g. udpin://127.0.0.1:14540
                  (mavsim's default --mavlink udpout:127.0.0.1:14540 sends there)
  GRPC_PORT       the port mavsdk_server serves the Python side on (a free one)

Prints one JSON line with what it saw; exits 1 naming the step that failed. Every await is
bounded.
"""

import asyncio
import json
import os
import sys
import warnings

# 3.x is the gRPC wrapper's last release under this name; it warns so on import.
warnings.simplefilter("ignore", FutureWarning)

from mavsdk import System  # noqa: E402
from mavsdk.offboard import Attitude, OffboardError  # noqa: E402

STEP_S = 20.0
ROLL_DEG = 5.0
# mavsim's (and the gateway's) default hover thrust is 0.5: 0.6 climbs at 1.2 g.
HOVER = 0.5
CLIMB = 0.6
FLY_S = 2.0
ROLL_TOLERANCE_DEG = 1.0
MIN_CLIMB_M = 0.2


class Failed(Exception):
    pass


async def bounded(what, awaitable, timeout=STEP_S):
    try:
        return await asyncio.wait_for(awaitable, timeout)
    except asyncio.TimeoutError:
        raise Failed(f"{what}: nothing within {timeout} s") from None
    except Failed:
        raise
    except Exception as e:  # the plugins' own errors (ActionError, OffboardError, ...)
        raise Failed(f"{what}: {type(e).__name__}: {e}") from None


async def first(what, stream, pred=lambda _: True, timeout=STEP_S):
    async def go():
        async for item in stream:
            if pred(item):
                return item

    return await bounded(what, go(), timeout)


async def latest(drone):
    """The newest attitude and local position, read afresh."""
    att = await first("attitude_euler", drone.telemetry.attitude_euler())
    pv = await first("position_velocity_ned", drone.telemetry.position_velocity_ned())
    return att, pv


async def fly(drone, system_address):
    await bounded("connect (mavsdk_server starts)", drone.connect(system_address=system_address))
    await first("connection_state", drone.core.connection_state(), lambda s: s.is_connected)
    armed0 = await first("armed (disarmed at start)", drone.telemetry.armed())
    if armed0:
        raise Failed("the vehicle is armed before it was asked")
    att0, pv0 = await latest(drone)
    mode0 = await first("flight_mode", drone.telemetry.flight_mode())

    await bounded("action.arm", drone.action.arm())
    await first("armed", drone.telemetry.armed(), lambda a: a)

    # PX4 refuses OFFBOARD without a setpoint stream: one first (MAVSDK then repeats it).
    await bounded("offboard.set_attitude (before start)", drone.offboard.set_attitude(Attitude(0.0, 0.0, 0.0, HOVER)))
    try:
        await bounded("offboard.start", drone.offboard.start())
    except Failed:
        raise
    except OffboardError as e:
        raise Failed(f"offboard.start: {e._result.result}") from None
    mode_offboard = await first("flight_mode OFFBOARD", drone.telemetry.flight_mode(), lambda m: str(m) == "OFFBOARD")

    await bounded(
        "offboard.set_attitude (roll, climb)",
        drone.offboard.set_attitude(Attitude(ROLL_DEG, 0.0, 0.0, CLIMB)),
    )
    await asyncio.sleep(FLY_S)
    att1, pv1 = await latest(drone)
    roll_error = abs(att1.roll_deg - ROLL_DEG)
    climbed = pv0.position.down_m - pv1.position.down_m
    if roll_error > ROLL_TOLERANCE_DEG:
        raise Failed(f"roll {att1.roll_deg:.2f} deg, commanded {ROLL_DEG} (tolerance {ROLL_TOLERANCE_DEG})")
    if climbed < MIN_CLIMB_M:
        raise Failed(f"climbed {climbed:.3f} m in {FLY_S} s at thrust {CLIMB} (hover {HOVER})")
    if abs(att1.pitch_deg) > ROLL_TOLERANCE_DEG:
        raise Failed(f"pitch {att1.pitch_deg:.2f} deg, commanded 0")
    # Rolled right (positive NED roll) drifts east.
    east = pv1.position.east_m - pv0.position.east_m

    await bounded("offboard.stop (to HOLD)", drone.offboard.stop())
    mode_after = await first("flight_mode HOLD", drone.telemetry.flight_mode(), lambda m: str(m) == "HOLD")
    await bounded("action.disarm", drone.action.disarm())
    await first("disarmed", drone.telemetry.armed(), lambda a: not a)

    return {
        "connected": True,
        "armed_at_start": armed0,
        "mode_at_start": str(mode0),
        "mode_offboard": str(mode_offboard),
        "mode_after_stop": str(mode_after),
        "roll_deg": att1.roll_deg,
        "pitch_deg": att1.pitch_deg,
        "roll_commanded_deg": ROLL_DEG,
        "roll_before_deg": att0.roll_deg,
        "climbed_m": climbed,
        "east_m": east,
        "down_before_m": pv0.position.down_m,
        "down_after_m": pv1.position.down_m,
        "disarmed": True,
    }


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    system_address, grpc_port = sys.argv[1], int(sys.argv[2])
    drone = System(port=grpc_port)
    loop = asyncio.new_event_loop()
    code = 1
    try:
        report = loop.run_until_complete(asyncio.wait_for(fly(drone, system_address), 120))
        print(json.dumps(report), flush=True)
        code = 0
    except Failed as e:
        print(f"mavsdk_mavsim: {e}", file=sys.stderr)
    except asyncio.TimeoutError:
        print("mavsdk_mavsim: the whole flight took more than 120 s", file=sys.stderr)
    finally:
        # mavsdk_server is a child process: kill it, and leave without waiting for the gRPC
        # streams still open to notice.
        drone._stop_mavsdk_server()
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(code)

if __name__ == "__main__":
    main()
