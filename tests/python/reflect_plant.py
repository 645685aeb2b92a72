"""An independent client of the Plant API: Python grpcio with nothing compiled from our .proto
files. It learns the services and messages from the server's reflection service, then flies a
lockstep plant: reset to a scenario, hover for a second through Step, read the state back, and
checks that a bad command is refused naming its field while the plant's time stays where it was.

Usage: reflect_plant.py HOST:PORT SCENARIO   (prints one JSON line on success)
"""

import json
import math
import sys

import grpc
from google.protobuf import descriptor_pool, message_factory
from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc
from grpc_reflection.v1alpha.proto_reflection_descriptor_database import (
    ProtoReflectionDescriptorDatabase,
)


def fail(message):
    print(f"reflect_plant: {message}", file=sys.stderr)
    sys.exit(1)


def listed_services(channel):
    stub = reflection_pb2_grpc.ServerReflectionStub(channel)
    request = reflection_pb2.ServerReflectionRequest(list_services="")
    for response in stub.ServerReflectionInfo(iter([request])):
        return sorted(s.name for s in response.list_services_response.service)
    return []


class Client:
    """Unary calls of one service, typed by the descriptors reflection gave."""

    def __init__(self, channel, pool, service):
        self.channel = channel
        self.service = pool.FindServiceByName(service)

    def message(self, method, **fields):
        m = self.service.FindMethodByName(method)
        return message_factory.GetMessageClass(m.input_type)(**fields)

    def call(self, method, request):
        m = self.service.FindMethodByName(method)
        output = message_factory.GetMessageClass(m.output_type)
        rpc = self.channel.unary_unary(
            f"/{self.service.full_name}/{method}",
            request_serializer=lambda r: r.SerializeToString(),
            response_deserializer=output.FromString,
        )
        return rpc(request, timeout=10)


def main():
    address, scenario = sys.argv[1], sys.argv[2]
    channel = grpc.insecure_channel(address)
    services = listed_services(channel)
    for expected in ["grpc.health.v1.Health", "hilbench.v1.Plant"]:
        if expected not in services:
            fail(f"reflection lists {services}, not {expected}")
    pool = descriptor_pool.DescriptorPool(ProtoReflectionDescriptorDatabase(channel))
    plant = Client(channel, pool, "hilbench.v1.Plant")

    reset = plant.call("Reset", plant.message("Reset", scenario=scenario))
    description = reset.description
    if description.scenario != scenario:
        fail(f"reset to {scenario} describes {description.scenario}")
    if description.time_mode != 2:  # TIME_MODE_LOCKSTEP
        fail(f"time mode {description.time_mode}, expected lockstep")
    start = list(reset.sample.state.x)
    gravity = description.model.gravity_mps2

    command_class = message_factory.GetMessageClass(pool.FindMessageTypeByName("hilbench.v1.Command"))

    # Hover for 1 s in 20 steps of 50 ms.
    seq = 0
    sample = reset.sample
    for _ in range(20):
        seq += 1
        command = command_class(
            input={"thrust_mps2": gravity, "roll_rad": 0.0, "pitch_rad": 0.0},
            command_seq=seq,
            based_on_sample_seq=sample.seq,
            based_on_sample_time_ns=sample.time_ns,
        )
        sample = plant.call("Step", plant.message("Step", command=command, duration_ns=50_000_000)).sample
    if sample.time_ns != reset.sample.time_ns + 1_000_000_000:
        fail(f"plant time {sample.time_ns} ns after 1 s of steps from {reset.sample.time_ns}")
    if sample.last_command.command_seq != seq:
        fail(f"last command {sample.last_command.command_seq}, sent {seq}")
    drift_m = math.dist(start[:3], list(sample.state.x)[:3])

    # A NaN thrust is refused, naming the field, and time does not move.
    bad = plant.message("ApplyCommand", input={"thrust_mps2": float("nan")}, command_seq=seq + 1)
    try:
        plant.call("ApplyCommand", bad)
        fail("a NaN thrust was accepted")
    except grpc.RpcError as e:
        if e.code() != grpc.StatusCode.INVALID_ARGUMENT or "thrust" not in e.details():
            fail(f"a NaN thrust gave {e.code()} {e.details()!r}")
        refusal = e.details()
    after = plant.call("GetState", plant.message("GetState"))
    if after.time_ns != sample.time_ns or after.last_command.command_seq != seq:
        fail("the refused command changed the plant")

    print(json.dumps({
        "services": services,
        "time_ns": sample.time_ns,
        "hover_drift_m": drift_m,
        "refusal": refusal,
    }))


if __name__ == "__main__":
    main()
