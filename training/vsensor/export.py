"""One ONNX graph per network: standardisation, projection (PCA), layers, output scaling.

Built with ``onnx.helper`` from the numpy weights (standard operators only; opset 17, IR 8, so
onnxruntime ≥ 1.17 loads it). Inputs ``u`` float32 (N, 6, F): the filtered inputs at k - d,
d = 0..5; ``y_past`` float32 (N, 5): the sensor's outputs at k - 1 … k - 5. Output ``flow``
float32 (N, 1) [m3 s-1], unclamped (the runtime clamps to the physical range). An ensemble's
members share the pre-processing; an ONNX ``Mean`` averages their outputs. A network trained on
a transformed flow (√G, log(1 + G): ``Narx.target``) has the transform on ``y_past`` and its
inverse on the output in the graph, so the interface stays flows in, flow out. An ensemble whose
members each hear their own past (``Narx.own_feedback``) takes ``y_past`` (N, K, 5) and gives
``flow`` (N, K), one flow per member: the runtime clips each and averages them. A network on
the effective opening (``Narx.target`` "opening", eighth pass) computes the ventilation driver
D = max(sqrt(b |ΔT| + w u²), floor) from ``u``'s wind and T_in − T_out at every delay
(``narx.Driver``, constants from the model layer), divides the past flows by D(k−1 … k−5) and
multiplies its output by D(k). A mixed ensemble (``narx.MixedNarx``, ninth pass) shares the
standardisation, PCA and D; each member has its own output scaling and target (an opening
member as above) and the members' flows are averaged (``Mean``), or given apart (own feedback).

``metadata_props`` carry everything the runtime checks and a reader needs: the feature names,
order, units and filter time constants, the delays, the model kind the fluxes come from, the
training range of every input, the metrics, a fingerprint of the data, the version. No time
stamp is written: the same data and seed give the same bytes.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from gateway.vsensor.features import INPUT_DELAYS, OUTPUT_DELAYS
from training.vsensor.narx import DT_IN_OUT, WIND, MixedNarx, Narx

OPSET = 17
IR_VERSION = 8
FORMAT = "serra-vsensor/1"


def _const(name: str, value: np.ndarray):
    from onnx import numpy_helper

    return numpy_helper.from_array(np.ascontiguousarray(value, dtype=np.float32), name)


def _y_transform(net: Narx, src: str, pre: str) -> list:
    """Nodes taking the past flows ``src`` into the network's target space (→ ``{pre}y_t``)."""
    from onnx import helper

    if net.target == "identity":
        return []
    if net.target == "opening":  # past flows → past openings G / D
        return [helper.make_node("Div", [src, "d_past"], [f"{pre}y_t"], name=f"{pre}y_opening")]
    nodes = [helper.make_node("Relu", [src], [f"{pre}y_pos"], name=f"{pre}y_nonneg")]
    if net.target == "sqrt":
        return nodes + [helper.make_node("Sqrt", [f"{pre}y_pos"], [f"{pre}y_t"], name=f"{pre}y_sqrt")]
    return nodes + [helper.make_node("Add", [f"{pre}y_pos", "one"], [f"{pre}y_p1"], name=f"{pre}y_plus_one"),
                    helper.make_node("Log", [f"{pre}y_p1"], [f"{pre}y_t"], name=f"{pre}y_log")]


def _y_input(net: Narx, src: str, pre: str, scale: str = "") -> list:
    """Standardise the past outputs ``src`` (empty: ``y_past``) with ``{scale}y_mean`` and
    ``{scale}y_std`` and join the delayed inputs (→ ``{pre}h0``)."""
    from onnx import helper

    return [helper.make_node("Sub", [src or "y_past", f"{scale}y_mean"], [f"{pre}y_c"],
                             name=f"{pre}y_centre"),
            helper.make_node("Div", [f"{pre}y_c", f"{scale}y_std"], [f"{pre}y_s"], name=f"{pre}y_reduce"),
            helper.make_node("Concat", ["z_flat", f"{pre}y_s"], [f"{pre}h0"], axis=1,
                             name=f"{pre}narx_input")]


