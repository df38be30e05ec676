"""Step length from the statistics of each detected step, and its calibration per responder.

Every model is linear in its coefficients, :math:`L = b(x) + \\Phi(x)\\,\\theta`, so one least-
squares routine (:func:`calibrate`) fits any of them from walks of known length. All
functions take arrays over many steps (see :func:`step_arrays`).

=========================  ==========================================  ===========================
model                      length (m)                                  source
=========================  ==========================================  ===========================
``weinberg``               :math:`K\\,\\sqrt[4]{a_{max}-a_{min}}`         Tupý §3.2 eq. 3.6
``weinberg_subtractive``   :math:`\\sqrt[4]{a_{max}-a_{min}} - K`        Tupý eq. 3.11 as printed
``weinberg_modified``      :math:`K_1\\sqrt[4]{a_{max}-a_{min}} - K_2`   Tupý eq. 3.7 (Kang & Han)
``kim``                    :math:`K\\,\\sqrt[3]{\\overline{|a|}}`          Tupý eq. 3.9
``scarlett``               :math:`K\\,(\\bar a - a_{min})/(a_{max}-a_{min})`  Tupý eq. 3.10
``frequency``              :math:`a + b\\,f`                            Ryšánek §3.6 eq. 34
``height``                 :math:`K\\,h`                                 Tupý eq. 3.1
=========================  ==========================================  ===========================

The accelerations are those of the detector's filtered signal over the step
(:class:`~pdr.events.StepDetection`), so coefficients belong to one detector and filter:
"any change of filter requires recalibration" (Tupý §2.1). ``f = 1 / duration`` is the
step frequency (Hz) and ``h`` the responder's height (m).

On Tupý's K = 0.828: eq. 3.6 multiplies, but the calibration eq. 3.11 subtracts. With the
thesis's 0.35-1.00 m steps the multiplicative reading needs swings of 0.03-2.1 m/s², the
subtractive one 1.9-11 m/s² — the latter is what a hand-held phone shows, so both are
offered and K should be re-fitted on one's own walks anyway.

Defaults give about 0.65-0.7 m for an adult walking at 1.8-2 Hz: ``frequency`` with
a = 0.25 m, b = 0.22 m·s (0.65 m at 1.8 Hz, 0.69 m at 2 Hz). b is the one step-length number
chosen from data: on the IPIN 2023 walks (hand-held phones, the ``norm`` detector) by
leave-one-route-out cross-validation over b ∈ {0.20, 0.22, 0.24} (``firetrack eval ipin --cv``):
0.22 is chosen on every fold but two at K = 0; the seed's 0.24 made the tracks about 5 % long
(dead reckoning p75 5.06 → 4.51 m on all 40 walks). ``height`` with K = 0.415
(men; 0.413 women), 0.73 m for 1.75 m. Kim's K = 0.55 and Scarlett's K = 1.4 are only
starting values (0.5-0.8 m on the ``norm`` detector's signal in the Oxford walks); they,
like Weinberg's K, must be calibrated per responder and detector.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from pdr.events import StepDetection
from pdr.fixed_order import row_dot

_MAX_FREQUENCY_HZ = 4.0  # a step shorter than 0.25 s is clipped to this frequency


def step_arrays(steps: Sequence[StepDetection]) -> dict[str, np.ndarray]:
    """The fields of many detections as arrays: ``a_max, a_min, a_mean, a_mean_abs, duration``."""
    fields = ("a_max", "a_min", "a_mean", "a_mean_abs")
    out = {k: np.fromiter((getattr(s, k) for s in steps), float, len(steps)) for k in fields}
    out["duration"] = np.fromiter((s.t - s.t_start for s in steps), float, len(steps))
    return out


def step_frequency(duration: np.ndarray) -> np.ndarray:
    """``1 / duration`` (Hz), with durations under 1/4 s counted as 4 Hz."""
    return 1.0 / np.maximum(np.asarray(duration, dtype=float), 1.0 / _MAX_FREQUENCY_HZ)


# -- the models: base b(x) and regressors Φ(x) ------------------------------------------------
class _Model(NamedTuple):
    coefficients: tuple[str, ...]
    defaults: tuple[float, ...]
    base: Callable[[dict, float], np.ndarray]  # part without coefficients, (N,)
    regressors: Callable[[dict, float], np.ndarray]  # (N, len(coefficients))


def _swing(x: dict) -> np.ndarray:
    return np.maximum(x["a_max"] - x["a_min"], 0.0)


def _zero(x: dict, h: float) -> np.ndarray:
    return np.zeros_like(x["a_max"])


def _scarlett_ratio(x: dict) -> np.ndarray:
    swing = x["a_max"] - x["a_min"]
    return np.divide(x["a_mean"] - x["a_min"], swing, out=np.zeros_like(swing), where=swing > 0)


MODELS: dict[str, _Model] = {
    "weinberg": _Model(("k",), (0.828,), _zero, lambda x, h: _swing(x)[:, None] ** 0.25),
    "weinberg_subtractive": _Model(("k",), (0.828,), lambda x, h: _swing(x) ** 0.25, lambda x, h: -np.ones((len(x["a_max"]), 1))),
    "weinberg_modified": _Model(
        ("k1", "k2"), (1.0, 0.828), _zero,
        lambda x, h: np.column_stack([_swing(x) ** 0.25, -np.ones(len(x["a_max"]))]),
    ),
    "kim": _Model(("k",), (0.55,), _zero, lambda x, h: np.cbrt(np.abs(x["a_mean_abs"]))[:, None]),
    "scarlett": _Model(("k",), (1.4,), _zero, lambda x, h: _scarlett_ratio(x)[:, None]),
    "frequency": _Model(
        ("a", "b"), (0.25, 0.22), _zero,
        lambda x, h: np.column_stack([np.ones(len(x["duration"])), step_frequency(x["duration"])]),
    ),
    "height": _Model(("k",), (0.415,), _zero, lambda x, h: np.full((len(x["a_max"]), 1), h)),
}


def default_coefficients(model: str) -> dict[str, float]:
    m = _model(model)
    return dict(zip(m.coefficients, m.defaults))


def _model(name: str) -> _Model:
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown step-length model {name!r}; choose one of {', '.join(MODELS)}") from None


def _as_arrays(steps) -> dict[str, np.ndarray]:
    return steps if isinstance(steps, dict) else step_arrays(steps)


# -- the responder -------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ResponderProfile:
    """What step length needs to know about one responder; plain data for the service config.

    ``model`` and ``coefficients`` are a :data:`MODELS` entry and its fitted values;
    ``detector`` names the step detector the coefficients were fitted with (they depend
    on its filter); ``carry`` is where the phone is worn (``hand``, ``pocket``, ``bag``,
    ``armband``, ``chest``, ...).
    """

    height_m: float = 1.75
    model: str = "frequency"
    coefficients: dict[str, float] = dataclasses.field(default_factory=lambda: default_coefficients("frequency"))
    carry: str = "hand"
    detector: str = "norm"

    def __post_init__(self) -> None:
        m = _model(self.model)
        if set(self.coefficients) != set(m.coefficients):
            raise ValueError(f"model {self.model!r} takes coefficients {m.coefficients}, got {tuple(self.coefficients)}")
        if not self.height_m > 0:
            raise ValueError(f"height_m must be positive, got {self.height_m}")

    @classmethod
    def with_model(cls, model: str, **fields) -> ResponderProfile:
        """A profile using ``model`` with its default coefficients (unless given)."""
        fields.setdefault("coefficients", default_coefficients(model))
        return cls(model=model, **fields)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ResponderProfile:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown profile fields {sorted(unknown)}; valid: {sorted(known)}")
        d = dict(d)
        if "coefficients" in d:
            d["coefficients"] = {k: float(v) for k, v in d["coefficients"].items()}
        return cls(**d)


def step_lengths(steps, profile: ResponderProfile | None = None) -> np.ndarray:
    """Length (m) of each step: detections or :func:`step_arrays` output; shape (N,)."""
    profile = profile or ResponderProfile()
    m = _model(profile.model)
    x = _as_arrays(steps)
    theta = np.array([profile.coefficients[c] for c in m.coefficients])
    if len(x["a_max"]) == 0:
        return np.empty(0)
    return m.base(x, profile.height_m) + row_dot(m.regressors(x, profile.height_m), theta)


class Calibration(NamedTuple):
    coefficients: dict[str, float]
    residuals_m: np.ndarray  # per walk, estimated minus known length


def calibrate(walks: Sequence[tuple[object, float]], model: str, height_m: float = 1.75) -> Calibration:
    """Least-squares coefficients of ``model`` from walks of known length.

    ``walks`` holds ``(steps, length_m)`` pairs, ``steps`` being detections or
    :func:`step_arrays` output. Each walk's summed step lengths must equal its length,
    :math:`\\sum_k b(x_k) + (\\sum_k \\Phi(x_k))\\,\\theta = D_w`: one linear equation per walk,
    solved for θ by least squares (at least as many walks as coefficients; vary the pace
    between walks for the two-coefficient models).
    """
    m = _model(model)
    if len(walks) < len(m.coefficients):
        raise ValueError(f"model {model!r} has {len(m.coefficients)} coefficients; give at least that many walks")
    rows, rhs = [], []
    for steps, length in walks:
        x = _as_arrays(steps)
        rows.append(m.regressors(x, height_m).sum(axis=0))
        rhs.append(float(length) - m.base(x, height_m).sum())
    A, b = np.array(rows), np.array(rhs)
    theta, *_ = np.linalg.lstsq(A, b, rcond=None)
    return Calibration(dict(zip(m.coefficients, map(float, theta))), A @ theta - b)
