"""Sends three invalid commands (a NaN thrust) through the Plant API, checks that each is refused
with INVALID_ARGUMENT, then flies as the example controller (its path is the argument) does.
The bench must count the three refusals (summary.json's external_controller.commands_refused).

Usage: invalid_first_controller.py PATH/TO/controller.py [--then-exit]
(--then-exit: exit 5 after the three refusals instead of flying, as a controller that gives up.)
"""

import importlib.util
import math
import os
import shutil
import sys
import tempfile

import grpc


def main(path, then_exit=False):
    spec = importlib.util.spec_from_file_location("pd_controller", path)
    pd = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pd)
    out = tempfile.mkdtemp(prefix="hilbench-stubs-")
    try:
        pb, pb_grpc = pd.stubs(out)
        plant = pb_grpc.PlantStub(grpc.insecure_channel(os.environ["HILBENCH_PLANT_ADDR"]))
        for k in range(3):
            bad = pb.Command(input=pb.ControlInput(thrust_mps2=math.nan, roll_rad=0.0, pitch_rad=0.0),
                             command_seq=1000 + k)
            try:
                plant.ApplyCommand(bad, timeout=10)
            except grpc.RpcError as e:
                if e.code() != grpc.StatusCode.INVALID_ARGUMENT:
                    sys.exit(f"invalid command {k}: {e.code().name}: {e.details()}")
                print(f"invalid command {k} refused: {e.details()}", file=sys.stderr)
            else:
                sys.exit(f"invalid command {k} was accepted")
    finally:
        shutil.rmtree(out, ignore_errors=True)
    if then_exit:
        sys.exit(5)
    pd.main()


if __name__ == "__main__":
    main(sys.argv[1], then_exit=sys.argv[2:] == ["--then-exit"])
