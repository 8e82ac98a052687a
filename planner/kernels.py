"""Compile (or load from numba's on-disk cache) every numba kernel of the motion planner, so
that no request pays for the compilation: the Docker image calls :func:`compile_kernels` at
build time and the service at start (:func:`service.pipeline.warm_up`)."""

from __future__ import annotations

from planner import clearance, geometry, timeline

__all__ = ["compile_kernels"]


def compile_kernels() -> None:
    """Every kernel of :mod:`planner.clearance`, :mod:`planner.geometry` and
    :mod:`planner.timeline`."""
    clearance.compile_kernels()
    geometry.compile_kernels()
    timeline.compile_kernels()
