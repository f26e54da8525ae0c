"""`dcsam`: discrete-continuous smoothing and mapping over the same candidates (`method.py`),
its per-detection modes (`model.py`) and the discrete step over them (`discrete_step.py`)."""

from pipeline.backend.methods.dcsam.method import DiscreteContinuous

__all__ = ["DiscreteContinuous"]
