"""The names of the tag classes, one convention for every log that holds tags: the front-end's
(`mmslam frontend`) and the simulated indoor run's (`mmslam simulate indoor-tags`)."""

from __future__ import annotations


def tag_class_names(num_classes: int) -> list[str]:
    """A tag's class is its id mod `num_classes`: `tag_mod2_0`, `tag_mod2_1` for two."""
    return [f"tag_mod{num_classes}_{k}" for k in range(num_classes)]
