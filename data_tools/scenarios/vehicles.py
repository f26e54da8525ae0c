"""The vehicle types of the street scenarios (`city-grid`, `kitti05-cars`): what they are
called, how often each occurs, and the classes a log names them by."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from pipeline.settings import positive


@dataclass(frozen=True)
class VehicleType:
    """A kind of vehicle in a scenario's world: its name, and how often it occurs (relative to
    the other kinds)."""

    name: str
    frequency: Annotated[float, positive(1.0)]


def type_shares(vehicles: Sequence[VehicleType]) -> np.ndarray:
    """Each vehicle type's share of the vehicles: its frequency over all of theirs."""
    frequencies = np.array([v.frequency for v in vehicles])
    return frequencies / frequencies.sum()


def vehicle_class_names(vehicles: Sequence[VehicleType], num_classes: int) -> list[str]:
    """Vehicle type k is class k mod C; a class's name lists the types it holds."""
    names = []
    for c in range(num_classes):
        members = [v.name for k, v in enumerate(vehicles) if k % num_classes == c]
        names.append("+".join(members) if members else f"class-{c}")
    return names
