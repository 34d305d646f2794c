"""The board's watchdog and reset, faked for MicroPython on the host: one copy for the firmware
tests' fakes (tests/mcu_fakes) and the simulated kit's (training/kitsim/fakes), whose `machine`
modules re-export them. A reset ends the process with a status the host reads: 75 the
watchdog, 76 ``machine.reset()``.

``ticks_ms`` is whatever `time` the interpreter has: the board's clock in the firmware tests
(tests/mcu_fakes/esp32_clock), the simulated kit's scaled device clock there (its
fakes/time.py); each is first on MICROPYPATH.
"""

import sys
from time import ticks_diff, ticks_ms


class WDT:
    """Resets the 'board' (exits with status 75) if not fed in time (device time), like the
    real one."""

    def __init__(self, id=0, timeout=5000):
        self.timeout = timeout
        self.t = ticks_ms()

    def feed(self):
        now = ticks_ms()
        if ticks_diff(now, self.t) > self.timeout:
            print("FAKE WDT: not fed for", ticks_diff(now, self.t), "ms: reset")
            sys.exit(75)
        self.t = now


def reset():
    print("FAKE machine.reset()")
    sys.exit(76)
