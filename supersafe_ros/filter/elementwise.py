"""Python's ``max`` and ``min`` elementwise over numpy arrays, ties and all.

``max(a, b)`` returns ``a`` unless ``b > a`` (so -0.0 and 0.0 come out as Python gives them);
``np.maximum`` does not, and a zero's sign shows in the commands. The column forms of the
filter's formulas (``commands``, ``propagation``) use these, so that a fleet's columns and a
lone robot's Python floats agree bit for bit.
"""
from __future__ import annotations

import numpy as np


def py_max(a, b):
    """Python's max(a, b) elementwise (a on ties)."""
    return np.where(b > a, b, a)


def py_min(a, b):
    """Python's min(a, b) elementwise (a on ties)."""
    return np.where(b < a, b, a)
