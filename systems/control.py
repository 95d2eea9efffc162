"""RmpController and ExpertWaypoints."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from topodrake.control import controls_toward
from topodrake.expert import (
    MEMORY_SIZE,
    ExpertConfig,
    PackedPaths,
    expert_waypoints,
    initial_memory,
)
from topodrake.navigation.manoeuvre import Manoeuvres
from topodrake.rmp import RmpConfig
from topodrake.sensing.config import LidarConfig
from topodrake.sensing.lidar import Lidar
from topodrake.sensing.scene import scene_of
from topodrake.vehicle import VehicleConfig


class RmpController(LeafSystem):
    """Inputs ``state`` (held car state), ``waypoint`` (world xy), ``ranges``
    (held lidar); output ``controls``. Direct feedthrough of held signals, so
    the controls are constant over each control period and evaluated once."""

    def __init__(self, lidar: LidarConfig | None = None, rmp: RmpConfig | None = None,
                 vehicle: VehicleConfig | None = None):
        super().__init__()
        self.lidar = lidar or LidarConfig()
        self.rmp = rmp or RmpConfig()
        self.vehicle = vehicle or VehicleConfig()
        self.state_port = self.DeclareVectorInputPort("state", 5)
        self.waypoint_port = self.DeclareVectorInputPort("waypoint", 2)
        self.ranges_port = self.DeclareVectorInputPort("ranges", self.lidar.beams)
        # Depends on the held inputs only (not time or continuous state), so it
        # is computed once per control period, not at every integrator stage.
        self.controls_port = self.DeclareVectorOutputPort(
            "controls", 2, self._calc, prerequisites_of_calc={
                self.input_port_ticket(p.get_index())
                for p in (self.state_port, self.waypoint_port, self.ranges_port)})

    def _calc(self, context, output):
        u = controls_toward(self.state_port.Eval(context)[None],
                            self.waypoint_port.Eval(context)[None],
                            self.ranges_port.Eval(context)[None],
                            self.lidar, self.rmp, self.vehicle)
        output.SetFromVector(u[0])


class ExpertWaypoints(LeafSystem):
    """A* from the car's initial pose to the ``goal`` parameter (planned at
    initialization, kept in abstract state), then at 10 Hz the expert's
    waypoint (:func:`topodrake.expert.expert_waypoints`, the function the
    batched engine calls). Output ``waypoint`` (world xy).

    Discrete state: ``[progress, waypoint x, waypoint y, memory...]`` with
    the expert's per-car memory (:data:`topodrake.expert.MEMORY_COLUMNS`).
    The expert sees the lidar scan of the pose (from its own
    :class:`~topodrake.sensing.lidar.Lidar`, the function the LidarSensor
    calls, so the same ranges). ``lidar``, ``rmp`` and ``vehicle`` are what
    the expert's prediction models; pass the ones the diagram's sensor,
    controller and car use."""

    def __init__(self, world, goal=(0.0, 0.0), config: ExpertConfig | None = None,
                 period: float = 0.1, lidar: LidarConfig | None = None,
                 rmp: RmpConfig | None = None, vehicle: VehicleConfig | None = None):
        super().__init__()
        self.world = world
        self.config = config or ExpertConfig()
        self.lidar = Lidar(world, lidar or LidarConfig())
        self.rmp = rmp or RmpConfig()
        self.vehicle = vehicle or VehicleConfig()
        self.pose_port = self.DeclareVectorInputPort("pose", 3)
        self.goal_index = self.DeclareNumericParameter(BasicVector(np.asarray(goal, float)[:2]))
        self.path_index = self.DeclareAbstractState(
            AbstractValue.Make(PackedPaths.pack([np.zeros((1, 2))])))
        self.wp_index = self.DeclareDiscreteState(3 + MEMORY_SIZE)
        self.waypoint_port = self.DeclareVectorOutputPort(
            "waypoint", 2, self._output, prerequisites_of_calc={self.xd_ticket()})
        self.DeclareInitializationUnrestrictedUpdateEvent(self._plan)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

    def set_goal(self, context, goal) -> None:
        context.get_mutable_numeric_parameter(self.goal_index).SetFromVector(
            np.asarray(goal, float)[:2])

    def _plan(self, context, state):
        pose = self.pose_port.Eval(context)
        goal = context.get_numeric_parameter(self.goal_index).CopyToVector()
        path = self.world.astar(pose, goal)
        state.get_mutable_abstract_state(self.path_index).set_value(PackedPaths.pack([path]))
        state.get_mutable_discrete_state(self.wp_index).SetFromVector(
            [0.0, *path[0], *initial_memory(pose[None, :3])[0]])

    def _update(self, context, discrete_state):
        packed = context.get_abstract_state(self.path_index).get_value()
        pose = self.pose_port.Eval(context)
        held = context.get_discrete_state(self.wp_index).get_value()
        memory = np.array(held[3:])[None]
        ranges = self.lidar.scan(pose[None, :3])
        wp, prog = expert_waypoints(self.world.grid, packed, np.array([int(held[0])]),
                                    pose[None, :3], self.config, memory=memory, ranges=ranges,
                                    lidar=self.lidar.config, scene=scene_of(self.world),
                                    rmp=self.rmp, vehicle=self.vehicle)
        discrete_state.set_value(self.wp_index, np.array([prog[0], *wp[0], *memory[0]]))

    def _output(self, context, output):
        output.SetFromVector(context.get_discrete_state(self.wp_index).get_value()[1:3])


class ManoeuvreGuard(LeafSystem):
    """Between the follower's waypoint and the RmpController: the expert's
    closed-loop check and manoeuvre search on the map the car has sensed
    (:class:`topodrake.navigation.manoeuvre.Manoeuvres`, the object the
    batched engine steps, here for one car). Inputs ``state`` (held),
    ``waypoint`` (the follower's, world xy), ``ranges`` (held lidar);
    output ``waypoint``. ``config``: the manoeuvre settings (the follower's
    ``manoeuvre``; default: their defaults).

    Timing as FollowerFsm's: the period's decision is a cache entry of the
    held inputs and the abstract state (the car's kept scans and expert
    memory), committed by a periodic unrestricted update at the start of
    the next period."""

    def __init__(self, lidar: LidarConfig | None = None, rmp: RmpConfig | None = None,
                 vehicle: VehicleConfig | None = None, period: float = 0.1, config=None):
        from pydrake.systems.framework import ValueProducer

        super().__init__()
        self.config = config
        self.lidar = lidar or LidarConfig()
        self.rmp = rmp or RmpConfig()
        self.vehicle = vehicle or VehicleConfig()
        self.period = float(period)
        self.state_port = self.DeclareVectorInputPort("state", 5)
        self.waypoint_in_port = self.DeclareVectorInputPort("waypoint", 2)
        self.ranges_port = self.DeclareVectorInputPort("ranges", self.lidar.beams)
        self.memory_index = self.DeclareAbstractState(AbstractValue.Make(None))
        prereq = {self.input_port_ticket(p.get_index())
                  for p in (self.state_port, self.waypoint_in_port, self.ranges_port)}
        prereq.add(self.abstract_state_ticket(self.memory_index))
        self._decision = self.DeclareCacheEntry(
            "decision", ValueProducer(allocate=lambda: AbstractValue.Make((None, None)),
                                      calc=self._decide), prereq)
        self.waypoint_port = self.DeclareVectorOutputPort(
            "waypoint", 2, lambda c, o: o.SetFromVector(self.decision(c)[1]),
            prerequisites_of_calc={self._decision.ticket()})
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.period, 0.0, self._commit)

    def decision(self, context):
        return self._decision.Eval(context)

    def _decide(self, context, value):
        import copy


        pose = np.asarray(self.state_port.Eval(context))[None, :3]
        held = context.get_abstract_state(self.memory_index).get_value()
        man = copy.deepcopy(held) if held is not None else \
            Manoeuvres(1, pose, self.lidar, self.config, rmp=self.rmp, vehicle=self.vehicle)
        wp = man.step(np.zeros(1, np.int64), pose, self.waypoint_in_port.Eval(context)[None],
                      np.asarray(self.ranges_port.Eval(context))[None])
        value.set_value((man, wp[0]))

    def _commit(self, context, state):
        from pydrake.systems.framework import EventStatus

        if context.get_time() < 0.5 * self.period:
            return EventStatus.DidNothing()      # nothing decided before the first period
        state.get_mutable_abstract_state(self.memory_index).set_value(self.decision(context)[0])
        return EventStatus.Succeeded()
