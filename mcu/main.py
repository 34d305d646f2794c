"""Serra kit firmware: sample, average per period, send with acks, never block, never reboot-loop.

On the board this file runs at boot. Hardware access stays in sensors.py (drivers) and in the
few lines of main() that open the watchdog, the Wi-Fi interface or the UART; host tests replace
only machine/dht/network with fakes.
"""

import gc
import sys
from time import sleep_ms, ticks_add, ticks_diff, ticks_ms

import wire
from health import Health
from link import UP, Sender, UdpPort, WifiLink
from ring import Ring
from sensors import Averager


def log_record(seq: int, avg) -> None:
    # One line per record on the console: the host tests compare it with the gateway's store.
    print("REC", seq, end="")
    for i in range(7):
        print(f" {avg.raw[i]}:{avg.status[i]}", end="")
    print()


def rssi(wlan) -> int:
    """The Wi-Fi signal in dBm, -128 when unknown (UART, or a port without it)."""
    if wlan is None:
        return -128
    try:
        return int(wlan.status("rssi"))
    except (OSError, ValueError, TypeError):
        return -128


def run(cfg, boot: int, wdt, wlan, sensors, fail: tuple = (), ring=None, port=None,
        max_loops: int = -1) -> None:
    """wlan None: no Wi-Fi (UART transport), the port is always up."""
    print("serra: device", cfg.device_id, "boot", boot)
    if ring is None:
        ring = Ring(cfg.ring_size)
    avg = Averager()
    wifi = None
    if wlan is not None:
        wifi = WifiLink(wlan, cfg.ssid, cfg.password, cfg.connect_timeout_ms, 1000, 60000, fail)
    if port is None:
        port = UdpPort(cfg.gateway_host, cfg.gateway_port)
    sender = Sender(ring, wire.Hmac(cfg.key), cfg.device_id, boot, cfg.period_ms // 100, port,
                    cfg.ack_timeout_ms)
    sample_ms = cfg.sample_ms
    period_ms = cfg.period_ms
    seq = 0
    now = ticks_ms()
    next_sample = now
    period_end = ticks_add(now, period_ms)
    last_state = -1
    loops = 0
    health = Health(now, cfg.health_ms)
    gc.collect()
    print("MEM boot", gc.mem_alloc())
    while loops != max_loops:
        loops += 1
        now = ticks_ms()
        if ticks_diff(now, next_sample) >= 0:
            avg.sample(sensors, now)
            next_sample = ticks_add(next_sample, sample_ms)
            if ticks_diff(now, next_sample) >= 0:  # fell behind: skip, do not burst
                next_sample = ticks_add(now, sample_ms)
        if ticks_diff(now, period_end) >= 0:
            avg.finish()
            wire.pack_channels(ring.push(seq, period_end), 0, avg.raw, avg.status)
            log_record(seq, avg)
            seq += 1
            period_end = ticks_add(period_end, period_ms)
            if seq % 50 == 0:
                gc.collect()
                print("MEM", gc.mem_alloc(), "ring", ring.count, "dropped", ring.dropped,
                      "sent", sender.sent, "acked", sender.acked, "errors", sender.errors)
        if wifi is None:
            sender.step(now)
        elif wifi.step(now):
            sender.step(now)
        elif wifi.state != UP:
            sender.close()
        # On a link that is up, and on a UART once the last frame has left (write() never
        # blocks then); not sent now, it stays due for a later pass.
        if (health.due_now(now, ring.dropped) and (wifi is None or wifi.state == UP)
                and sender.port.ready()):
            health.send(now, sender, seq, rssi(wlan))
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


def main() -> None:
    import config

    try:
        cfg = config.load("config.json")
    except config.ConfigError as e:
        # No reboot loop on a bad config: say what is wrong on the serial console and stop.
        print("serra: CONFIG ERROR:", e)
        return
    # The ring's channel buffer (2.7 KB for 128 records) is the one large block: allocate it
    # now, while the top of the heap is one free area; the code dropped below leaves holes.
    gc.collect()
    ring = Ring(cfg.ring_size)
    import bootcount

    try:
        boot = bootcount.next_boot(cfg.boot_file)
    except bootcount.BootCountError as e:
        print("serra: BOOT COUNTER ERROR:", e)
        return
    # Config parsing and the boot counter run once: drop their code from the heap.
    del config, bootcount
    sys.modules.pop("config")
    sys.modules.pop("bootcount")
    import machine
    import sensors

    sens = sensors.build(cfg.pins, cfg.cal)
    cfg.pins = cfg.cal = None  # needed at boot only
    # Started only once config and counter are good: a bad file must not become a reset loop.
    wdt = machine.WDT(timeout=cfg.wdt_ms)
    if cfg.transport == "uart":
        import uartport

        run(cfg, boot, wdt, None, sens, (), ring, uartport.from_config(cfg))
        return
    import network

    fail = (network.STAT_NO_AP_FOUND, network.STAT_WRONG_PASSWORD, network.STAT_CONNECT_FAIL)
    run(cfg, boot, wdt, network.WLAN(network.STA_IF), sens, fail, ring)


if __name__ == "__main__":
    main()
