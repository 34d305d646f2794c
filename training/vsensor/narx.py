"""The NARX networks as plain arrays: standardisation, optional projection, layers.

One structure for the three models trained side by side (the PCA-NARX and its two baselines),
so that one forward pass (numpy here, ONNX at run time: training/vsensor/export.py) serves all:

    z_d = ((u(k-d) - mean) / std) @ P          d = 0..5   (P: PCA loadings, or identity)
    h   = [z_0, z_1, …, z_5, (T(y(k-1..k-5)) - y_mean) / y_std]
    y   = T⁻¹(layers(h) * y_std + y_mean)       (tanh hidden layers, linear output)

T is the target transform (``target``: none, √G or log(1 + G)); y_mean and y_std are those of
T(G) over the training rows. The ``opening`` target (eighth pass) divides every flow by the
ventilation driver D of the same minute (:class:`Driver`, from the inputs' wind and
T_in − T_out): the network learns and hears effective openings G / D, and its output is
multiplied back by D(k), so flows still go in and come out.

An ensemble (``members``: several layer stacks fitted from different seeds on the same rows)
shares the pre-processing and averages the stacks' outputs; in closed loop every member hears
the ensemble's own past outputs (one ``y_past``), or, with ``own_feedback``, its own (K output
histories: ``y_past`` (N, K, 5), one flow per member, averaged by the loop after clipping).
A mixed ensemble (:class:`MixedNarx`, ninth pass) holds members of different targets (flow and
opening, alternating by seed), each with its own y_mean, y_std, and averages them as flows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gateway.vsensor.features import INPUT_DELAYS, OUTPUT_DELAYS

ACTIVATIONS = ("tanh", "identity")
TARGETS = ("identity", "sqrt", "log1p", "opening")
"""What the network learns and feeds back: the flow itself, its square root or log(1 + G)
(a compressed target; the graph applies it to ``y_past`` and inverts it on the output), or the
effective opening G / D (:class:`Driver`)."""
WIND, DT_IN_OUT = 0, 1
"""Columns of the inputs the driver reads (features.py: ``wind`` filtered, ``dt_in_out``)."""
T_OUT_REF = 20.0
"""[°C] The outside temperature in the driver's buoyancy term B = A_eff² 2 g h / T_out: fixed,
because the graph's inputs carry T_in − T_out but not T_out (1/T_out moves D by ±2.5 % over
0–35 °C)."""
FLOOR_WIND = 0.25
"""[m s-1] The driver's floor is D at this wind and ΔT = 0 (5.5 m3 s-1 for the Almería house):
it bounds the opening where the air is still and the inside at the outside temperature."""


@dataclass(frozen=True)
class Driver:
    """The ventilation driver D = max(sqrt(b |ΔT| + w u²), floor) [m3 s-1] of the inputs' wind u
    (filtered) and ΔT = T_in − T_out: ``gateway.model.almeria.ventilation_driver`` at T_out =
    T_OUT_REF, its two constants (b = D² at 1 K and no wind, w = D² at 1 m s-1 and ΔT 0) taken
    from that function, so III.31 is written once (the graph computes the same expression)."""

    b: float  # [m6 s-2 K-1]
    w: float  # [m4]: D² [m6 s-2] per u² [m2 s-2]
    floor: float  # [m3 s-1]
    t_out_ref: float = T_OUT_REF

    @classmethod
    def of_greenhouse(cls, gh) -> Driver:
        from gateway.model.almeria import driver_constants

        return cls(*driver_constants(gh, T_OUT_REF, FLOOR_WIND))

    def of(self, u: np.ndarray) -> np.ndarray:
        """D for inputs u (..., F) → (...)."""
        root = np.sqrt(self.b * np.abs(u[..., DT_IN_OUT]) + self.w * u[..., WIND] ** 2)
        return np.maximum(root, self.floor)

    def as_meta(self) -> dict[str, float]:
        return {"b": self.b, "w": self.w, "floor": self.floor, "t_out_ref_c": self.t_out_ref,
                "floor_wind_m_s": FLOOR_WIND}


def to_target(y: np.ndarray, target: str, d: np.ndarray | None = None) -> np.ndarray:
    """Flows [m3 s-1] → the network's target space (negative flows count as 0; ``opening``:
    G / D with ``d`` the driver of the same minutes)."""
    if target == "identity":
        return y
    if target == "opening":
        return y / d
    if target == "sqrt":
        return np.sqrt(np.maximum(y, 0.0))
    if target == "log1p":
        return np.log1p(np.maximum(y, 0.0))
    raise ValueError(f"target {target!r}: one of {TARGETS}")


def from_target(v: np.ndarray, target: str, d: np.ndarray | None = None) -> np.ndarray:
    """The network's target space → flows [m3 s-1] (sqrt: max(v, 0)²; log1p: e^v − 1;
    opening: v D)."""
    if target == "identity":
        return v
    if target == "opening":
        return v * d
    if target == "sqrt":
        return np.maximum(v, 0.0) ** 2
    if target == "log1p":
        return np.expm1(v)
    raise ValueError(f"target {target!r}: one of {TARGETS}")


@dataclass
class Layer:
    weight: np.ndarray  # (n_in, n_out)
    bias: np.ndarray  # (n_out,)
    activation: str  # "tanh" or "identity"


@dataclass
class Narx:
    """A trained network with its pre-processing (all float64 here, float32 in ONNX)."""

    name: str  # "pca_narx", "narx_no_pca", "linear_arx"
    mean: np.ndarray  # (F,) standardisation
    std: np.ndarray  # (F,)
    projection: np.ndarray | None  # (F, m) PCA loadings, None: the standardised inputs
    y_mean: float
    y_std: float
    layers: list[Layer] = field(default_factory=list)
    explained: np.ndarray | None = None  # (m,) variance share of each kept component
    members: list[list[Layer]] = field(default_factory=list)  # ensemble stacks; empty: ``layers``
    target: str = "identity"  # TARGETS: y_mean, y_std and the layers' output are in this space
    own_feedback: bool = False  # an ensemble's members each hear their own past (K histories)
    driver: Driver | None = None  # the ``opening`` target's D
    flow_median: float = float("nan")  # ``opening``: the training flows' median (y0)

    @property
    def histories(self) -> int:
        """Output histories the closed loop keeps: K for own feedback, else 1."""
        return len(self.stacks) if self.own_feedback else 1

    @property
    def y0(self) -> float:
        """The past flows before the first step [m3 s-1]: the training median."""
        if self.target == "opening":
            return self.flow_median
        return float(from_target(np.asarray(self.y_mean), self.target))

    @property
    def stacks(self) -> list[list[Layer]]:
        """The layer stacks whose outputs are averaged (one for a single network)."""
        return self.members or [self.layers]

    @property
    def width(self) -> int:
        """Values per delay after the projection."""
        return len(self.mean) if self.projection is None else self.projection.shape[1]

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(layer.weight.shape[1] for layer in self.stacks[0][:-1])

    def reduce(self, inputs: np.ndarray) -> np.ndarray:
        """Standardised (and projected) inputs: (..., F) → (..., m)."""
        z = (inputs - self.mean) / self.std
        return z if self.projection is None else z @ self.projection

    def head(self, z_lags: np.ndarray, y_past: np.ndarray, d_past: np.ndarray | None = None
             ) -> np.ndarray:
        """The network's input row: (N, D, m) reduced inputs and (N, 5) past flows (``opening``:
        with their drivers ``d_past`` (N, 5)) → (N, D m + 5)."""
        ys = (to_target(y_past, self.target, d_past) - self.y_mean) / self.y_std
        return np.concatenate([z_lags.reshape(len(z_lags), -1), ys], axis=1)

    def forward(self, h: np.ndarray) -> np.ndarray:
        """Scaled output of the layers (the mean over an ensemble's stacks) for rows ``h``
        (N, D m + 5) → (N,)."""
        out = np.zeros(len(h))
        for stack in self.stacks:
            out += _run(stack, h)
        return out / len(self.stacks)

    def predict(self, u: np.ndarray, y_past: np.ndarray) -> np.ndarray:
        """Flows (N,) [m3 s-1] from raw inputs u (N, D, F) and past flows (N, 5); with own
        feedback (``histories`` K > 1) y_past is (N, K, 5), member j's own past at [:, j], and
        the result each member's flow (N, K)."""
        z = self.reduce(u)
        d = self.driver.of(u) if self.target == "opening" else None  # (N, 6): k, k-1 … k-5
        d_past = None if d is None else d[:, 1:]
        if self.histories > 1:
            v = np.column_stack([_run(stack, self.head(z, y_past[:, j], d_past))
                                 for j, stack in enumerate(self.stacks)])
            d_now = None if d is None else d[:, :1]
        else:
            v = self.forward(self.head(z, y_past, d_past))
            d_now = None if d is None else d[:, 0]
        return from_target(v * self.y_std + self.y_mean, self.target, d_now)


MIXED = "mixed"
"""The mixed ensemble (ninth pass): members alternate target by seed (:func:`member_target`)."""
MEMBER_KINDS = {"identity": "flow", "opening": "opening"}
"""A mixed member's target → its name in the metadata's ``member_targets``."""


def member_target(seed: int) -> str:
    """A mixed ensemble's member of network seed ``seed``: even seeds learn the flow (the
    shipped setting's members), odd seeds the effective opening G / D (the eighth pass's)."""
    return "identity" if seed % 2 == 0 else "opening"


@dataclass
class MixedNarx:
    """An ensemble whose members learn different targets (``member_target``): each member a
    single :class:`Narx` with its own target, y_mean, y_std (and driver), all sharing the
    standardisation and PCA; their outputs are averaged **as flows** (an opening member's output
    multiplied by D(k)). Closed loop, every member hears the ensemble's past flows (an opening
    member divides them by D(k−1…k−5)), or with ``own_feedback`` its own."""

    name: str
    parts: list[Narx]
    own_feedback: bool = False
    explained: np.ndarray | None = None

    def __post_init__(self) -> None:
        if any(p.members for p in self.parts) or any(p.target not in MEMBER_KINDS for p in self.parts):
            raise ValueError(f"mixed members: single networks on {tuple(MEMBER_KINDS)}")
        y0 = {p.y0 for p in self.parts}  # the training flows' median, whatever the target
        if len(y0) != 1:
            raise ValueError(f"mixed members disagree on y0: {sorted(y0)}")

    target = MIXED
    mean = property(lambda self: self.parts[0].mean)
    std = property(lambda self: self.parts[0].std)
    projection = property(lambda self: self.parts[0].projection)
    width = property(lambda self: self.parts[0].width)
    hidden = property(lambda self: self.parts[0].hidden)
    y0 = property(lambda self: self.parts[0].y0)

    @property
    def targets(self) -> list[str]:
        """Each member's target in the metadata's words (``flow``, ``opening``)."""
        return [MEMBER_KINDS[p.target] for p in self.parts]

    @property
    def driver(self) -> Driver | None:
        return next((p.driver for p in self.parts if p.target == "opening"), None)

    @property
    def stacks(self) -> list[list[Layer]]:
        return [p.layers for p in self.parts]

    @property
    def members(self) -> list[list[Layer]]:
        return self.stacks

    @property
    def histories(self) -> int:
        return len(self.parts) if self.own_feedback else 1

    def reduce(self, inputs: np.ndarray) -> np.ndarray:
        return self.parts[0].reduce(inputs)

    def predict(self, u: np.ndarray, y_past: np.ndarray) -> np.ndarray:
        """Flows (N,) from raw inputs u (N, D, F) and the ensemble's past flows (N, 5): the
        members' flows averaged; own feedback: y_past (N, K, 5) → each member's flow (N, K)."""
        if self.histories > 1:
            return np.column_stack([p.predict(u, y_past[:, j]) for j, p in enumerate(self.parts)])
        return np.mean([p.predict(u, y_past) for p in self.parts], axis=0)


def _run(stack: list[Layer], h: np.ndarray) -> np.ndarray:
    """One layer stack's scaled output (N,) for rows ``h``."""
    a = h
    for layer in stack:
        a = a @ layer.weight + layer.bias
        if layer.activation == "tanh":
            a = np.tanh(a)
    return a[:, 0]


def lag_rows(z: np.ndarray, y: np.ndarray, y_lags: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Series-parallel rows of one series: z (T, m) reduced inputs, y (T,) target.

    Returns (Z (N, D, m), Y_past (N, 5), target (N,)) for every k whose delayed inputs and
    outputs are all finite. ``y_lags`` (T,) supplies the past outputs instead of ``y`` (closed-
    loop outputs, for training on the network's own feedback); targets are always ``y``.
    """
    d_in = max(INPUT_DELAYS) + 1
    d_out = max(OUTPUT_DELAYS)
    lags = y if y_lags is None else y_lags
    start = max(d_in - 1, d_out)
    ks = np.arange(start, len(y))
    if ks.size == 0:
        return np.empty((0, d_in, z.shape[1])), np.empty((0, d_out)), np.empty(0)
    zi = ks[:, None] - np.asarray(INPUT_DELAYS)[None, :]
    yi = ks[:, None] - np.asarray(OUTPUT_DELAYS)[None, :]
    zz, yp, tg = z[zi], lags[yi], y[ks]
    ok = np.all(np.isfinite(zz), axis=(1, 2)) & np.all(np.isfinite(yp), axis=1) & np.isfinite(tg)
    # the target's own past must be real too, or a row would learn from a gap
    ok &= np.all(np.isfinite(y[yi]), axis=1)
    return zz[ok], yp[ok], tg[ok]
