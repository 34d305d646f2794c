"""Fake `network` for the simulated kit: the access point is always there (the UDP is real)."""

STA_IF = 0
STAT_CONNECTING = 1001
STAT_GOT_IP = 1010
STAT_NO_AP_FOUND = 201
STAT_WRONG_PASSWORD = 202
STAT_CONNECT_FAIL = 203


class WLAN:
    def __init__(self, interface=STA_IF):
        self._active = False
        self._ok = False

    def active(self, a=None):
        if a is None:
            return self._active
        self._active = a
        return None

    def connect(self, ssid=None, key=None):
        self._ok = True

    def disconnect(self):
        self._ok = False

    def isconnected(self):
        return self._ok

    def status(self, *a):
        return STAT_GOT_IP if self._ok else STAT_CONNECTING
