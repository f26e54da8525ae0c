"""The ways to use association weights: known, ml, gpda, mm, mm-nh (METHOD.md), and dcsam
(discrete-continuous smoothing and mapping over the same candidates).

`METHODS` is the one registry of their names: the command line, the sweeps and the tools read
it. Reading it imports nothing else (the methods' modules load GTSAM), so `mmslam --help` stays
fast; a method's module is imported when one is made.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pipeline.backend.methods.base import AssociationMethod, BackendContext

METHODS = ("known", "ml", "gpda", "mm", "mm-nh", "dcsam")

__all__ = ["METHODS", "make_method"]


def make_method(name: str, context: BackendContext) -> AssociationMethod:
    if name == "known":
        from pipeline.backend.methods.known import KnownAssociation

        return KnownAssociation(context)
    if name == "ml":
        from pipeline.backend.methods.ml import MaximumLikelihood

        return MaximumLikelihood(context)
    if name == "gpda":
        from pipeline.backend.methods.gpda import GaussianPDA

        return GaussianPDA(context)
    if name in ("mm", "mm-nh"):
        from pipeline.backend.methods.maxmixture import MaxMixture

        return MaxMixture(context, null_hypothesis=name == "mm-nh")
    if name == "dcsam":
        from pipeline.backend.methods.dcsam import DiscreteContinuous

        return DiscreteContinuous(context)
    raise ValueError(f"unknown association method {name!r}; choose from {', '.join(METHODS)}")
