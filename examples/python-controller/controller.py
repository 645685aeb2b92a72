"""A PD controller for the hilbench MAV, flown by `hilbench run FILE --controller-cmd`.

A client of the Plant API (grpcio; stubs generated from the repository's proto/ at start):
position error and velocity -> desired acceleration -> thrust, roll and pitch within the
limits the plant describes. It flies straight at the goal and avoids nothing. Lockstep: it
calls Step itself every 50 ms of plant time (netem in between holds each command for its delay
and advances the plant on to the release); real time: one command per streamed sample.
Environment (set by the bench): HILBENCH_PLANT_ADDR, HILBENCH_TIME_MODE.
"""

import importlib.resources
import math
import os
import shutil
import signal
import sys
import tempfile
from pathlib import Path

import grpc
from grpc_tools import protoc

CYCLE_NS = 50_000_000  # one command per 50 ms of plant time
KP, KD = 0.6, 1.4  # horizontal: 1/s^2, 1/s (slow enough for 0.5 s attitude lag and ~0.2 s delays)
KP_Z, KD_Z = 2.0, 2.5  # vertical
TILT_USE = 0.8  # share of the tilt limit the position loop may ask for


def stubs(out):
    """Generates the Python modules of plant.proto (and delay.proto, which it imports) into out."""
    # The checkout's proto/proto, two folders above this file; HILBENCH_PROTO_DIR names another
    # (a copy of this controller kept elsewhere).
    root = Path(os.environ.get("HILBENCH_PROTO_DIR") or Path(__file__).resolve().parents[2] / "proto" / "proto")
    well_known = importlib.resources.files("grpc_tools") / "_proto"
    args = ["protoc", f"-I{root}", f"-I{well_known}", f"--python_out={out}", f"--grpc_python_out={out}",
            "hilbench/v1/delay.proto", "hilbench/v1/plant.proto"]
    if protoc.main(args) != 0:
        sys.exit(f"controller: protoc failed on {root} (set HILBENCH_PROTO_DIR to your checkout's proto/proto)")
    sys.path.insert(0, out)
    from hilbench.v1 import plant_pb2, plant_pb2_grpc
    return plant_pb2, plant_pb2_grpc


def clip(v, lo, hi):
    return max(lo, min(hi, v))


class PD:
    """The law, with the goal, model and limits of the plant's Describe."""

    def __init__(self, description):
        self.goal = list(description.goal_m)
        m, lim = description.model, description.limits
        self.g, self.drag = m.gravity_mps2, (m.drag_x_per_s, m.drag_y_per_s, m.drag_z_per_s)
        self.t_lim = (lim.min.thrust_mps2, lim.max.thrust_mps2)
        self.roll_lim = (lim.min.roll_rad, lim.max.roll_rad)
        self.pitch_lim = (lim.min.pitch_rad, lim.max.pitch_rad)
        tilt = min(abs(v) for v in self.roll_lim + self.pitch_lim)
        self.a_max = TILT_USE * self.g * math.tan(tilt)

    def command(self, x):
        px, py, pz, vx, vy, vz = x[:6]
        ax = KP * (self.goal[0] - px) - KD * vx
        ay = KP * (self.goal[1] - py) - KD * vy
        norm = math.hypot(ax, ay)
        if norm > self.a_max:
            ax, ay = ax * self.a_max / norm, ay * self.a_max / norm
        az = clip(KP_Z * (self.goal[2] - pz) - KD_Z * vz, -0.5 * self.g, 0.5 * self.g)
        # The model: v' = T (cos(phi) sin(theta), -sin(phi), cos(phi) cos(theta)) - g e_z - drag v.
        ax, ay, lift = ax + self.drag[0] * vx, ay + self.drag[1] * vy, self.g + az + self.drag[2] * vz
        pitch = clip(math.atan2(ax, lift), *self.pitch_lim)
        roll = clip(math.atan2(-ay * math.cos(pitch), lift), *self.roll_lim)
        thrust = clip(lift / (math.cos(roll) * math.cos(pitch)), *self.t_lim)
        return thrust, roll, pitch


def main():
    address = os.environ["HILBENCH_PLANT_ADDR"]
    lockstep = os.environ.get("HILBENCH_TIME_MODE", "lockstep") == "lockstep"
    out = tempfile.mkdtemp(prefix="hilbench-stubs-")

    def stop(*_):
        # The bench ends a run with SIGTERM: remove the stubs and exit at once (an interpreter
        # shutdown waits for grpc's threads, about a second and a half).
        shutil.rmtree(out, ignore_errors=True)
        os._exit(0)

    signal.signal(signal.SIGTERM, stop)
    try:
        pb, pb_grpc = stubs(out)
        plant = pb_grpc.PlantStub(grpc.insecure_channel(address))
        law = PD(plant.Describe(pb.DescribeRequest(), timeout=10))
        seq = 0

        def command(sample):
            nonlocal seq
            seq += 1
            t, roll, pitch = law.command(list(sample.state.x))
            return pb.Command(input=pb.ControlInput(thrust_mps2=t, roll_rad=roll, pitch_rad=pitch),
                              command_seq=seq, based_on_sample_seq=sample.seq,
                              based_on_sample_time_ns=sample.time_ns)

        if lockstep:
            sample = plant.GetState(pb.GetStateRequest(), timeout=10)
            while True:  # until the bench's SIGTERM
                step = pb.StepRequest(command=command(sample), duration_ns=CYCLE_NS, wait_for_command_seq=seq)
                sample = plant.Step(step, timeout=60).sample
        else:
            for sample in plant.StreamState(pb.StreamStateRequest(period_ns=CYCLE_NS)):
                plant.ApplyCommand(command(sample), timeout=5)
    except grpc.RpcError as e:
        sys.exit(f"controller: {e.code().name}: {e.details()}")
    finally:
        shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
