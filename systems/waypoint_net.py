"""WaypointNet (C_WP as a Drake system), TargetSource, and the C_WP + RMP diagram.

WaypointNet is a thin wrapper over :mod:`topodrake.learning.waypoint.policy`: any
:class:`~topodrake.learning.waypoint.policy.WaypointPolicy` (the learned network or
the A* oracle) runs inside it.

Timing (10 Hz, sample and hold). Its inputs are held signals: the camera
image (or lidar ranges) that the sensors sample every period, the car state
held by a ZeroOrderHold, and the target. The prediction is a cache entry
that depends on those inputs and on the system's abstract state only, never
on time or the continuous state, so it is computed once per control period
(not at every integrator stage) from the observation sampled at the start
of the period, with no extra period of delay: the same order as the batched
engine (render, predict, control, step).

Target cache. The target half of the network (one tensor per anchor) lives
in abstract state as ``TargetCache(key, features)``. A periodic update
(same period) stores the features of the current target whenever the
target's ``key`` differs from the cached one; in the one period after a
target change the prediction encodes the new target on the fly. The policy
object holds weights only; nothing per-run is kept in ``self``.

A stateful C_WP (``track_size`` > 0, the registration C_WP) keeps its
per-car track in abstract state too. The period's prediction is computed
from a copy of it (with the held car state as odometry and the target's
``key`` as the anchor's) and carries the updated copy
(:class:`TrackedPrediction`); the periodic update at the end of the period
commits it, as the follower commits its decision, so the track sees each
period's observation once, as in the batched engine.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from topodrake.contract.waypoint import TargetContext, WaypointPrediction, target_input
from topodrake.navigation.evaluate import initial_track, track_size
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.vehicle import car_to_world
from topodrake.world import load_world


@dataclass
class TrackedPrediction(WaypointPrediction):
    """A stateful C_WP's prediction with its per-car track after it."""

    track: np.ndarray | None = None


@dataclass
class TargetCache:
    key: int = -2
    features: object = None


def _nan_prediction(direct: bool) -> WaypointPrediction:
    return WaypointPrediction(np.full((1, 2), np.nan), np.zeros(1), np.zeros((1, 2)),
                              np.zeros((1, 2)) if direct else None)


