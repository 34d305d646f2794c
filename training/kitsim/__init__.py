"""The simulated kit: real firmware under MicroPython, sensors fed by the reference simulator at
accelerated time (:class:`SimKit`, :class:`KitClock`, :func:`simulated_trace`). See kit.py."""

from training.kitsim.kit import KitClock, SimKit, micropython, simulated_trace, write_trace

__all__ = ["KitClock", "SimKit", "micropython", "simulated_trace", "write_trace"]
