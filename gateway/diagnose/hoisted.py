"""The state-independent part of a structured run's steps, computed a chunk of steps at a time.

A free run (``Structured.shoot``, ``Structured.free_run``) takes one Python iteration per
step, and at the few hundred rows of most of a diagnosis's runs each numpy operation there
costs about as much as its call. The terms that do not read the state
(``FluxTerm.state_dependent`` False) and the sensor terms give the same coefficients and
offsets whatever the run does, so ``Structured._steps`` evaluates them for a chunk of steps at
once, as blocks (steps, ...), and a step only indexes them. The numbers are the ones each step
computed: the same element-wise operations on the same values, added in the terms' order (the
leading state-independent terms are added up as a block, in that order; after a
state-dependent term each is added at its step).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.diagnose.recomputed import Same
from gateway.model.terms import FluxTerm, Index

Columns = np.ndarray | Same | None
"""A block's value at step k of the chunk ``v[k]`` (as the state broadcasts it), or None where
it is a float zero (it adds nothing: ``add``)."""


def add(total: np.ndarray | float, v: np.ndarray | float) -> np.ndarray | float:
    """``total + v`` of a sum of coefficients, where a float 0.0 on either side adds nothing
    and costs no array operation: the same numbers (x + 0 = x; only a zero's sign could
    differ, and neither sum is divided by)."""
    if isinstance(v, float) and v == 0.0:
        return total
    if isinstance(total, float) and total == 0.0:
        return v
    return total + v


def columns(v: np.ndarray | float) -> Columns:
    """A value of the block as per-step values: one that varies in time is (steps, ...), its
    step k ``v[k]``; one constant in time (a parameter's column, a scalar) is the same at
    every step."""
    if isinstance(v, float) and v == 0.0:
        return None
    v = np.asarray(v)
    return v if v.ndim == 3 else Same(v)


@dataclass(frozen=True)
class Plan:
    """The terms' coefficient sums of a run: ``head`` the (g, s) columns of the leading
    state-independent terms added up, ``rest`` the other terms in order, each either a
    state-dependent term (evaluated at its step) or a state-independent one's (g, s) columns."""

    head: tuple[Columns, Columns]
    rest: tuple[tuple[FluxTerm | None, Columns, Columns], ...]

    def sums(self, k: int, q: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray],
             ta: np.ndarray, t: Index) -> tuple[np.ndarray | float, np.ndarray | float]:
        """(Σg, Σs) of all terms at the run's step ``k`` (time index ``t``, parameters ``q``
        and drivers ``x`` in force there) for the state ``ta``."""
        g0, s0 = self.head
        g_sum: np.ndarray | float = 0.0 if g0 is None else g0[k]
        s_sum: np.ndarray | float = 0.0 if s0 is None else s0[k]
        for term, gc, sc in self.rest:
            if term is not None:
                g, s = term.coefficients(q, x, ta, t)
                g_sum, s_sum = add(g_sum, g), add(s_sum, s)
                continue
            if gc is not None:
                g_sum = add(g_sum, gc[k])
            if sc is not None:
                s_sum = add(s_sum, sc[k])
        return g_sum, s_sum


NO_STATE = np.full((0, 0, 0, 0), np.nan)
"""The state handed to a state-independent term's ``coefficients`` (it must not read it: an
operation with it fails to broadcast, or gives nothing)."""


def plan(terms: Sequence[FluxTerm], q: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray],
         t: np.ndarray) -> Plan:
    """The :class:`Plan` of a chunk of a run's steps from the parameters ``q`` and drivers
    ``x`` in force at their time indices ``t`` (steps, ...: step k's indices ``t[k]`` have the
    run's state's shape or broadcast to it)."""
    g_head: np.ndarray | float = 0.0
    s_head: np.ndarray | float = 0.0
    i = 0
    while i < len(terms) and not terms[i].state_dependent:
        g, s = terms[i].coefficients(q, x, NO_STATE, t)
        g_head, s_head = add(g_head, g), add(s_head, s)
        i += 1
    rest: list[tuple[FluxTerm | None, Columns, Columns]] = []
    for term in terms[i:]:
        if term.state_dependent:
            rest.append((term, None, None))
        else:
            g, s = term.coefficients(q, x, NO_STATE, t)
            rest.append((None, columns(g), columns(s)))
    return Plan((columns(g_head), columns(s_head)), tuple(rest))


def unplanned(terms: Sequence[FluxTerm]) -> Plan:
    """A plan that evaluates every term at its step (a step outside a run: ``one_step``)."""
    return Plan((None, None), tuple((term, None, None) for term in terms))