def _driver(net: Narx | MixedNarx) -> tuple[list, list]:
    """(initialisers, nodes) of the ventilation driver D (N, 6) from ``u``, sliced into
    ``d_now`` (N, 1), the delay 0, and ``d_past`` (N, 5), the delays 1–5."""
    from onnx import TensorProto, helper

    dr, d_in = net.driver, len(INPUT_DELAYS)
    inits = [_const("drv_b", np.array([dr.b])), _const("drv_w", np.array([dr.w])),
             _const("drv_floor", np.array([dr.floor])),
             helper.make_tensor("drv_wind", TensorProto.INT64, [], [WIND]),
             helper.make_tensor("drv_dt", TensorProto.INT64, [], [DT_IN_OUT]),
             helper.make_tensor("drv_axis", TensorProto.INT64, [1], [1]),
             helper.make_tensor("drv_0", TensorProto.INT64, [1], [0]),
             helper.make_tensor("drv_1", TensorProto.INT64, [1], [1]),
             helper.make_tensor("drv_end", TensorProto.INT64, [1], [d_in])]
    n = helper.make_node
    nodes = [n("Gather", ["u", "drv_wind"], ["drv_u"], axis=2, name="driver_wind"),
             n("Gather", ["u", "drv_dt"], ["drv_dt_v"], axis=2, name="driver_dt"),
             n("Mul", ["drv_u", "drv_u"], ["drv_u2"], name="driver_wind_sq"),
             n("Mul", ["drv_u2", "drv_w"], ["drv_wt"], name="driver_wind_term"),
             n("Abs", ["drv_dt_v"], ["drv_adt"], name="driver_abs_dt"),
             n("Mul", ["drv_adt", "drv_b"], ["drv_bt"], name="driver_buoyancy_term"),
             n("Add", ["drv_bt", "drv_wt"], ["drv_sum"], name="driver_sum"),
             n("Sqrt", ["drv_sum"], ["drv_root"], name="driver_root"),
             n("Max", ["drv_root", "drv_floor"], ["d_all"], name="driver_floor"),
             n("Slice", ["d_all", "drv_0", "drv_1", "drv_axis"], ["d_now"], name="driver_now"),
             n("Slice", ["d_all", "drv_1", "drv_end", "drv_axis"], ["d_past"], name="driver_past")]
    return inits, nodes


def _reduce(net: Narx | MixedNarx, inits: list, nodes: list) -> str:
    """Append the standardisation and the PCA of ``u``; returns the reduced inputs' name."""
    from onnx import helper

    nodes += [helper.make_node("Sub", ["u", "mean"], ["u_c"], name="centre"),
              helper.make_node("Div", ["u_c", "std"], ["z"], name="reduce")]
    if net.projection is None:
        return "z"
    inits.append(_const("pca", net.projection))
    nodes.append(helper.make_node("MatMul", ["z", "pca"], ["pcs"], name="pca"))
    return "pcs"


def build_graph(net: Narx | MixedNarx, n_features: int):
    """The ONNX ModelProto of ``net`` (no metadata yet)."""
    from onnx import TensorProto, helper

    d_in = len(INPUT_DELAYS)
    if isinstance(net, MixedNarx):
        return _model(net, n_features, *_mixed(net))
    inits = [
        _const("mean", net.mean), _const("std", net.std),
        _const("y_mean", np.array([net.y_mean])), _const("y_std", np.array([net.y_std])),
        helper.make_tensor("flat_shape", TensorProto.INT64, [2], [-1, d_in * net.width]),
    ]
    nodes: list = []
    z = _reduce(net, inits, nodes)
    k_h = net.histories  # K > 1: every member on its own past outputs, y_past (N, K, 5)
    if net.target in ("sqrt", "log1p"):
        inits.append(_const("one", np.array([1.0])))
    if net.target == "opening":
        d_inits, d_nodes = _driver(net)
        inits += d_inits
        nodes += d_nodes
    if k_h == 1:
        nodes += _y_transform(net, "y_past", "")
        nodes += [
            helper.make_node("Reshape", [z, "flat_shape"], ["z_flat"], name="delays"),
            *_y_input(net, "" if net.target == "identity" else "y_t", ""),
        ]
        heads = ["h0"] * len(net.stacks)
    else:
        nodes.append(helper.make_node("Reshape", [z, "flat_shape"], ["z_flat"], name="delays"))
        heads = []
        for j in range(k_h):
            pre = f"m{j}_"
            inits.append(helper.make_tensor(f"{pre}index", TensorProto.INT64, [], [j]))
            nodes.append(helper.make_node("Gather", ["y_past", f"{pre}index"], [f"{pre}y_past"],
                                          axis=1, name=f"{pre}own_past"))
            nodes += _y_transform(net, f"{pre}y_past", pre)
            nodes += _y_input(net, f"{pre}y_past" if net.target == "identity" else f"{pre}y_t", pre)
            heads.append(f"{pre}h0")
    h = _networks(net, heads, inits, nodes)
    nodes += _to_flow(net, h)
    return _model(net, n_features, inits, nodes)


