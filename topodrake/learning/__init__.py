"""Learning: the waypoint network C_WP, the reachability estimator RE, and the follower's states.

Import modules directly; no package here imports anything heavy.

Shared by C_WP and RE (RE is the C_WP network with one logit), at this level:

* :mod:`~topodrake.learning.samples`    expert trajectories; C_WP samples from them
* :mod:`~topodrake.learning.data`       batches rendered from poses on the fly
* :mod:`~topodrake.learning.networks`   the network (camera / lidar), split first layer
* :mod:`~topodrake.learning.inference`  the lean batch-1 inference path
* :mod:`~topodrake.learning.config`     TrainConfig, YAML loading
* :mod:`~topodrake.learning.checkpoint` checkpoint files, checked loading
* :mod:`~topodrake.contract.frames`, :mod:`~topodrake.learning.tagged`,
  :mod:`~topodrake.learning.trajpack`   context frames, small tagged checkpoints, packed drives
* :mod:`~topodrake.experiments.bench_learning`      training / inference throughput of C_WP and RE
* :mod:`~topodrake.apps.train_cli`        the ``train`` and ``bench`` parsers

Subpackages, one idea each:

* :mod:`~topodrake.learning.waypoint`      C_WP: training (``train``; ``scale``, GPU at scale),
  policies (``policy``), the controlled-error oracle (``noisy_oracle``), evaluation pairs
  (``evaluation``)
* :mod:`~topodrake.learning.reachability`  RE: the estimator (``estimator``), rollout labels
  (``labels``), training (``train``), calibration (``calibration``), the controller an RE
  describes (``controllers``)
* :mod:`~topodrake.learning.onpolicy`      the follower's own states (``states``): DAgger
  (``dagger``), RE labels there (``reach_labels``), RE calibrated there (``calibration``,
  its file ``platt``), the benchmark on them (``bench``)
"""
