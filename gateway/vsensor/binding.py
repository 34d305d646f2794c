"""The sensor's one-row ``session.run`` through an onnxruntime IOBinding, bound once.

    run = BoundRun(session, histories=1)
    out = run(u, y_past)      # (1, n_out) float32: the graph's first output for this step

The graph's inputs ``u`` (1, lags, F) and ``y_past`` ((1, 5) or (1, K, 5)) are bound to the
caller's numpy arrays, which onnxruntime reads in place (no copy) when they are C-contiguous
float32 (``CreateTensor`` in onnxruntime's ``onnxruntime_pybind_mlvalue.cc`` wraps the array's
buffer; a non-contiguous array would be bound as a private contiguous copy, which is why
:meth:`BoundRun.bind` refuses one). So in-place updates of the bound arrays are seen by the next
call; an array *replaced* by a new object (``VentSensor.reset``/``restore``) is noticed by
identity and bound afresh. The output is written into one preallocated buffer, overwritten by the
next call. Same kernels on the same bytes as ``session.run``: bit-identical outputs
(tests/test_vsensor_binding.py); the time saved per step is measured side by side in
tests/bench/vsensor.py.
"""

from __future__ import annotations

import numpy as np


class BoundRun:
    """``session.run([output], {"u": u, "y_past": y_past})[0]`` through an IOBinding, ``output``
    the graph's first."""

    def __init__(self, session, histories: int) -> None:
        """``session``: an onnxruntime InferenceSession on the CPU; ``histories``: the output's
        width for one row when the graph leaves it symbolic (its declared width otherwise)."""
        self.session = session
        self.io = session.io_binding()
        out = session.get_outputs()[0]
        shape = out.shape
        n_out = shape[-1] if len(shape) == 2 and isinstance(shape[-1], int) else histories
        self.out = np.zeros((1, n_out), dtype=np.float32)
        self.io.bind_output(out.name, "cpu", 0, np.float32, [1, n_out], self.out.ctypes.data)
        self._u: np.ndarray | None = None
        self._y: np.ndarray | None = None

    def bind(self, u: np.ndarray, y_past: np.ndarray) -> None:
        """Bind the graph inputs to these arrays (read in place by every later run)."""
        for name, arr in (("u", u), ("y_past", y_past)):
            if arr.dtype != np.float32 or not arr.flags.c_contiguous:
                raise ValueError(f"{name}: a C-contiguous float32 array is bound in place, "
                                 f"got {arr.dtype} (contiguous {arr.flags.c_contiguous})")
        self.io.bind_cpu_input("u", u)
        self.io.bind_cpu_input("y_past", y_past)
        self._u, self._y = u, y_past  # held: the binding points into their buffers

    def __call__(self, u: np.ndarray, y_past: np.ndarray) -> np.ndarray:
        """The graph's output (1, n_out) for the current contents of ``u`` and ``y_past``
        (re-bound first when either is another array object than the one bound)."""
        if u is not self._u or y_past is not self._y:
            self.bind(u, y_past)
        self.session.run_with_iobinding(self.io)
        return self.out
