"""`mm` and `mm-nh`: semantic max-mixture factors (`method.py`), chosen between iSAM2 updates
or inside a custom factor (`mixture_factor.py`), a keyframe's detections first associated
together (`joint_association.py`)."""

from pipeline.backend.methods.maxmixture.method import MaxMixture

__all__ = ["MaxMixture"]
