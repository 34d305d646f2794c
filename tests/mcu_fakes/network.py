"""Fake `network`: a station interface whose connection attempts follow $SERRA_WIFI, e.g.
"fail,fail,ok" (the last outcome repeats), and $SERRA_WIFI_OUTAGE="START_MS:LENGTH_MS" takes the
access point away for a while (from the interpreter's start). The UDP traffic itself is real,
on 127.0.0.1."""

import os
from time import ticks_diff, ticks_ms

STA_IF = 0
STAT_CONNECTING = 1001
STAT_GOT_IP = 1010
STAT_NO_AP_FOUND = 201
STAT_WRONG_PASSWORD = 202
STAT_CONNECT_FAIL = 203

CONNECT_DELAY_MS = 50
RSSI_DBM = -61
_T0 = ticks_ms()


def _outage():
    spec = os.getenv("SERRA_WIFI_OUTAGE")
    if not spec:
        return False
    start, length = spec.split(":")
    dt = ticks_diff(ticks_ms(), _T0)
    return int(start) <= dt < int(start) + int(length)


class WLAN:
    def __init__(self, interface=STA_IF):
        plan = os.getenv("SERRA_WIFI") or "ok"
        self._plan = plan.split(",")
        self._attempt = 0
        self._active = False
        self._ok = False
        self._t = 0
        self.connects = 0

    def active(self, a=None):
        if a is None:
            return self._active
        self._active = a
        return None

    def connect(self, ssid=None, key=None):
        if not self._active:
            raise OSError("wifi not active")
        outcome = self._plan[min(self._attempt, len(self._plan) - 1)]
        self._attempt += 1
        self.connects += 1
        self._ok = outcome == "ok" and not _outage()
        self._t = ticks_ms()
        print("FAKE wifi connect attempt", self._attempt, outcome)

    def disconnect(self):
        self._ok = False

    def isconnected(self):
        if self._ok and _outage():
            self._ok = False  # the access point went away
        return self._ok and ticks_diff(ticks_ms(), self._t) >= CONNECT_DELAY_MS

    def status(self, *a):
        if a == ("rssi",):  # the ESP32 port's signal strength [dBm]
            if not self.isconnected():
                raise OSError("not connected")
            return RSSI_DBM
        if self.isconnected():
            return STAT_GOT_IP
        return STAT_CONNECTING if self._ok else STAT_NO_AP_FOUND
