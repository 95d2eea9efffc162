"""The A* expert: waypoints along a planned path, for many cars at once.

Each car has an A* path to its goal (2-D, on the configuration-space grid;
paths of different lengths are packed into one array with offsets). Every
control step the expert

1. advances the car's progress index to the nearest path point a little
   ahead of it;
2. takes the *A* waypoint*: the farthest path point within ``lookahead_m``
   of path length that the car sees along a straight line keeping
   ``sight_margin_m`` more than the car's radius from walls (when the car
   itself stands closer than that to a wall, the bare c-space is used);
3. *predicts* the closed loop of this expert and the car's controller for
   ``horizon_s``: the same RMP (:func:`topodrake.rmp.rmp_car_controls`,
   noise-free), fed with the current lidar hits that lie within
   ``obstacle_range_m`` of the predicted car and inside the lidar's field of
   view, and the bicycle model; the waypoint is re-selected along the way
   as in step 2. The predicted body is checked on the clearance map. The A*
   waypoint is emitted when the prediction is collision-free and makes
   ``min_progress_m`` of progress along the path, or reaches the goal
   (which it must when the goal is closer than ``final_m``);
4. otherwise plans a *manoeuvre*: a leg of ``manoeuvre_s`` toward one of a
   ring of auxiliary waypoints around the car (ahead, to the sides, behind;
   the RMP reverses toward a waypoint behind, swinging its nose toward it),
   followed in the prediction by step 3 from the leg's end. It commits to
   the leg with the most predicted progress (or the earliest arrival at
   the goal), re-checking it against walls every step.

Why predict instead of geometry: the car turns with radius >= 0.425 m, but
the RMP does not drive circles of that radius. It stretches short waypoints
to 2 m, which under-steers near the goal (a goal inside the turning circle
is orbited for ever); it reverses whenever the waypoint is behind, with its
rear control points blind and the lidar covering only 240 deg forward; and
near a wall its nose repulsion can dominate the waypoint (a car parked
facing a wall backs up, whatever the waypoint says). Rolling out the
controller itself on the map -- the expert is an oracle: it has the grid,
its clearance map, the car's pose and the lidar -- catches exactly these
cases (a goal orbited instead of reached, a start facing a wall or with a
wall behind, a doorway entered too fast from a corridor, a furniture corner
cut by a straight sight line, a blind reversal into a wall), and the
manoeuvre search turns them into three-point turns checked against walls
the lidar cannot see. Where the prediction passes, which is nearly
everywhere, the expert is the plain farthest-visible-waypoint expert.

The expert sees the pose and the lidar (as in the Drake diagram), not the
speed and steering: those are estimated for the prediction from the
previous pose held in the car's ``memory`` (columns
:data:`MEMORY_COLUMNS`), which also holds the manoeuvre in progress. Both
executors (the batched engine and the Drake ``ExpertWaypoints``) carry
``progress`` and ``memory`` per car.
"""

from topodrake.expert.config import MEMORY_COLUMNS, MEMORY_SIZE, ExpertConfig, PackedPaths, initial_memory
from topodrake.expert.kernel import STATS, expert_waypoints, lidar_world_points
from topodrake.expert.sight import segment_clear

__all__ = ["ExpertConfig", "PackedPaths", "MEMORY_COLUMNS", "MEMORY_SIZE", "STATS",
           "expert_waypoints", "initial_memory", "lidar_world_points", "segment_clear"]
