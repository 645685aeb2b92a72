"""Runs the example Python controller (examples/python-controller/controller.py) while a thread
prints bytes that are not UTF-8 to stdout and stderr every 10 ms, flushed, for as long as the
process lives: a controller that "prints what it likes" (docs/external-controller.md). A write
that fails (the bench closed the pipe) ends the process with status 41, so a bench that stops
reading a controller's output fails the run instead of passing it.

Usage: noisy_controller.py PATH/TO/controller.py
"""

import os
import runpy
import sys
import threading
import time


def noise():
    n = 0
    while True:
        try:
            sys.stdout.buffer.write(b"\xff\xfe not utf-8 \x80 %d\n" % n)
            sys.stdout.buffer.flush()
            sys.stderr.buffer.write(b"\xc3\x28 stderr %d\n" % n)
            sys.stderr.buffer.flush()
        except (BrokenPipeError, OSError):
            os._exit(41)
        n += 1
        time.sleep(0.01)


if __name__ == "__main__":
    threading.Thread(target=noise, daemon=True).start()
    controller = sys.argv[1]
    sys.argv = [controller]
    runpy.run_path(controller, run_name="__main__")
