"""Adapters that let callers working in float32 use the float64 analytic fields of the built-in scenes.

The closed-form SDFs and materials of :mod:`srvol.synth.scenes` are written for the float64
ground-truth renderer. Wrapped here, they are evaluated on the caller's points cast to float64 and
answer in the caller's dtype, so a float32 renderer or baker sees float32 tensors throughout.
"""
from __future__ import annotations

from torch import Tensor

from srvol.types import MaterialFn, SdfFn, SurfaceMaterial


def sdf_in_float64(sdf: SdfFn) -> SdfFn:
    """``sdf`` evaluated in float64 on points of any dtype, returned in the points' dtype."""
    def sdf_fn(x: Tensor) -> Tensor:
        return sdf(x.double()).to(x.dtype)
    return sdf_fn


def material_in_float64(material: MaterialFn) -> MaterialFn:
    """``material`` evaluated in float64 on points of any dtype, each parameter returned in the points' dtype."""
    def material_fn(x: Tensor) -> SurfaceMaterial:
        m = material(x.double())
        return SurfaceMaterial(albedo=m.albedo.to(x.dtype), specular=m.specular.to(x.dtype),
                               alpha=m.alpha.to(x.dtype))
    return material_fn
