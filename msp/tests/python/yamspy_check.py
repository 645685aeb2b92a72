"""yamspy (PyPI), an independent MSP implementation, against the msp crate's bytes.

Reads a JSON object on stdin: {"replies": "<hex>"}, a stream of flight-controller replies that
the msp crate encoded. Parses it with yamspy's own receiver (MSPy.receive_msg, the
betaflight-configurator state machine) and message processors, and prints one JSON object: what
yamspy decoded, and the requests yamspy's encoder writes (send_RAW_msg, send_RAW_RC), as hex,
for the crate's decoder to parse back.
"""

import json
import sys

from yamspy import MSPy


class Pipe:
    """Stands in for yamspy's serial port: reads from a byte string, records writes."""

    def __init__(self, data=b""):
        self.data = bytearray(data)
        self.written = bytearray()
        self.closed = False

    def read(self, n=1):
        if not self.data:
            raise EOFError
        out, self.data = bytes(self.data[:n]), self.data[n:]
        return out

    def write(self, b):
        self.written += bytes(b)
        return len(b)


def main():
    query = json.load(sys.stdin)
    board = MSPy(device="none", logfilename=None, loglevel="ERROR")
    board.INAV = False  # set by MSPy.connect from MSP_FC_VARIANT; Betaflight here
    board.conn = Pipe(bytes.fromhex(query["replies"]))
    frames = []
    while True:
        try:
            handler = board.receive_msg()
        except EOFError:
            break
        code = handler["code"]
        result = board.process_recv_data(handler)
        frames.append({"code": code, "version": handler["msp_version"], "result": result,
                       "crc_error": bool(handler["crcError"]), "unsupported": bool(handler["unsupported"])})

    decoded = {
        "api_version": board.CONFIG["apiVersion"],
        "msp_protocol": board.CONFIG["mspProtocolVersion"],
        "variant": board.CONFIG["flightControllerIdentifier"],
        "fc_version": board.CONFIG["flightControllerVersion"],
        "cycle_time": board.CONFIG["cycleTime"],
        "sensors": board.CONFIG["activeSensors"],
        "mode": board.CONFIG["mode"],
        "arming_disable_count": board.CONFIG["armingDisableCount"],
        "arming_disable_flags": board.CONFIG["armingDisableFlags"],
        "attitude": board.SENSOR_DATA["kinematics"],
        "acc": board.SENSOR_DATA["accelerometer"],
        "gyro": board.SENSOR_DATA["gyroscope"],
        "mag": board.SENSOR_DATA["magnetometer"],
        "rc": board.RC["channels"],
        "motor": board.MOTOR_DATA,
        "voltage": board.ANALOG["voltage"],
        "mah_drawn": board.ANALOG["mAhdrawn"],
        "rssi": board.ANALOG["rssi"],
        "amperage": board.ANALOG["amperage"],
        "box_names": board.AUX_CONFIG,
        "box_ids": board.AUX_CONFIG_IDS,
    }

    # yamspy's encoder: v1 requests, MSP_SET_RAW_RC, and a v2 request (command > 255).
    requests = []
    for code, data in [(MSPy.MSPCodes["MSP_API_VERSION"], []), (MSPy.MSPCodes["MSP_STATUS_EX"], []),
                       (0x3003, [1, 2, 3])]:
        board.conn = Pipe()
        board.send_RAW_msg(code, data)
        requests.append(board.conn.written.hex())
    board.conn = Pipe()
    board.send_RAW_RC([1400, 1600, 1000, 1550, 1000, 1800, 1200, 1300])
    requests.append(board.conn.written.hex())

    print(json.dumps({"frames": frames, "decoded": decoded, "requests": requests}))


if __name__ == "__main__":
    main()
