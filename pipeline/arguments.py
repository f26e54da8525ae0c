"""Argument types that the `mmslam` command line and the data tools' own command lines share,
so that a tool need not import the command line (it sits above everything)."""

from __future__ import annotations

import argparse

from pipeline.backend.methods import METHODS


def method_list(text: str) -> list[str]:
    """An argparse type: `known,ml,mm-nh`, each a method, none twice."""
    methods = [m.strip() for m in text.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if not methods or unknown:
        raise argparse.ArgumentTypeError(
            f"expected methods from {', '.join(METHODS)}, comma-separated; got {text!r}"
        )
    if len(set(methods)) != len(methods):
        raise argparse.ArgumentTypeError(f"a method is named twice in {text!r}")
    return methods
