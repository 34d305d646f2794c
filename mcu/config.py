"""Device configuration (config.json), validated at boot with an error naming the bad field."""

import binascii
import json

from micropython import const

_MAX_PERIOD_S = const(6553)  # the wire format carries the period in 0.1 s units (uint16)


class ConfigError(Exception):
    pass


class Config:
    """Plain attributes, all set by parse(); see config.example.json for every field."""

    device_id: int
    key: bytes
    transport: str  # "udp" (Wi-Fi) or "uart": a board wired to the gateway's USB port
    ssid: str
    password: str
    connect_timeout_ms: int
    gateway_host: str
    gateway_port: int
    uart_id: int
    uart_baud: int
    uart_tx: int  # -1: the board's default pins
    uart_rx: int
    sample_ms: int
    period_ms: int
    ack_timeout_ms: int
    ring_size: int
    health_ms: int  # between health packets (docs/wire-format.md, "Health packet")
    wdt_ms: int
    boot_file: str
    pins: dict | None  # set to None once the drivers are built
    cal: dict | None


def _get(d: dict, path: str, kind, default=None, lo=None, hi=None, where: str = ""):
    cur = d
    for part in path.split("."):
        if not isinstance(cur, dict) or part not in cur:
            if default is not None:
                return default
            raise ConfigError(f"{where}: missing field '{path}'")
        cur = cur[part]
    if kind is float and isinstance(cur, int) and not isinstance(cur, bool):
        cur = float(cur)
    if not isinstance(cur, kind) or isinstance(cur, bool) and kind is not bool:
        raise ConfigError(f"{where}: field '{path}' must be {kind.__name__}, got {cur!r}")
    if lo is not None and cur < lo or hi is not None and cur > hi:
        raise ConfigError(f"{where}: field '{path}' = {cur!r} outside [{lo}, {hi}]")
    return cur


_PIN_NAMES = const(("dht_in", "dht_out", "pyranometer", "anemometer", "rain"))
_CAL_DEFAULTS = const((
    ("pyr_dark_counts", 0),
    ("pyr_w_per_count", 0.0305),
    ("wind_mps_per_volt", 20.0),
    ("wind_dead_band_v", 0.03),
    ("rain_active_low", True),
))


def parse(d, where: str = "config") -> Config:
    if not isinstance(d, dict):
        raise ConfigError(f"{where}: top level must be a JSON object")
    c = Config()
    c.device_id = _get(d, "device_id", int, lo=0, hi=0xFFFFFFFF, where=where)
    key_hex = _get(d, "key", str, where=where)
    try:
        c.key = binascii.unhexlify(key_hex)
    except ValueError:
        raise ConfigError(f"{where}: field 'key' is not hexadecimal") from None
    if not 16 <= len(c.key) <= 64:
        raise ConfigError(f"{where}: field 'key' has {len(c.key)} bytes, expected 16..64")
    c.transport = _get(d, "transport", str, "udp", where=where)
    c.ssid = c.password = c.gateway_host = ""
    c.connect_timeout_ms = 15000
    c.gateway_port = 0
    c.uart_id, c.uart_baud, c.uart_tx, c.uart_rx = 1, 115200, -1, -1
    if c.transport == "udp":
        c.ssid = _get(d, "wifi.ssid", str, where=where)
        c.password = _get(d, "wifi.password", str, where=where)
        c.connect_timeout_ms = _get(d, "wifi.connect_timeout_ms", int, 15000, lo=1000,
                                    hi=120000, where=where)
        c.gateway_host = _get(d, "gateway.host", str, where=where)
        c.gateway_port = _get(d, "gateway.port", int, lo=1, hi=65535, where=where)
    elif c.transport == "uart":
        c.uart_id = _get(d, "uart.id", int, 1, lo=0, hi=9, where=where)
        c.uart_baud = _get(d, "uart.baudrate", int, 115200, lo=1200, hi=4000000, where=where)
        c.uart_tx = _get(d, "uart.tx", int, -1, lo=-1, hi=64, where=where)
        c.uart_rx = _get(d, "uart.rx", int, -1, lo=-1, hi=64, where=where)
    else:
        raise ConfigError(f"{where}: field 'transport' must be \"udp\" or \"uart\", "
                          f"got {c.transport!r}")
    c.sample_ms = _get(d, "sample_ms", int, 2000, lo=20, hi=600000, where=where)
    period_s = _get(d, "period_s", float, 60.0, lo=0.1, hi=_MAX_PERIOD_S, where=where)
    c.period_ms = int(period_s * 1000)
    if c.sample_ms > c.period_ms:
        raise ConfigError(f"{where}: sample_ms {c.sample_ms} longer than period_s {period_s}")
    c.ack_timeout_ms = _get(d, "ack_timeout_ms", int, 3000, lo=50, hi=600000, where=where)
    c.ring_size = _get(d, "ring_size", int, 128, lo=120, hi=1024, where=where)
    c.health_ms = _get(d, "health_s", int, 3600, lo=1, hi=86400, where=where) * 1000
    c.wdt_ms = _get(d, "wdt_ms", int, 30000, lo=2000, hi=3600000, where=where)
    c.boot_file = _get(d, "boot_file", str, "boot.cnt", where=where)
    pins = d.get("pins", {})
    if not isinstance(pins, dict):
        raise ConfigError(f"{where}: field 'pins' must be an object")
    c.pins = {}
    for name in _PIN_NAMES:
        v = pins.get(name)
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 0):
            raise ConfigError(f"{where}: field 'pins.{name}' must be a GPIO number or null")
        c.pins[name] = v
    for name in pins:
        if name not in _PIN_NAMES:
            raise ConfigError(f"{where}: unknown field 'pins.{name}'")
    cal = d.get("calibration", {})
    if not isinstance(cal, dict):
        raise ConfigError(f"{where}: field 'calibration' must be an object")
    c.cal = {}
    for name, dflt in _CAL_DEFAULTS:
        c.cal[name] = _get(cal, name, type(dflt), dflt, where=where + " calibration")
    for name in cal:
        if name not in c.cal:
            raise ConfigError(f"{where}: unknown field 'calibration.{name}'")
    return c


def load(path: str = "config.json") -> Config:
    try:
        with open(path) as f:
            text = f.read()
    except OSError:
        raise ConfigError(f"{path}: cannot read the file") from None
    try:
        d = json.loads(text)
    except ValueError:
        raise ConfigError(f"{path}: not valid JSON") from None
    return parse(d, path)