def _model(net: Narx | MixedNarx, n_features: int, inits: list, nodes: list):
    """The graph of ``nodes`` (inputs ``u``, ``y_past``; output ``flow``) as a ModelProto."""
    from onnx import TensorProto, helper

    d_in, d_out, k_h = len(INPUT_DELAYS), len(OUTPUT_DELAYS), net.histories
    y_shape = ["N", d_out] if k_h == 1 else ["N", k_h, d_out]
    graph = helper.make_graph(
        nodes, f"serra_vsensor_{net.name}",
        [helper.make_tensor_value_info("u", TensorProto.FLOAT, ["N", d_in, n_features]),
         helper.make_tensor_value_info("y_past", TensorProto.FLOAT, y_shape)],
        [helper.make_tensor_value_info("flow", TensorProto.FLOAT, ["N", k_h])],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="serra training.vsensor", producer_version="1")
    model.ir_version = IR_VERSION
    return model


def _networks(net: Narx, heads: list[str], inits: list, nodes: list) -> str:
    """Append every member's layers (from its input ``heads[j]``) to ``inits``/``nodes``;
    returns the name of the scaled output: the members' mean, or all of them (own feedback)."""
    from onnx import helper

    outs = [_stack(stack, heads[j], "" if len(net.stacks) == 1 else f"m{j}_", inits, nodes)
            for j, stack in enumerate(net.stacks)]
    if net.histories > 1:  # own feedback: every member's flow (the runtime clips and averages)
        nodes.append(helper.make_node("Concat", outs, ["h_all"], axis=1, name="members_out"))
        return "h_all"
    if len(outs) > 1:  # the ensemble: the members' mean
        nodes.append(helper.make_node("Mean", outs, ["h_mean"], name="ensemble_mean"))
        return "h_mean"
    return outs[0]


def _stack(stack: list, h: str, pre: str, inits: list, nodes: list) -> str:
    """Append one member's layers (prefix ``pre``) from its input ``h``; returns its output."""
    from onnx import helper

    for i, layer in enumerate(stack):
        w, b, a, nxt = f"{pre}w{i}", f"{pre}b{i}", f"{pre}a{i}", f"{pre}h{i + 1}"
        inits += [_const(w, layer.weight), _const(b, layer.bias)]
        out = a if layer.activation == "tanh" else nxt
        nodes.append(helper.make_node("Gemm", [h, w, b], [out], name=f"{pre}layer{i}"))
        if layer.activation == "tanh":
            nodes.append(helper.make_node("Tanh", [out], [nxt], name=f"{pre}tanh{i}"))
        h = nxt
    return h


