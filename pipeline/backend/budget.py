"""A budget of search nodes that several searches share: what bounds a merge check's work, and
a keyframe's joint association's, however many pairs or detections they hold.

A search that finds the budget spent stops unfinished, and its caller takes the safe answer
an unfinished search gives: no merge (each landmark stays one of its own), or the null for
every detection of the keyframe (each starts a landmark of its own, for a merge to join later).
Each node costs at most a bounded amount of arithmetic (the sets it scores are bounded too), so
the nodes bound the time."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class SearchBudget:
    """`nodes` to spend; `spent` so far."""

    nodes: int
    spent: int = 0

    def spend(self, nodes: int = 1) -> bool:
        """Spend `nodes` if that many are left (and say so); else spend nothing: the budget is
        exhausted from then on."""
        if self.spent + nodes > self.nodes:
            self.spent = self.nodes
            return False
        self.spent += nodes
        return True

    @property
    def exhausted(self) -> bool:
        return self.spent >= self.nodes
