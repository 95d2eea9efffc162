"""Which controller a network or a label set describes, and loading an RE for it.

A controller is a C_WP checkpoint (named by its path and file SHA-1) or the
registration C_WP (``"registration"``, named by the SHA-1 of its settings
and lidar). RE checkpoints, label folders and cached runs record this
fingerprint, and :func:`load_reachability` refuses an RE trained for
another controller.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path

from topodrake.errors import TopodrakeError
from topodrake.fileio import check_intact, file_sha1
from topodrake.learning.waypoint.noisy_oracle import NoisyOracle, is_oracle_spec
from topodrake.registration.policy import RegistrationPolicy

#: The ``controller`` name of the registration C_WP (no checkpoint file).
REGISTRATION = "registration"


#: Registration settings that act only along a route's legs (the handover between anchors, a
#: search fit checked against a neighbouring anchor, the fit that slides taken at the route's
#: start), never in RE's label rollouts toward one
#: target: they stay out of the fingerprint, so an RE stays valid whatever they are.
FOLLOWER_ONLY = ("handover", "handover_m", "search_check_m", "start_slides")


def registration_identity(policy=None) -> dict:
    """The fingerprint of a registration C_WP (default settings when
    ``policy`` is None): ``{"checkpoint": "registration", "sha1": ...}``, the
    SHA-1 of its settings and lidar."""
    policy = policy or RegistrationPolicy()
    settings = {k: v for k, v in asdict(policy.config).items()
                if k not in FOLLOWER_ONLY}
    blob = json.dumps({"registration": settings, "lidar": asdict(policy.sensor)}, sort_keys=True)
    return {"checkpoint": REGISTRATION, "sha1": hashlib.sha1(blob.encode()).hexdigest()}


def registration_runs_key() -> str:
    """A key for cached runs of the registration C_WP: its default settings'
    fingerprint and a hash of the registration package's sources (a code
    change invalidates the runs, which a settings fingerprint alone would not)."""
    import topodrake.registration as package

    h = hashlib.sha1(registration_identity()["sha1"].encode())
    for f in sorted(Path(package.__file__).parent.glob("*.py")):
        h.update(f.read_bytes())
    return f"{REGISTRATION}-{h.hexdigest()[:16]}"


def controller_identity(path) -> dict:
    """``{"checkpoint", "sha1"}`` of a controller: a C_WP checkpoint's path
    and file SHA-1; for ``"registration"`` or a
    :class:`~topodrake.registration.policy.RegistrationPolicy`, the
    fingerprint of its settings (:func:`registration_identity`)."""
    if str(path) == REGISTRATION:
        return registration_identity()
    if getattr(path, "name", None) == REGISTRATION and hasattr(path, "config"):
        return registration_identity(path)
    if not isinstance(path, (str, Path)):
        raise TopodrakeError(f"a controller is a C_WP checkpoint path or {REGISTRATION!r}, got "
                             f"{type(path).__name__}")
    path = Path(path)
    if not path.is_file():
        raise TopodrakeError(f"controller checkpoint {path} does not exist")
    check_intact(path, "controller checkpoint")     # a damaged file is no controller
    return {"checkpoint": str(path), "sha1": file_sha1(path)}


def controller_policy(path, world=None):
    """The waypoint policy a controller name stands for: the registration
    C_WP for ``"registration"``, the A* oracle with a controlled error in
    ``world`` for an ``oracle[:KEY=VALUE...]`` spec
    (:mod:`topodrake.learning.waypoint.noisy_oracle`: it needs the world), else the
    C_WP checkpoint's network (a direct-control network is refused: RE
    needs a C_WP)."""
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    if is_oracle_spec(path):
        if world is None:
            raise TopodrakeError(f"C_WP {path!r} is the A* oracle of a world; name a checkpoint "
                                 f"here")
        return NoisyOracle(world, path)
    if str(path) == REGISTRATION:
        from topodrake.registration.policy import RegistrationPolicy

        return RegistrationPolicy()
    controller_identity(path)
    policy = LearnedWaypointPolicy.from_checkpoint(path)
    if policy.is_direct_control:
        raise TopodrakeError(f"{path} is a direct-control network; RE needs a C_WP")
    return policy


def checkpoint_temperature(meta: dict) -> float:
    """The temperature an RE checkpoint was calibrated with (1 if none)."""
    return float((meta.get("extra") or {}).get("temperature", 1.0))


def load_reachability(path, controller_checkpoint):
    """An RE checkpoint for ``controller_checkpoint`` (a C_WP checkpoint
    path, ``"registration"`` or a registration policy: see
    :func:`controller_identity`); an RE trained for another controller
    (other file contents, or other registration settings) is refused."""
    from topodrake.learning.checkpoint import load_checkpoint

    ck = load_checkpoint(path, output="reach")
    want = controller_identity(controller_checkpoint)
    have = (ck.meta.get("extra") or {}).get("controller") or {}
    if have.get("sha1") != want["sha1"]:
        raise TopodrakeError(f"reachability estimator {path} was trained for controller "
                             f"{have.get('checkpoint', 'unknown')!r} (sha1 {str(have.get('sha1'))[:10]}), "
                             f"not {want['checkpoint']!r} (sha1 {want['sha1'][:10]})")
    return ck