def _mixed(net: MixedNarx) -> tuple[list, list]:
    """(initialisers, nodes) of a mixed ensemble (ninth pass): shared standardisation, PCA and
    driver D; per member its own y_mean, y_std and target (an opening member hears the past
    flows divided by D(k−1…k−5) and its output is multiplied by D(k), as a ``--target opening``
    graph does); the members' flows averaged (``Mean``) or, with own feedback, each member on
    its own past and all their flows given (N, K)."""
    from onnx import TensorProto, helper

    inits = [_const("mean", net.mean), _const("std", net.std),
             helper.make_tensor("flat_shape", TensorProto.INT64, [2],
                                [-1, len(INPUT_DELAYS) * net.width])]
    nodes: list = []
    z = _reduce(net, inits, nodes)
    if net.driver is not None:
        d_inits, d_nodes = _driver(net)
        inits += d_inits
        nodes += d_nodes
    nodes.append(helper.make_node("Reshape", [z, "flat_shape"], ["z_flat"], name="delays"))
    flows = []
    for j, part in enumerate(net.parts):
        pre = f"m{j}_"
        inits += [_const(f"{pre}y_mean", np.array([part.y_mean])),
                  _const(f"{pre}y_std", np.array([part.y_std]))]
        src = "y_past"
        if net.histories > 1:  # this member's own past flows
            inits.append(helper.make_tensor(f"{pre}index", TensorProto.INT64, [], [j]))
            nodes.append(helper.make_node("Gather", ["y_past", f"{pre}index"], [f"{pre}y_past"],
                                          axis=1, name=f"{pre}own_past"))
            src = f"{pre}y_past"
        nodes += _y_transform(part, src, pre)  # opening: past flows / D(k−1…k−5)
        nodes += _y_input(part, src if part.target == "identity" else f"{pre}y_t", pre, pre)
        h = _stack(part.layers, f"{pre}h0", pre, inits, nodes)
        flow = f"{pre}flow" if part.target == "identity" else f"{pre}v"
        nodes += [helper.make_node("Mul", [h, f"{pre}y_std"], [f"{pre}y_scaled"], name=f"{pre}y_unscale"),
                  helper.make_node("Add", [f"{pre}y_scaled", f"{pre}y_mean"], [flow],
                                   name=f"{pre}y_uncentre")]
        if part.target == "opening":  # opening × D(k) → a flow
            nodes.append(helper.make_node("Mul", [flow, "d_now"], [f"{pre}flow"],
                                          name=f"{pre}v_times_driver"))
        flows.append(f"{pre}flow")
    if net.histories > 1:
        nodes.append(helper.make_node("Concat", flows, ["flow"], axis=1, name="members_out"))
    else:  # the ensemble: the members' flows averaged
        nodes.append(helper.make_node("Mean", flows, ["flow"], name="ensemble_mean"))
    return inits, nodes


def _to_flow(net: Narx, h: str) -> list:
    """Nodes from the scaled output ``h`` to ``flow`` [m3 s-1]: unscale, then undo the target."""
    from onnx import helper

    nodes = [
        helper.make_node("Mul", [h, "y_std"], ["y_scaled"], name="y_unscale"),
        helper.make_node("Add", ["y_scaled", "y_mean"],
                         ["flow" if net.target == "identity" else "v"], name="y_uncentre"),
    ]
    if net.target == "sqrt":  # back to a flow: max(v, 0)²
        nodes += [helper.make_node("Relu", ["v"], ["v_pos"], name="v_nonneg"),
                  helper.make_node("Mul", ["v_pos", "v_pos"], ["flow"], name="v_square")]
    elif net.target == "log1p":  # e^v − 1
        nodes += [helper.make_node("Exp", ["v"], ["v_exp"], name="v_exp"),
                  helper.make_node("Sub", ["v_exp", "one"], ["flow"], name="v_minus_one")]
    elif net.target == "opening":  # opening × D(k): (N, K) × (N, 1)
        nodes.append(helper.make_node("Mul", ["v", "d_now"], ["flow"], name="v_times_driver"))
    return nodes


def write_model(net: Narx, n_features: int, meta: Mapping[str, Any], path: str | Path) -> bytes:
    """Build, check and write the model with ``meta`` as metadata_props (values JSON-encoded
    unless already strings). Returns the bytes written."""
    import onnx
    from onnx import helper

    model = build_graph(net, n_features)
    props = {k: v if isinstance(v, str) else json.dumps(v, sort_keys=True) for k, v in meta.items()}
    props["format"] = FORMAT
    helper.set_model_props(model, dict(sorted(props.items())))
    model.doc_string = ("Serra virtual ventilation sensor (thesis §IV.3): filtered inputs u (N, 6, F) "
                        "and past flows y_past (N, 5) → flow (N, 1) [m3 s-1]. See docs/vsensor.md.")
    onnx.checker.check_model(model)
    data = model.SerializeToString(deterministic=True)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_bytes(data)
    return data
