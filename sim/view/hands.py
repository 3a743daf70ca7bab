"""What the view draws of each hand (`HandState`), made by a run's visual step (sim/run.py) and
drawn by the window (sim/view/window.py): its own module, so that a run builds them without
loading the window's OpenGL."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class HandState:
    """What the view draws of one hand."""

    position: tuple
    force: tuple = (0.0, 0.0, 0.0)
    grasped_vertex: int | None = None  # its patch is coloured
    holding: bool = False  # the jaws are closed on tissue (also when no patch is coloured: the analyst's pictures)
    target: object = None  # a sim.targets.TargetState: where the hand's target is, the progress towards it

    @property
    def closed(self) -> bool:
        return self.holding or self.grasped_vertex is not None


def hand_states(hands, targets=None) -> list[HandState]:
    """What the participant view draws of a visual step's hands (sim.servo.loop.Hand) and their
    targets (a sim.targets.TargetTracker)."""
    return [HandState(h.position, h.force, h.contact.vertex if h.contact is not None else None,
                      target=targets.states[i] if targets is not None else None) for i, h in enumerate(hands)]
