"""WorldChangesSource: one car's changed world (boxes, walkers, a closed door) in a diagram.

A thin wrapper over :class:`topodrake.world.changes.CarChanges` (a batch of
one car; the batched engine steps the same object for N cars).

Timing (10 Hz, as the engine). The sensors of period ``k`` (sampled at
``t_k``) see the walkers where they are in period ``k``; the walkers move
after the car's step ``k``, given where that step took it. The abstract
state holds the changes of the last committed period and how many moves
they made. The period's changes are a cache entry: the held ones, moved
once more from the car's pose where a period began since the last move
(at ``t_k``, before the commit). A periodic unrestricted update at ``t_k``
commits them, so the camera (an unrestricted update at ``t_k``, which sees
the context before it) and the lidar (a discrete update, after it) read the
same faces. Between ``t_k`` and the commit at ``t_k+1`` the held changes
are period ``k``'s: the runner's collision check at ``t_k+1`` reads them
(:meth:`WorldChangesSource.touching`), as the engine checks the car's step
``k`` against the walkers it saw.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem, ValueProducer

from topodrake.vehicle import VehicleConfig
from topodrake.world.changes import CarChanges


def no_changes() -> CarChanges:
    """One car's unchanged world."""
    return CarChanges(np.zeros((1, 0, 8)))


@dataclass
class HeldChanges:
    """One car's changes and the moves its walkers made (one per period)."""

    changes: CarChanges = field(default_factory=no_changes)
    moves: int = 0

    def __deepcopy__(self, memo) -> "HeldChanges":
        # a context's copy: the walkers' grid (the world's, read-only) stays shared
        return HeldChanges(self.changes.take([0]), self.moves)


class WorldChangesSource(LeafSystem):
    """Input ``pose`` (the car's, 3); outputs ``faces`` ((F, 8) render rows
    of what the car meets now, the sensors' ``extra``) and ``changes`` (the
    :class:`~topodrake.world.changes.CarChanges` of now, for the viewer;
    read it, never change it). A run sets the car's changes with
    :meth:`set_changes`; without, the world is unchanged."""

    def __init__(self, period: float = 0.1):
        super().__init__()
        self.period = float(period)
        self.pose_port = self.DeclareVectorInputPort("pose", 3)
        self.held_index = self.DeclareAbstractState(AbstractValue.Make(HeldChanges()))
        prereq = {self.time_ticket(), self.input_port_ticket(self.pose_port.get_index()),
                  self.abstract_state_ticket(self.held_index)}
        self._now = self.DeclareCacheEntry(
            "now", ValueProducer(allocate=lambda: AbstractValue.Make(HeldChanges()),
                                 calc=self._calc_now), prereq)
        ticket = {self._now.ticket()}
        self.faces_port = self.DeclareAbstractOutputPort(
            "faces", lambda: AbstractValue.Make(np.zeros((0, 8))),
            lambda c, o: o.set_value(self.now(c).faces([0])[0]), prerequisites_of_calc=ticket)
        self.changes_port = self.DeclareAbstractOutputPort(
            "changes", lambda: AbstractValue.Make(no_changes()),
            lambda c, o: o.set_value(self.now(c)), prerequisites_of_calc=ticket)
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.period, 0.0, self._commit)

    def set_changes(self, context, changes: CarChanges | None) -> None:
        """The car's changes for a run (a :class:`CarChanges` of one car,
        as placed; None: none), from the run's start."""
        if changes is not None and len(changes) != 1:
            raise ValueError(f"a WorldChangesSource holds one car's changes, got {len(changes)}")
        held = HeldChanges() if changes is None else HeldChanges(changes.take([0]))
        context.get_mutable_abstract_state(self.held_index).set_value(held)

    def held(self, context) -> CarChanges:
        """The changes of the last committed period (the car's last step is checked on them)."""
        return context.get_abstract_state(self.held_index).get_value().changes

    def now(self, context) -> CarChanges:
        """The changes the car meets in the period that begins at or before now."""
        return self._now.Eval(context).changes

    def touching(self, context, state, vehicle: VehicleConfig) -> bool:
        """Does the car at ``state`` (5) touch the held changes?"""
        x = np.asarray(state, np.float64).reshape(1, -1)
        return bool(self.held(context).touching([0], x, vehicle)[0])

    def _calc_now(self, context, value):
        held = context.get_abstract_state(self.held_index).get_value()
        period = int(np.floor(context.get_time() / self.period + 1e-6))
        if period <= held.moves:
            value.set_value(held)
            return
        changes = held.changes
        if changes.moving:
            changes = changes.take([0])
            changes.step(self.period, [0], np.asarray(self.pose_port.Eval(context))[None, :2])
        value.set_value(HeldChanges(changes, held.moves + 1))

    def _commit(self, context, state):
        now = self._now.Eval(context)
        if now.moves == context.get_abstract_state(self.held_index).get_value().moves:
            return EventStatus.DidNothing()          # nothing moved before the first period
        state.get_mutable_abstract_state(self.held_index).set_value(now)
        return EventStatus.Succeeded()