class TargetConditionedNet(LeafSystem):
    """Base of the systems that run a network on (current observation,
    cached target): the observation and ``target`` input ports, the target
    cache in abstract state with its periodic update, and a cache entry
    ``prediction`` computed once per period by :meth:`compute` (subclasses
    declare their outputs from :meth:`prediction`).

    ``network`` has ``observation`` ("camera", "lidar" or "pose"), an
    optional ``sensor`` and ``encode_target``."""

    def __init__(self, network, period: float, camera=None, lidar=None, state_input: bool = True,
                 odometry_input: bool = False):
        super().__init__()

        self.network = network
        kind = network.observation
        if kind == "camera":
            c = camera or getattr(network, "sensor", None) or CameraConfig()
            self.observation_port = self.DeclareAbstractInputPort(
                "observation", AbstractValue.Make(np.zeros((c.height, c.width, 3), np.uint8)))
        elif kind == "lidar":
            beams = (lidar or getattr(network, "sensor", None) or LidarConfig()).beams
            self.observation_port = self.DeclareVectorInputPort("observation", beams)
        elif kind == "pose":
            self.observation_port = None
        else:
            raise ValueError(f"unknown observation kind {kind!r}")
        if kind == "pose" and not state_input:
            raise ValueError("a pose-observing network needs the state input")
        self.target_port = self.DeclareAbstractInputPort("target", AbstractValue.Make(TargetContext()))
        self.state_port = self.DeclareVectorInputPort("state", 5) if state_input else None
        # the car's odometry state (5), where it drifts from the held state: a stateful
        # network tracks on it and the waypoint is given in its frame
        self.odometry_port = self.DeclareVectorInputPort("odometry", 5) \
            if odometry_input and state_input else None
        self.cache_index = self.DeclareAbstractState(AbstractValue.Make(TargetCache()))
        inputs = [p for p in (self.target_port, self.state_port, self.observation_port,
                              self.odometry_port)
                  if p is not None]
        prereq = {self.input_port_ticket(p.get_index()) for p in inputs}
        prereq.add(self.abstract_state_ticket(self.cache_index))
        self.period = float(period)
        self.track_index = None

        if track_size(network) > 0:
            if self.state_port is None:
                raise ValueError("a stateful network needs the state input (its odometry)")
            self.track_index = self.DeclareAbstractState(
                AbstractValue.Make(initial_track(network, 1)))
            prereq.add(self.abstract_state_ticket(self.track_index))
        self._prediction = self.DeclareCacheEntry(
            "prediction", ValueProducer(allocate=lambda: AbstractValue.Make(self.empty()),
                                        calc=self._calc_prediction), prereq)
        self.prediction_ticket = {self._prediction.ticket()}
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update_cache)

    # -- subclass interface ------------------------------------------------------
    def empty(self):
        """The prediction without a target (key < 0)."""
        raise NotImplementedError

    def compute(self, observation: np.ndarray, features):
        """The prediction for one observation (1, ...) and target features."""
        raise NotImplementedError

    def prediction(self, context):
        return self._prediction.Eval(context)

    # -- target features ---------------------------------------------------------
    def _features(self, context, target: TargetContext):
        if target.features is not None and target.by is self.network:
            return target.features
        cache = context.get_abstract_state(self.cache_index).get_value()
        if cache.key == target.key:
            return cache.features
        return self.network.encode_target(target_input(self.network, target))

    def _update_cache(self, context, state):
        if self.track_index is not None and context.get_time() >= 0.5 * self.period:
            # commit the track of the period that ends now (none before the first)
            pred = self.prediction(context)
            if isinstance(pred, TrackedPrediction) and pred.track is not None:
                state.get_mutable_abstract_state(self.track_index).set_value(pred.track.copy())
        target = self.target_port.Eval(context)
        cache = context.get_abstract_state(self.cache_index).get_value()
        if target.key < 0 or target.key == cache.key or (target.features is not None
                                                          and target.by is self.network):
            return
        feats = self.network.encode_target(target_input(self.network, target))
        if hasattr(feats, "numpy"):
            feats = feats.numpy().copy()
        state.get_mutable_abstract_state(self.cache_index).set_value(TargetCache(target.key, feats))

    def _calc_prediction(self, context, value):
        target = self.target_port.Eval(context)
        if target.key < 0:
            value.set_value(self.empty())
            return
        if self.observation_port is None:
            obs = self.state_port.Eval(context)[None, :3]
        else:
            obs = np.asarray(self.observation_port.Eval(context))[None]
        if self._reusable(target, obs):
            value.set_value(target.prediction)
            return
        feats = self._features(context, target)
        if self.track_index is not None:
            track = np.array(context.get_abstract_state(self.track_index).get_value(), np.float64)
            car = self.odometry(context)[None, :3]
            p = self.network.predict_tracked(obs, feats, track, np.zeros(1, np.int64),
                                             np.array([target.key], np.int64), car)
            value.set_value(TrackedPrediction(p.waypoint, p.heading_diff, p.overlap, p.controls,
                                              track))
            return
        value.set_value(self.compute(obs, feats))

    def odometry(self, context) -> np.ndarray:
        """The car's odometry state (5): the ``odometry`` input, else the held state."""
        port = self.odometry_port if self.odometry_port is not None else self.state_port
        return np.asarray(port.Eval(context))

    def _reusable(self, target: TargetContext, obs: np.ndarray) -> bool:
        """The target carries the answer this system would compute: made by
        the same network for this very observation."""
        return False


class WaypointNet(TargetConditionedNet):
    """Inputs: ``observation`` (camera: abstract (H, W, 3) uint8 image; lidar:
    vector of ranges; absent for the pose oracle, which reads ``state``),
    ``target`` (abstract :class:`TargetContext`), ``state`` (held car state,
    5) and, with ``odometry_input``, ``odometry`` (the car's odometry state,
    5; the waypoint is then in the odometry frame). Outputs: ``waypoint``
    (world xy, for RmpController), ``waypoint_local``
    (car frame), ``heading_diff`` (1), ``overlap`` (2), and ``controls`` (2)
    for a direct-control policy. Without a target (key < 0) the waypoint is
    NaN, which the RMP reads as "stop"."""
    def __init__(self, policy, period: float = 0.1, camera=None, lidar=None,
                 odometry_input: bool = False):
        self.policy = policy
        self.direct = bool(getattr(policy, "is_direct_control", False))
        super().__init__(policy, period, camera, lidar, odometry_input=odometry_input)
        ticket = self.prediction_ticket
        self.waypoint_port = self.DeclareVectorOutputPort("waypoint", 2, self._out_waypoint,
                                                          prerequisites_of_calc=ticket)
        self.waypoint_local_port = self.DeclareVectorOutputPort(
            "waypoint_local", 2, lambda c, o: o.SetFromVector(self.prediction(c).waypoint[0]),
            prerequisites_of_calc=ticket)
        self.heading_port = self.DeclareVectorOutputPort(
            "heading_diff", 1, lambda c, o: o.SetFromVector(self.prediction(c).heading_diff[:1]),
            prerequisites_of_calc=ticket)
        self.overlap_port = self.DeclareVectorOutputPort(
            "overlap", 2, lambda c, o: o.SetFromVector(self.prediction(c).overlap[0]),
            prerequisites_of_calc=ticket)
        self.controls_port = None
        if self.direct:
            self.controls_port = self.DeclareVectorOutputPort(
                "controls", 2, lambda c, o: o.SetFromVector(self.prediction(c).controls[0]),
                prerequisites_of_calc=ticket)

    def empty(self) -> WaypointPrediction:
        return _nan_prediction(self.direct)

    def compute(self, observation, features) -> WaypointPrediction:
        return self.policy.predict(observation, features)

    def _reusable(self, target: TargetContext, obs: np.ndarray) -> bool:
        # (the follower asked this policy toward this anchor in the same period)
        return (target.prediction is not None and target.by is self.policy and not self.direct
                and target.observed is not None and np.array_equal(target.observed, obs[0]))

    def _out_waypoint(self, context, output):
        local = self.prediction(context).waypoint[:1]
        state = self.odometry(context)
        output.SetFromVector(car_to_world(local[:, None], state[None])[0, 0])


