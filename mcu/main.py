"""Serra kit firmware: sample, average per period, send with acks, never block, never reboot-loop.

On the board this file runs at boot. Hardware access stays in the drivers and in build_sensors();
host tests replace only machine/dht/network with fakes.
"""

import gc
import sys
from time import sleep_ms, ticks_add, ticks_diff, ticks_ms

import status
import wire
from link import UP, Sender, UdpPort, WifiLink
from record import Averager
from ring import Ring

T_IN, RH_IN, T_OUT, RH_OUT, I_GLOB, WIND, RAIN = 0, 1, 2, 3, 4, 5, 6


def build_sensors(cfg):
    """Return (dht_in, dht_out, pyranometer, anemometer, rain); None when not fitted."""
    import dht
    import machine
    from drivers.anemometer import Anemometer
    from drivers.dht22 import DHT22
    from drivers.pyranometer import Pyranometer
    from drivers.rain import RainDetector

    p, cal = cfg.pins, cfg.cal

    def adc(n):
        a = machine.ADC(machine.Pin(n))
        a.atten(machine.ADC.ATTN_11DB)  # 0..3.1 V input range
        return a

    return (
        DHT22(machine.Pin(p["dht_in"]), dht.DHT22) if p["dht_in"] is not None else None,
        DHT22(machine.Pin(p["dht_out"]), dht.DHT22) if p["dht_out"] is not None else None,
        Pyranometer(adc(p["pyranometer"]), cal["pyr_dark_counts"], cal["pyr_w_per_count"])
        if p["pyranometer"] is not None else None,
        Anemometer(adc(p["anemometer"]), cal["wind_mps_per_volt"], cal["wind_dead_band_v"])
        if p["anemometer"] is not None else None,
        RainDetector(machine.Pin(p["rain"], machine.Pin.IN), cal["rain_active_low"])
        if p["rain"] is not None else None,
    )


def sample(sensors, avg, now) -> None:
    dht_in, dht_out, pyr, anem, rain = sensors
    for drv, ct, ch in ((dht_in, T_IN, RH_IN), (dht_out, T_OUT, RH_OUT)):
        if drv is None:
            avg.fail(ct, status.NO_SENSOR)
            avg.fail(ch, status.NO_SENSOR)
        elif drv.read(now) == status.OK:
            avg.add(ct, drv.temperature)
            avg.add(ch, drv.humidity)
        else:
            avg.fail(ct, drv.status)
            avg.fail(ch, drv.status)
    for drv, c in ((pyr, I_GLOB), (anem, WIND), (rain, RAIN)):
        if drv is None:
            avg.fail(c, status.NO_SENSOR)
        elif drv.read() == status.OK:
            avg.add(c, drv.value)
        else:
            avg.fail(c, drv.status)


def log_record(seq: int, avg) -> None:
    # One line per record on the console: the host tests compare it with the gateway's store.
    print("REC", seq, " ".join(f"{avg.raw[i]}:{avg.status[i]}" for i in range(7)))


def run(cfg, boot: int, wdt, wlan, sensors, fail_status: tuple = (), ring=None, port=None,
        max_loops: int = -1) -> None:
    """wlan None: no Wi-Fi (UART transport), the port is always up."""
    print("serra: device", cfg.device_id, "boot", boot)
    mac = wire.Hmac(cfg.key)
    if ring is None:
        ring = Ring(cfg.ring_size)
    avg = Averager()
    wifi = None
    if wlan is not None:
        wifi = WifiLink(wlan, cfg.ssid, cfg.password, cfg.connect_timeout_ms,
                        fail_status=fail_status)
    if port is None:
        port = UdpPort(cfg.gateway_host, cfg.gateway_port)
    sender = Sender(ring, mac, cfg.device_id, boot, port, cfg.ack_timeout_ms)
    period_ds = cfg.period_ms // 100
    seq = 0
    now = ticks_ms()
    next_sample = now
    period_end = ticks_add(now, cfg.period_ms)
    last_state = -1
    loops = 0
    gc.collect()
    print("MEM boot", gc.mem_alloc())
    while loops != max_loops:
        loops += 1
        now = ticks_ms()
        if ticks_diff(now, next_sample) >= 0:
            sample(sensors, avg, now)
            next_sample = ticks_add(next_sample, cfg.sample_ms)
            if ticks_diff(now, next_sample) >= 0:  # fell behind: skip, do not burst
                next_sample = ticks_add(now, cfg.sample_ms)
        if ticks_diff(now, period_end) >= 0:
            avg.finish()
            buf = ring.push(seq, period_end)
            wire.pack_record(buf, cfg.device_id, boot, seq, period_end, period_ds, avg.raw,
                             avg.status)
            log_record(seq, avg)
            seq += 1
            period_end = ticks_add(period_end, cfg.period_ms)
            if seq % 50 == 0:
                gc.collect()
                print("MEM", gc.mem_alloc(), "ring", ring.count, "dropped", ring.dropped,
                      "sent", sender.sent, "acked", sender.acked)
        if wifi is None:
            sender.step(now)
        elif wifi.step(now):
            sender.step(now)
        elif wifi.state != UP:
            sender.close()
        if wifi is not None and wifi.state != last_state:
            last_state = wifi.state
            print("serra: wifi", ("down", "connecting", "up", "backoff")[last_state])
        wdt.feed()
        # Sleep until the next event, but wake often enough to catch acks.
        wait = ticks_diff(next_sample, ticks_ms())
        if wait > 10:
            wait = 10
        if wait > 0:
            sleep_ms(wait)


def _unload(name: str) -> None:
    # Config parsing and the boot counter run once: drop their bytecode from the heap.
    if name in sys.modules:
        del sys.modules[name]


def main() -> None:
    import config

    try:
        cfg = config.load("config.json")
    except config.ConfigError as e:
        # No reboot loop on a bad config: say what is wrong on the serial console and stop.
        print("serra: CONFIG ERROR:", e)
        return
    from bootcount import BootCountError, next_boot

    try:
        boot = next_boot(cfg.boot_file)
    except BootCountError as e:
        print("serra: BOOT COUNTER ERROR:", e)
        return
    del config, BootCountError, next_boot
    _unload("config")
    _unload("bootcount")
    # The ring is the one large buffer (8 KB for 128 records): allocate it while the heap is
    # still unfragmented.
    gc.collect()
    ring = Ring(cfg.ring_size)
    import machine

    # Started only once config and counter are good: a bad file must not become a reset loop.
    wdt = machine.WDT(timeout=cfg.wdt_ms)
    if cfg.transport == "uart":
        from uartport import UartPort

        if cfg.uart_tx >= 0 and cfg.uart_rx >= 0:
            uart = machine.UART(cfg.uart_id, baudrate=cfg.uart_baud, tx=cfg.uart_tx,
                                rx=cfg.uart_rx)
        else:
            uart = machine.UART(cfg.uart_id, baudrate=cfg.uart_baud)
        run(cfg, boot, wdt, None, build_sensors(cfg), (), ring, UartPort(uart))
        return
    import network

    fail = (network.STAT_NO_AP_FOUND, network.STAT_WRONG_PASSWORD, network.STAT_CONNECT_FAIL)
    run(cfg, boot, wdt, network.WLAN(network.STA_IF), build_sensors(cfg), fail, ring)


if __name__ == "__main__":
    main()
