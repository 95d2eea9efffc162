"""FollowerFsm: the follower state machine as a Drake system, and WaypointSelect.

A thin wrapper over :func:`topodrake.navigation.follower.follower_step`
(batch of one; the batched engine calls the same function for N cars).

Timing (10 Hz, sample and hold). The period's decision is a cache entry
computed from the held observation, the held car state and the follower's
abstract state (a :class:`~topodrake.navigation.follower.FollowerState` of
one car: mode, active and last visited anchor, the held waypoint, counters,
and a stateful C_WP's per-car track, which the decision updates from the held
car state as odometry),
never from time or the continuous state: it is computed once per period from
the observation sampled at the period's start. A periodic unrestricted
update at the end of each period (the start of the next) commits it, and
ends the run with ``EventStatus.ReachedTermination`` when the follower
reached the last anchor or gave up. The route's anchor features are
computed once at construction (per route, not state).

Replanning (optional, ``replanner``: a
:class:`~topodrake.navigation.replan.Replanner` of one car, the same the
batched engine calls): the commit asks it after each decision; a route it
accepts (only where Search would pass on it from the held observation,
as in the engine) is encoded once and kept in the system's append-only list of
routes, the abstract state ``route`` (its index; 0 = the route given at
construction) switches to it and the follower starts again in Search (or,
for a plan from the anchor the car returns to, dead reckoning back to it:
the replanner's ``return_to_anchor``). The
replanner's bookkeeping (tries, excluded edges) lives in that object, one
per run (:class:`~topodrake.systems.navigation.NavigationRunner` resets it).

Outputs: ``target`` (the active anchor's
:class:`~topodrake.learning.waypoint.policy.TargetContext` for WaypointNet; key = the
anchor index, -1 = none; it carries the anchor's C_WP features and C_WP's
answer toward it from the period's observation, which the decision already
computed, so WaypointNet does not run the network again), ``held_waypoint``
(the Dead reckoning waypoint, NaN otherwise) and ``mode`` (1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem, ValueProducer

from topodrake.contract.waypoint import TargetContext, WaypointPrediction
from topodrake.navigation.evaluate import (
    Evaluator,
    encode_routes,
    initial_track,
    network_context,
    take_rows,
)
from topodrake.navigation.follower import (
    MODES,
    REASONS,
    FollowerConfig,
    FollowerState,
    Mode,
    follower_step,
)
from topodrake.navigation.replan import kept_features, search_would_start
from topodrake.sensing.config import CameraConfig, LidarConfig


class FollowerFsm(LeafSystem):
    """Inputs ``observation`` (camera image / lidar ranges; absent for pose
    oracles), ``state`` (held car state, 5), for a camera C_WP ``ranges``
    (the car's lidar scan, optional) and, with ``odometry_input``,
    ``odometry`` (the car's odometry state, 5, from
    :class:`~topodrake.systems.odometry.OdometrySensor`): the follower then
    decides on the odometry pose, as the engine does under drifting
    odometry, and its waypoints are in the odometry frame (the pose oracles
    still read ``state``)."""

    def __init__(self, route, policy, reach, config: FollowerConfig | None = None,
                 period: float = 0.1, camera=None, lidar=None, replanner=None,
                 odometry_input: bool = False):
        super().__init__()

        self.route = route
        self.policy = policy
        self.reach = reach
        self.config = (config or FollowerConfig()).check()
        if replanner is not None:
            replanner.schedule.check_against(self.config.dead_reckoning.dr_max_iterations)
        self.replanner = replanner
        self._routes: list[_EncodedRoute] = []
        self._encode(route)
        kind = policy.observation
        # a pose oracle RE may stand beside a sensing C_WP (it reads the held car state)
        if reach.observation not in (kind, "pose"):
            raise ValueError(f"C_WP observes {kind}, RE {reach.observation}")
        self.kind = kind
        self.lidar = (lidar or getattr(policy, "sensor", None) or LidarConfig()) \
            if kind == "lidar" else (lidar or LidarConfig())
        if kind == "camera":
            c = camera or getattr(policy, "sensor", None) or CameraConfig()
            self.observation_port = self.DeclareAbstractInputPort(
                "observation", AbstractValue.Make(np.zeros((c.height, c.width, 3), np.uint8)))
        elif kind == "lidar":
            self.observation_port = self.DeclareVectorInputPort("observation", self.lidar.beams)
        else:
            self.observation_port = None
        # a camera car's lidar scan, for the route tracker's scan fixes on routes that keep
        # their anchors' scans (optional: unconnected, no fixes)
        self.ranges_port = self.DeclareVectorInputPort("ranges", self.lidar.beams) \
            if kind == "camera" else None
        self.state_port = self.DeclareVectorInputPort("state", 5)
        self.odometry_port = self.DeclareVectorInputPort("odometry", 5) if odometry_input \
            else None
        self.fsm_index = self.DeclareAbstractState(AbstractValue.Make(self._initial_state()))
        self.route_index = self.DeclareAbstractState(AbstractValue.Make(0))
        prereq = {self.input_port_ticket(p.get_index())
                  for p in (self.state_port, self.observation_port, self.ranges_port,
                            self.odometry_port)
                  if p is not None}
        prereq.add(self.abstract_state_ticket(self.fsm_index))
        prereq.add(self.abstract_state_ticket(self.route_index))
        self._decision = self.DeclareCacheEntry(
            "decision", ValueProducer(allocate=lambda: AbstractValue.Make((None, None)),
                                      calc=self._calc_decision), prereq)
        ticket = {self._decision.ticket()}
        self.target_port = self.DeclareAbstractOutputPort(
            "target", lambda: AbstractValue.Make(TargetContext()), self._out_target,
            prerequisites_of_calc=ticket)
        self.held_waypoint_port = self.DeclareVectorOutputPort(
            "held_waypoint", 2, self._out_held, prerequisites_of_calc=ticket)
        self.mode_port = self.DeclareVectorOutputPort(
            "mode", 1, lambda c, o: o.SetFromVector([float(self.decision(c)[0].mode[0])]),
            prerequisites_of_calc=ticket)
        # Same event times as the sensors and the ZeroOrderHold (offset 0), so the
        # commit at t_k is simultaneous with their samples and reads the held
        # values of period k-1; an offset of one period computes the times
        # differently and rounding put some commits after the samples.
        self.period = float(period)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._commit)

    def _encode(self, route, features=None) -> None:
        """Keep ``route`` with its features (:func:`encode_routes`; computed
        when not given)."""
        wide = self.policy if self.policy.k >= self.reach.k else self.reach
        base = self._routes[-1].key_base + len(self._routes[-1].route) if self._routes else 0
        if features is None:
            features = encode_routes([route], self.policy, self.reach,
                                     legs_m=self.config.tracker.legs_m)
        self._routes.append(_EncodedRoute(
            route, features, network_context(route.contexts, wide.k, wide.frame_step, self.policy),
            base))

    def _startable(self, context, car: np.ndarray, encoded: dict):
        """``startable(row, route)`` for the replanner, as the batched engine's
        (:func:`~topodrake.navigation.replan.search_would_start` from the
        held observation; the route and its encoding kept in ``encoded`` under
        ``id(route)``)."""
        obs, ranges = self._held_observations(context)

        odo = self._odometry(context, car)

        def startable(_row: int, route) -> bool:
            ok, feats = search_would_start(self.policy, self.reach, route, obs, car[:, :3],
                                           ranges, self.lidar, self.config,
                                           odometry=odo[:, :3])
            encoded[id(route)] = (route, feats)      # the route kept: its id stays its own
            return ok
        return startable

    def _held_observations(self, context):
        """(the held observation (1, ...) or None, the held lidar scan (1, beams) or None)."""
        obs = None if self.observation_port is None else \
            np.asarray(self.observation_port.Eval(context))[None]
        ranges = None
        if self.ranges_port is not None and self.ranges_port.HasValue(context):
            ranges = np.asarray(self.ranges_port.Eval(context))[None]
        return obs, ranges

    def _odometry(self, context, car: np.ndarray) -> np.ndarray:
        """The car's odometry state (1, 5): the ``odometry`` input, else the held state."""
        return car if self.odometry_port is None else \
            np.asarray(self.odometry_port.Eval(context))[None]

    def _initial_state(self) -> FollowerState:
        return FollowerState.initial(1, initial_track(self.policy, 1))

    def follower_state(self, context) -> FollowerState:
        return context.get_abstract_state(self.fsm_index).get_value()

    def current_route(self, context):
        """The route the follower drives in ``context`` (a replanned one, or
        the route given at construction)."""
        return self._routes[self._route_of(context)].route

    def _route_of(self, context) -> int:
        return int(context.get_abstract_state(self.route_index).get_value())

    def decision(self, context):
        """(the follower's state after this period, its StepOutput)."""
        return self._decision.Eval(context)

    def _calc_decision(self, context, value):
        state = self.follower_state(context)
        car = np.asarray(self.state_port.Eval(context))[None]
        obs, ranges = self._held_observations(context)
        feats = self._routes[self._route_of(context)].features
        odo = self._odometry(context, car)
        ev = Evaluator(self.policy, self.reach, feats, np.zeros(1, np.int64), obs,
                       poses=car[:, :3], track=state.track, odometry=odo[:, :3],
                       lidar=self.lidar, ranges=ranges)
        fs, out = follower_step(state, feats.n_anchors, odo, ev, self.config)
        fs.track = ev.track
        value.set_value((fs, out))

    def _out_target(self, context, output):
        fs, out = self.decision(context)
        a = int(out.target[0])
        if a < 0:
            output.set_value(TargetContext())
            return
        enc = self._routes[self._route_of(context)]
        ctx = enc.policy_contexts[a]
        pose = self.kind == "pose"
        # C_WP's answer toward this anchor from this period's observation,
        # which the decision already holds: WaypointNet need not ask again
        observed = (np.asarray(self.state_port.Eval(context))[:3] if pose
                    else np.asarray(self.observation_port.Eval(context)))
        prediction = None
        if np.all(np.isfinite(out.local[0])) and np.isfinite(out.heading[0]):
            prediction = WaypointPrediction(out.local[:1].copy(), out.heading[:1].copy(),
                                            out.overlap[:1].copy())
        output.set_value(TargetContext(
            key=enc.key_base + a, observations=None if pose else ctx, poses=ctx if pose else None,
            by=self.policy, features=take_rows(enc.features.cwp, np.array([a])),
            prediction=prediction, observed=observed.copy()))

    def _out_held(self, context, output):
        fs, out = self.decision(context)
        wp = out.waypoint[0] if out.held[0] else np.full(2, np.nan)
        output.SetFromVector(wp)

    def _commit(self, context, state):
        if context.get_time() < 0.5 * self.period:
            return EventStatus.DidNothing()      # nothing decided before the first period
        fs, _ = self.decision(context)
        fs = fs.copy()
        if self.replanner is not None:
            car = np.asarray(self.state_port.Eval(context))[None]
            encoded: dict = {}
            for _, new, start in self.replanner.step(
                    np.zeros(1, np.int64), fs, car[:, :3],
                    startable=self._startable(context, car, encoded), fresh=self._initial_state,
                    odometry=self._odometry(context, car)[:, :3]):
                self._encode(new, kept_features(encoded, new))
                state.get_mutable_abstract_state(self.route_index).set_value(len(self._routes) - 1)
                fs = start
        state.get_mutable_abstract_state(self.fsm_index).set_value(fs)
        m = int(fs.mode[0])
        if m == Mode.REACHED:
            return EventStatus.ReachedTermination(self, "reached the last anchor")
        if m == Mode.FAILED:
            return EventStatus.ReachedTermination(self, REASONS[int(fs.reason[0])])
        return EventStatus.Succeeded()


@dataclass
class _EncodedRoute:
    route: object
    features: object          # RouteFeatures of this one route
    policy_contexts: np.ndarray
    key_base: int             # target keys of this route: key_base + anchor (unique over routes)


class WaypointSelect(LeafSystem):
    """The waypoint the RMP drives to: ``held`` (FollowerFsm's own waypoint:
    Dead reckoning's, or the route tracker's) when it is finite, else
    ``net`` (WaypointNet's)."""
    def __init__(self):
        super().__init__()
        self.net_port = self.DeclareVectorInputPort("net", 2)
        self.held_port = self.DeclareVectorInputPort("held", 2)
        self.waypoint_port = self.DeclareVectorOutputPort(
            "waypoint", 2, self._calc, prerequisites_of_calc={
                self.input_port_ticket(p.get_index()) for p in (self.net_port, self.held_port)})

    def _calc(self, context, output):
        held = self.held_port.Eval(context)
        output.SetFromVector(held if np.all(np.isfinite(held)) else self.net_port.Eval(context))


__all__ = ["FollowerFsm", "WaypointSelect", "MODES"]
