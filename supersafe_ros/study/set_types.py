"""What kind of safe set a supervisor has: Standard-like, Conservative-like or gradual.

The paper's Fig. 6 sorts its participants' learned sets by eye on the theta = 0 slice:
"three users' safe sets clustered to arcing like the Standard safe set. Three others
clustered to arcing like the Conservative safe set. The final five ... reflect
supervisors' preference for gradual, pre-emptive arcs." ``set_type`` makes that sorting a
rule, on the same slice (heading 0, the obstacle at the origin), of the unsafe set
U = {V <= alpha} against the Standard set (true dynamics, radius 1.8, alpha 0) and the
Conservative set (radius 3.6):

* **conservative**: U overlaps the Conservative unsafe set more than the Standard one
  (intersection over union on the slice, ``iou_conservative >= iou_standard``): the set
  keeps robots about as far out as the doubled radius does;
* **gradual**: otherwise, if U reaches at least ``GRADUAL_EXTRA_REACH`` (0.75 m) further
  ahead of the obstacle, head-on, than the true dynamics' set at the same level alpha
  does (``extra_reach``): at the same lateral margin the avoid arc starts earlier, which
  is the gentle, pre-emptive arc of a slower believed turn rate (in the paper's library:
  omega_max <= 0.625);
* **standard**: the rest (arcs as the true dynamics', at a small margin).

Shapes are measured on a 0.05 m raster of the slice over the library's grid.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
import functools

import numpy as np

TYPES = ('standard', 'conservative', 'gradual')
TYPE_LABELS = {'standard': 'Standard-like', 'conservative': 'Conservative-like', 'gradual': 'gradual'}
GRADUAL_EXTRA_REACH = 0.75      # m further ahead, head-on, than the true dynamics at the same level
RASTER = 0.05                   # m


@dataclass(frozen=True)
class SetShape:
    reach: float                # head-on: how far ahead of the centre U starts (y = 0) [m]
    width: float                # abreast: U's half-width at x = 0 [m]
    extra_reach: float          # reach minus the true dynamics' reach at the same alpha [m]
    iou_standard: float
    iou_conservative: float
    type: str

    def to_dict(self) -> dict:
        return asdict(self)


@functools.lru_cache(maxsize=1)
def _raster(lo: float = -8.0, hi: float = 8.0):
    xs = np.arange(lo, hi + RASTER / 2, RASTER)
    x, y = np.meshgrid(xs, xs, indexing='ij')
    return xs, np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


_VALUES: dict = {}                # id(vf) -> (vf, its values on the raster); a few kept


def _unsafe(vf, alpha: float) -> np.ndarray:
    """{V <= alpha} on the raster (a value function's raster is computed once)."""
    xs, states = _raster()
    hit = _VALUES.get(id(vf))
    if hit is None or hit[0] is not vf:
        if len(_VALUES) >= 32:
            _VALUES.pop(next(iter(_VALUES)))
        hit = _VALUES[id(vf)] = (vf, vf.value(states).reshape(len(xs), len(xs)))
    return hit[1] <= float(alpha)


def _reach_width(mask) -> tuple[float, float]:
    xs, _ = _raster()
    mid = int(np.argmin(np.abs(xs)))
    row, col = mask[:, mid], mask[mid, :]
    reach = float(-xs[np.argmax(row)]) if row.any() else 0.0
    width = float(np.max(np.abs(xs[col]))) if col.any() else 0.0
    return reach, width


_REFERENCES: dict = {}


def _reference(standard_vf, conservative_vf):
    """The reference sets' unsafe rasters (value functions are not hashable: by identity)."""
    key = (id(standard_vf), id(conservative_vf))
    if key not in _REFERENCES:
        _REFERENCES.clear()
        _REFERENCES[key] = (standard_vf, conservative_vf, _unsafe(standard_vf, 0.0), _unsafe(conservative_vf, 0.0))
    return _REFERENCES[key][2:]


def _iou(a, b) -> float:
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / union) if union else 0.0


def set_shape(vf, alpha: float, standard_vf, conservative_vf) -> SetShape:
    """Reach, width, overlaps and type of {vf <= alpha} (``standard_vf``: the true dynamics'
    value function, also the reference for ``extra_reach``)."""
    std, cons = _reference(standard_vf, conservative_vf)
    mask = _unsafe(vf, alpha)
    reach, width = _reach_width(mask)
    true_reach, _ = _reach_width(_unsafe(standard_vf, alpha))
    iou_s, iou_c = _iou(mask, std), _iou(mask, cons)
    extra = reach - true_reach
    kind = 'conservative' if iou_c >= iou_s else 'gradual' if extra >= GRADUAL_EXTRA_REACH - 1e-9 else 'standard'
    return SetShape(reach, width, extra, iou_s, iou_c, kind)


def count_types(types) -> dict:
    """{type: how many} over every type (zeros included)."""
    types = list(types)
    return {t: types.count(t) for t in TYPES}
