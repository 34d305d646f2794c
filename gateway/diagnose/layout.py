"""How ``Structured.shoot`` lays out its free runs: candidates × starts (issue 10, speed).

One Python iteration per step serves every candidate (P parameter sets) from every start (N
windows). Two layouts of the state give the same numbers (every operation of a step is
element-wise, so broadcasting computes each element as the other layout does):

- rows (P·N, 1), candidate-major: the parameters repeated per start, the drivers gathered
  per row; every operation is on contiguous columns (fastest when the candidates differ in
  many parameters: a Jacobian, a swarm);
- a grid (P, N) when at most ``GRID_VARIED`` parameters differ between the candidates (a τ
  scan varies an effect's amplitude and τ): a parameter every candidate holds to the bit is
  one (1, 1) column (:func:`shared`), the drivers are gathered per start (1, N), so a term
  that reads only shared parameters is computed once per start rather than once per
  candidate.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

GRID_VARIED = 3
"""At most this many parameters differ between the candidates of a grid (an effect's
amplitude, τ and, for an added store, its time constant). Timed on the shooting calls of the
bench's twonode heater case (tests/bench/diagnose.py): 3 and 6 ran alike, a grid for every
call ran the Jacobian-sized calls (P ≈ 20, N ≈ 18, most parameters varied) ~10% slower."""


def shared(p: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The parameter columns (P, 1), each that holds the same value (to the bit) in every row
    as one (1, 1) row."""
    out = {}
    for name, v in p.items():
        bits = v.view(np.int64)
        out[name] = v[:1] if len(v) > 1 and (bits == bits[0]).all() else v
    return out


def layout(p: Mapping[str, np.ndarray], starts: np.ndarray,
           ) -> tuple[dict[str, np.ndarray], np.ndarray, tuple[int, int]]:
    """``shoot``'s layout for the parameter columns ``p`` (P, 1) and the start indices
    ``starts`` (N,): the parameters as the step reads them, the start indices (rows (P·N, 1)
    or (1, N)) and the state's shape ((P·N, 1) or (P, N))."""
    q = shared(p)
    n_p, n = len(next(iter(p.values()))), len(starts)
    if n_p > 1 and n > 1 and sum(len(v) > 1 for v in q.values()) <= GRID_VARIED:
        return q, starts[None, :], (n_p, n)
    return ({name: np.repeat(v, n, axis=0) for name, v in p.items()},
            np.tile(starts, n_p)[:, None], (n_p * n, 1))
