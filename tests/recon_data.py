"""A reconstruction in memory made from arrays, for the viewer's tests (the product only ever
loads one from a folder: :func:`impress_gui.core.measure.readings.load_reconstruction`)."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from impress_gui.core.base.errors import InputError
from impress_gui.core.measure.readings import ReconData
from impress_gui.core.reconstruction.grid import GridSpec


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    a.setflags(write=False)
    return a


def recon_data_from_arrays(
    spec: GridSpec,
    height_mm: np.ndarray,
    texture_rgb=None,
    metadata: Mapping | None = None,
    **layers: np.ndarray,
) -> ReconData:
    """A :class:`ReconData` of ``height_mm`` (the "fused" layer) on ``spec``, with the other
    ``layers``, the texture and the metadata given (read-only arrays, no folder)."""
    if tuple(height_mm.shape) != tuple(spec.shape):
        raise InputError(f"height map {height_mm.shape} does not match grid {spec.shape}")
    all_layers = {"fused": _frozen(np.asarray(height_mm, np.float32))}
    all_layers.update({k: _frozen(v) for k, v in layers.items()})
    tex = None if texture_rgb is None else _frozen(texture_rgb)
    return ReconData(spec, MappingProxyType(all_layers), tex, MappingProxyType(dict(metadata or {})))
