"""The ways to use association weights: known, ml, gpda, mm, mm-nh (METHOD.md), and dcsam
(discrete-continuous smoothing and mapping over the same candidates)."""

from __future__ import annotations

from pipeline.backend.methods.base import AssociationMethod, BackendContext, Keyframe
from pipeline.backend.methods.dcsam import DiscreteContinuous
from pipeline.backend.methods.gpda import GaussianPDA
from pipeline.backend.methods.known import KnownAssociation
from pipeline.backend.methods.maxmixture import MaxMixture
from pipeline.backend.methods.ml import MaximumLikelihood

METHODS = ("known", "ml", "gpda", "mm", "mm-nh", "dcsam")

__all__ = ["METHODS", "AssociationMethod", "BackendContext", "Keyframe", "make_method"]


def make_method(name: str, context: BackendContext) -> AssociationMethod:
    if name == "known":
        return KnownAssociation(context)
    if name == "ml":
        return MaximumLikelihood(context)
    if name == "gpda":
        return GaussianPDA(context)
    if name == "mm":
        return MaxMixture(context, null_hypothesis=False)
    if name == "mm-nh":
        return MaxMixture(context, null_hypothesis=True)
    if name == "dcsam":
        return DiscreteContinuous(context)
    raise ValueError(f"unknown association method {name!r}; choose from {', '.join(METHODS)}")