class TargetSource(LeafSystem):
    """Outputs ``target``: a :class:`TargetContext` kept as a parameter of the
    Context, so each Monte Carlo trial sets its own with :meth:`set_target`."""

    def __init__(self, target: TargetContext | None = None):
        super().__init__()
        self.param_index = self.DeclareAbstractParameter(AbstractValue.Make(target or TargetContext()))
        self.target_port = self.DeclareAbstractOutputPort(
            "target", lambda: AbstractValue.Make(TargetContext()), self._calc,
            prerequisites_of_calc={self.all_parameters_ticket()})

    def set_target(self, context, target: TargetContext) -> None:
        context.get_mutable_abstract_parameter(self.param_index).set_value(target)

    def _calc(self, context, output):
        output.set_value(context.get_abstract_parameter(self.param_index).get_value())


@dataclass
class WaypointDiagram:
    diagram: object
    car: object
    waypoint_net: WaypointNet
    target_source: TargetSource
    pose_logger: object
    noise_logger: object
    world: object
    scenario: object
    extras: dict = field(default_factory=dict)


def build_waypoint_diagram(scenario, policy, world=None, target: TargetContext | None = None,
                           meshcat=None) -> WaypointDiagram:
    """CarPlant + sensors + WaypointNet (+ RmpController) + ActuationNoise.

    ::

        CarPlant --pose--> LidarSensor, CameraSensor (camera policies)
        CarPlant --state--> ZeroOrderHold --> WaypointNet, RmpController
        TargetSource --target--> WaypointNet --waypoint--> RmpController --> ActuationNoise --> CarPlant
        (a direct-control policy's ``controls`` go straight to ActuationNoise)

    Exported outputs: ``pose``, ``state``, ``waypoint``, ``overlap``,
    ``heading_diff``, ``controls``, ``ranges`` and (camera) ``image``.
    """
    from pydrake.systems.framework import DiagramBuilder
    from topodrake.systems.control import RmpController
    from topodrake.systems.diagram import add_chassis

    world = world or load_world(scenario.world)
    dt = scenario.vehicle.dt
    b = DiagramBuilder()
    c = add_chassis(b, scenario, world, camera=policy.observation == "camera", meshcat=meshcat)
    source = b.AddNamedSystem("target_source", TargetSource(target))
    net = b.AddNamedSystem("waypoint_net", WaypointNet(policy, dt, scenario.camera, scenario.lidar))
    b.Connect(c.hold.get_output_port(), net.state_port)
    b.Connect(source.target_port, net.target_port)
    if c.camera is not None:
        b.Connect(c.camera.image_port, net.observation_port)
    elif policy.observation == "lidar":
        b.Connect(c.lidar.ranges_port, net.observation_port)
    if net.direct:
        b.Connect(net.controls_port, c.noise.controls_port)
    else:
        rmp = b.AddNamedSystem("rmp", RmpController(scenario.lidar, scenario.rmp, scenario.vehicle))
        b.Connect(c.hold.get_output_port(), rmp.state_port)
        b.Connect(net.waypoint_port, rmp.waypoint_port)
        b.Connect(c.lidar.ranges_port, rmp.ranges_port)
        b.Connect(rmp.controls_port, c.noise.controls_port)
    b.ExportOutput(net.waypoint_port, "waypoint")
    b.ExportOutput(net.overlap_port, "overlap")
    b.ExportOutput(net.heading_port, "heading_diff")
    diagram = b.Build()
    diagram.set_name("topodrake_waypoint")
    return WaypointDiagram(diagram, c.car, net, source, c.pose_logger, c.noise_logger, world,
                           scenario)
