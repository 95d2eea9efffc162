"""Learning: the waypoint network C_WP, its samples, training and checkpoints.

Modules (import them directly; this package imports nothing heavy):

* :mod:`~topodrake.learning.samples`    C_WP samples from expert trajectories
* :mod:`~topodrake.learning.data`       batches rendered from poses on the fly
* :mod:`~topodrake.learning.networks`   the network (camera / lidar), split first layer
* :mod:`~topodrake.learning.config`     TrainConfig, YAML loading
* :mod:`~topodrake.learning.train`      training loop, validation, resume
* :mod:`~topodrake.learning.checkpoint` checkpoint files, checked loading
* :mod:`~topodrake.learning.policy`     WaypointPolicy protocol, learned policy, A* oracle
* :mod:`~topodrake.learning.bench`      training / inference throughput
* :mod:`~topodrake.learning.cli`        ``train waypoint`` and ``bench networks`` parsers
"""
