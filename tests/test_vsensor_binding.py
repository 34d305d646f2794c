"""The sensor's graph run through an onnxruntime IOBinding (gateway/vsensor/binding.py): the same
bits as ``session.run``, step by step, after a restore, and with the bound arrays updated in place."""

from __future__ import annotations

import json

import numpy as np
import onnxruntime as ort
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.vsensor import VentSensor
from gateway.vsensor.binding import BoundRun
from gateway.vsensor.features import feature_names
from gateway.vsensor.models import shipped_model
from tests import vsensor_data as vd

MODELS = ("tiny", "tiny-own-feedback", "shipped")


@pytest.fixture(scope="module")
def gh():
    return load_greenhouse(vd.GREENHOUSE)


@pytest.fixture(scope="module")
def novent(gh):
    return vd.novent_run(gh)


def _model(which: str):
    if which == "tiny":
        return vd.tiny_model()
    if which == "tiny-own-feedback":  # K = 2 output histories: y_past (1, 2, 5), not a view
        return vd.tiny_model("own-feedback", ensemble=2, own_feedback=True)
    return shipped_model("almeria")


def _rows(novent, lo: int, hi: int):
    names = feature_names("almeria")[3:]
    for t in range(lo, hi):
        yield ({k: float(v[t]) for k, v in novent.x.items()},
               {k: float(novent.fluxes[k][t]) for k in names})


def _bits(values) -> bytes:
    return np.asarray(values, dtype=np.float64).tobytes()


def _recording(sensor: VentSensor) -> list:
    """Wrap the sensor's graph call: every step's (u, y_past, output), copied."""
    log, run = [], sensor._run

    def spy(u, y_past):
        out = run(u, y_past)
        log.append((u.copy(), y_past.copy(), out.copy()))
        return out

    sensor._run = spy
    return log


@pytest.mark.parametrize("which", MODELS)
def test_bound_steps_are_bit_identical_to_session_run(gh, novent, which):
    """A 600-minute replay: the bound sensor's flows, heat fluxes and history are the plain
    sensor's bit for bit, and every bound output is a fresh session's run of that step's inputs
    (so each step's in-place update of u and y_past was read)."""
    path = _model(which)
    bound, plain = VentSensor(path, gh, "almeria"), VentSensor(path, gh, "almeria", io_binding=False)
    assert isinstance(bound._run, BoundRun) and not isinstance(plain._run, BoundRun)
    log = _recording(bound)
    a = [bound.step(m, q) for m, q in _rows(novent, 0, 600)]
    b = [plain.step(m, q) for m, q in _rows(novent, 0, 600)]
    assert _bits([e.flow for e in a]) == _bits([e.flow for e in b])
    assert _bits([e.q_vent for e in a]) == _bits([e.q_vent for e in b])
    assert [e.valid for e in a] == [e.valid for e in b]
    assert json.dumps(bound.snapshot()) == json.dumps(plain.snapshot())
    fresh = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for u, y_past, out in log:
        assert fresh.run(None, {"u": u, "y_past": y_past})[0].tobytes() == out.tobytes()
    outs = np.array([out[0, 0] for _, _, out in log])
    assert len(log) == 600 and np.count_nonzero(np.diff(outs)) > 300  # the inputs moved


@pytest.mark.parametrize("which", MODELS[:2])
def test_restore_and_reset_rebind_the_replaced_arrays(gh, novent, which):
    """A bound sensor that has stepped (its binding on its first arrays) and then restores a
    snapshot steps bit-identically to the uninterrupted run; after reset, to a fresh sensor."""
    path = _model(which)
    first = VentSensor(path, gh, "almeria")
    for m, q in _rows(novent, 0, 120):
        first.step(m, q)
    saved = json.loads(json.dumps(first.snapshot()))
    again = VentSensor(path, gh, "almeria")
    for m, q in _rows(novent, 300, 330):  # bound, and a history unlike the saved one
        again.step(m, q)
    old_u = again._u
    again.restore(saved)
    assert again._u is not old_u  # restore replaces the arrays: the binding must follow
    a = [first.step(m, q).flow for m, q in _rows(novent, 120, 240)]
    b = [again.step(m, q).flow for m, q in _rows(novent, 120, 240)]
    assert _bits(a) == _bits(b)
    again.reset()
    fresh = VentSensor(path, gh, "almeria", io_binding=False)
    c = [again.step(m, q).flow for m, q in _rows(novent, 0, 60)]
    d = [fresh.step(m, q).flow for m, q in _rows(novent, 0, 60)]
    assert _bits(c) == _bits(d)
    assert _bits(a[:60]) != _bits(d)  # the history matters, so the checks above can fail


def test_in_place_updates_and_new_arrays_are_seen(gh):
    """Two different consecutive inputs in the same bound arrays give two outputs, each the one
    session.run gives (a stale binding would repeat the first); a new array object is bound
    afresh; an array onnxruntime would copy (not C-contiguous) is refused."""
    path = vd.tiny_model()
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    n_f = sess.get_inputs()[0].shape[-1]
    rng = np.random.default_rng(3)
    u = rng.normal(size=(1, 6, n_f)).astype(np.float32)
    y = np.full((1, 5), 2.0, dtype=np.float32)
    run = BoundRun(sess, histories=1)

    def plain(u_, y_):
        return sess.run(None, {"u": u_, "y_past": y_})[0].tobytes()

    first = run(u, y).copy()
    assert first.tobytes() == plain(u, y)
    u[0, 0] += 1.0  # in place, as VentSensor.step shifts its delays
    y[0, 1:] = y[0, :-1].copy()
    y[0, 0] = 7.0
    second = run(u, y).copy()
    assert second.tobytes() == plain(u, y) and second.tobytes() != first.tobytes()
    u2 = rng.normal(size=u.shape).astype(np.float32)  # another object: re-bound by identity
    third = run(u2, y).copy()
    assert third.tobytes() == plain(u2, y) and third.tobytes() != second.tobytes()
    strided = np.zeros((1, 6, 2 * n_f), dtype=np.float32)[:, :, ::2]
    with pytest.raises(ValueError, match="C-contiguous"):
        run(strided, y)
    with pytest.raises(ValueError, match="float32"):
        run(u2.astype(np.float64), y)
