"""Layer heights: tops, mid-heights and thicknesses of the layers of a part."""

from __future__ import annotations

import math

import numpy as np

from ..tolerances import SAME_LENGTH


def layer_heights(height: float, layer_height: float, first_layer_height: float):
    """Layer tops, mid-heights and thicknesses for a part ``height`` mm tall.

    The first layer is ``first_layer_height`` thick, every other ``layer_height``.
    A layer is kept while its mid-height lies inside the part. Returns three (L,)
    float arrays, mm: ``top``, ``mid``, ``thickness``.
    """
    if height <= 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    n_more = max(0, math.ceil((height - first_layer_height) / layer_height) + 1)
    top = first_layer_height + layer_height * np.arange(n_more + 1, dtype=float)
    thickness = np.full(len(top), layer_height)
    thickness[0] = first_layer_height
    mid = top - thickness / 2
    keep = mid < height - SAME_LENGTH
    return top[keep], mid[keep], thickness[keep]
