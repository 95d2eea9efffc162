"""Builders that wire the LeafSystems into named Drake Diagrams."""

from __future__ import annotations

from dataclasses import dataclass

from pydrake.common import RandomDistribution
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, RandomSource, ZeroOrderHold
from topodrake.systems.car import ActuationNoise, CarPlant
from topodrake.systems.changes import WorldChangesSource
from topodrake.systems.control import ExpertWaypoints, RmpController
from topodrake.systems.scenario import Scenario
from topodrake.systems.sensors import CameraSensor, LidarSensor

from topodrake.world import load_world


@dataclass
class ExpertDiagram:
    """The built diagram and handles to the systems a run needs."""

    diagram: object
    car: CarPlant
    expert: ExpertWaypoints
    pose_logger: object
    noise_logger: object
    world: object
    scenario: Scenario


@dataclass
class Chassis:
    """The systems every navigation diagram shares, already connected:

    ``CarPlant --state--> ZeroOrderHold`` (``hold``), ``CarPlant --pose-->
    LidarSensor`` (and ``CameraSensor`` when asked), ``RandomSource -->
    ActuationNoise --> CarPlant``, Meshcat when given, and 10 Hz loggers of
    the pose and of the noise samples; with ``changes``, ``CarPlant --pose-->
    WorldChangesSource --faces--> LidarSensor, CameraSensor`` (the car's
    changed world; a run sets it). The caller connects something to
    ``noise.controls_port`` and builds."""

    builder: DiagramBuilder
    car: CarPlant
    hold: object
    lidar: LidarSensor
    camera: CameraSensor | None
    noise: ActuationNoise
    pose_logger: object
    noise_logger: object
    changes: WorldChangesSource | None = None


def add_chassis(b: DiagramBuilder, scenario: Scenario, world, *, camera: bool,
                meshcat=None, changes: bool = False) -> Chassis:
    dt = scenario.vehicle.dt
    car = b.AddNamedSystem("car", CarPlant(scenario.vehicle))
    hold = b.AddNamedSystem("state_hold", ZeroOrderHold(dt, 5))
    lidar = b.AddNamedSystem("lidar", LidarSensor(world, scenario.lidar, dt))
    noise = b.AddNamedSystem("actuation_noise", ActuationNoise(scenario.noise_std))
    rand = b.AddNamedSystem("noise_source", RandomSource(RandomDistribution.kGaussian, 2, dt))
    b.Connect(car.state_port, hold.get_input_port())
    b.Connect(car.pose_port, lidar.pose_port)
    b.Connect(rand.get_output_port(), noise.noise_port)
    b.Connect(noise.output_port, car.controls_port)
    b.ExportOutput(car.pose_port, "pose")
    b.ExportOutput(car.state_port, "state")
    b.ExportOutput(lidar.ranges_port, "ranges")
    b.ExportOutput(noise.output_port, "controls")
    cam = None
    if camera:
        cam = b.AddNamedSystem("camera", CameraSensor(world, scenario.camera, dt))
        b.Connect(car.pose_port, cam.pose_port)
        b.ExportOutput(cam.image_port, "image")
    source = None
    if changes:
        source = b.AddNamedSystem("world_changes", WorldChangesSource(dt))
        b.Connect(car.pose_port, source.pose_port)
        for sensor in (lidar, cam):
            if sensor is not None:
                b.Connect(source.faces_port, sensor.extra_port)
    if meshcat is not None:
        from topodrake.systems.visualization import MeshcatCar, MeshcatChanges

        from topodrake.sensing.scenegraph import add_meshcat_world, frame_whole_world

        add_meshcat_world(meshcat, world)
        frame_whole_world(meshcat, world)
        viz = b.AddNamedSystem("meshcat_car", MeshcatCar(meshcat, dt, scenario.lidar))
        b.Connect(car.pose_port, viz.pose_port)
        b.Connect(lidar.ranges_port, viz.ranges_port)
        if source is not None:
            shown = b.AddNamedSystem("meshcat_changes", MeshcatChanges(
                meshcat, dt, float(world.wall_height)))
            b.Connect(source.changes_port, shown.changes_port)
    pose_logger = LogVectorOutput(car.pose_port, b, dt)
    pose_logger.set_name("pose_log")
    noise_logger = LogVectorOutput(rand.get_output_port(), b, dt)
    noise_logger.set_name("noise_log")
    return Chassis(b, car, hold, lidar, cam, noise, pose_logger, noise_logger, source)


def build_expert_diagram(scenario: Scenario, world=None, meshcat=None) -> ExpertDiagram:
    """CarPlant + Lidar/Camera + ExpertWaypoints + RmpController + ActuationNoise.

    ::

        CarPlant --pose--> LidarSensor, CameraSensor, ExpertWaypoints
        CarPlant --state--> ZeroOrderHold --> RmpController
        ExpertWaypoints --waypoint--> RmpController <--ranges-- LidarSensor
        RmpController --> ActuationNoise <-- RandomSource;  ActuationNoise --> CarPlant

    Exported outputs: ``pose``, ``state``, ``waypoint``, ``ranges``,
    ``controls`` and (when the camera is enabled) ``image``.
    """
    world = world or load_world(scenario.world)
    b = DiagramBuilder()
    c = add_chassis(b, scenario, world, camera=scenario.camera_enabled, meshcat=meshcat)
    expert = b.AddNamedSystem("expert", ExpertWaypoints(world, config=scenario.expert,
                                                        period=scenario.vehicle.dt))
    rmp = b.AddNamedSystem("rmp", RmpController(scenario.lidar, scenario.rmp, scenario.vehicle))
    b.Connect(c.car.pose_port, expert.pose_port)
    b.Connect(c.hold.get_output_port(), rmp.state_port)
    b.Connect(expert.waypoint_port, rmp.waypoint_port)
    b.Connect(c.lidar.ranges_port, rmp.ranges_port)
    b.Connect(rmp.controls_port, c.noise.controls_port)
    b.ExportOutput(expert.waypoint_port, "waypoint")
    diagram = b.Build()
    diagram.set_name("topodrake_expert")
    return ExpertDiagram(diagram, c.car, expert, c.pose_logger, c.noise_logger, world, scenario)
