"""Where maps come from: the shipped estimators and the demonstrations.

``make_scorer`` gives the reachability a map is built with: the shipped
learned RE of a modality (camera k=5 or lidar k=5, with the C_WP it was
trained for; ``lidar_reg``: the RE of the registration C_WP, which has no
checkpoint and is named ``registration``), explicit checkpoints, or the
geometric oracle. ``open_map`` opens a map file with the world, reachability,
checkpoints and plan calibration it was built for; ``load_networks`` the
C_WP and RE a follower drives with.
``demo_trajectories`` reads (collecting them first if needed) a world's
expert demonstrations and renders each drive's observations lazily.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from topodrake.demonstrations import collect, load_demos
from topodrake.errors import TopodrakeError
from topodrake.fileio import check_intact
from topodrake.learning.reachability.controllers import controller_policy
from topodrake.sensing.observe import lidar_scans, observe
from topodrake.topomap.mapfile import load_map, read_map_meta
from topodrake.topomap.plan_calibration import calibration_beside
from topodrake.topomap.scorer import LearnedScorer, OracleScorer
from topodrake.world import load_world
from topodrake.world.catalogue import same_world

ROOT = Path(__file__).resolve().parents[2]
#: map kind -> (RE checkpoint folder, C_WP checkpoint folder or "registration") shipped in
#: checkpoints/
SHIPPED = {"camera": ("reach_camera_k5", "camera_k5"), "lidar": ("reach_lidar_k5", "lidar_k5"),
           "lidar_reg": ("reach_lidar_reg", "registration")}
MODALITIES = ("camera", "lidar", "lidar_reg", "oracle")
#: the registration C_WP's name where a C_WP checkpoint would go
REGISTRATION = "registration"
#: what each map kind observes
OBSERVES = {"camera": "camera", "lidar": "lidar", "lidar_reg": "lidar"}


def shipped_checkpoint(name: str) -> Path:
    """``checkpoints/<name>/checkpoint.pt`` of this installation."""
    path = ROOT / "checkpoints" / name / "checkpoint.pt"
    if not path.is_file():
        raise TopodrakeError(f"shipped checkpoint {path} is missing")
    return path


def resolve_checkpoint(path) -> Path:
    """``path``; a relative path that does not exist from here but does in
    this installation (the shipped ``checkpoints/...``) resolves there."""
    p = Path(path)
    if not p.is_absolute() and not p.exists() and (ROOT / p).exists():
        return ROOT / p
    return p


def controller_checkpoint(controller):
    """A C_WP checkpoint path resolved as :func:`resolve_checkpoint` does;
    ``"registration"`` (the registration C_WP) stays a name."""
    return REGISTRATION if str(controller) == REGISTRATION else resolve_checkpoint(controller)


def shipped_controller(kind: str):
    """The shipped C_WP of a map kind: its checkpoint, or ``"registration"``."""
    name = SHIPPED[kind][1]
    return REGISTRATION if name == REGISTRATION else shipped_checkpoint(name)


def shipped_controllers() -> list[str]:
    """``"registration"`` and the shipped C_WP checkpoints (their cards say ``waypoint``)."""
    import json

    names = [REGISTRATION]
    for card in sorted((ROOT / "checkpoints").glob("*/card.json")):
        try:
            if json.loads(card.read_text()).get("output") == "waypoint":
                names.append(f"checkpoints/{card.parent.name}/checkpoint.pt")
        except (OSError, ValueError):
            continue
    return names


def check_controller(controller, reach=None) -> None:
    """A given C_WP is ``"registration"`` or a checkpoint file, and a given
    RE checkpoint exists, neither damaged; anything else is refused in one
    line (an unknown controller with the known ones)."""
    if controller is not None and str(controller) != REGISTRATION \
            and not resolve_checkpoint(controller).is_file():
        from pathlib import Path

        if Path(str(controller)).suffix or "/" in str(controller):
            raise TopodrakeError(f"C_WP checkpoint {controller} does not exist (shipped: "
                                 f"{', '.join(shipped_controllers())})")
        raise TopodrakeError(f"controller {controller} is unknown: give a C_WP checkpoint file or "
                             f"one of {', '.join(shipped_controllers())}")
    if reach is not None and not resolve_checkpoint(reach).is_file():
        raise TopodrakeError(f"RE checkpoint {reach} does not exist")
    # a damaged file is refused as such before anything reads what it records
    if controller is not None and str(controller) != REGISTRATION:
        check_intact(resolve_checkpoint(controller), "C_WP checkpoint")
    if reach is not None:
        check_intact(resolve_checkpoint(reach), "RE checkpoint")


def reach_controller(reach):
    """The C_WP an RE checkpoint was trained for, as it records it (a
    checkpoint path resolved here, or ``"registration"``)."""
    from topodrake.learning.checkpoint import load_checkpoint

    recorded = ((load_checkpoint(reach, output="reach").meta.get("extra") or {})
                .get("controller") or {}).get("checkpoint")
    if not recorded:
        raise TopodrakeError(f"RE checkpoint {reach} does not record its controller; "
                             f"give it with --controller")
    return controller_checkpoint(recorded)


def default_reach(controller) -> Path:
    """The shipped RE trained for ``controller`` (a shipped C_WP
    ``checkpoints/<name>/checkpoint.pt``: ``checkpoints/reach_<name>/``; the
    registration C_WP: its shipped RE); a controller without one is refused."""
    controller = controller_checkpoint(controller)
    if controller == REGISTRATION:
        return shipped_checkpoint(SHIPPED["lidar_reg"][0])
    folder = Path(controller).resolve().parent
    if folder.parent == (ROOT / "checkpoints").resolve():
        reach = ROOT / "checkpoints" / f"reach_{folder.name}" / "checkpoint.pt"
        if reach.is_file():
            return reach
    raise TopodrakeError(f"no RE ships for the controller {controller}: give the RE checkpoint "
                         f"trained for it")


def load_networks(controller, reach=None):
    """(C_WP, RE) a follower drives with: ``controller`` a C_WP checkpoint or
    ``"registration"``; ``reach`` the RE checkpoint trained for it (default:
    :func:`default_reach`). An RE of another controller is refused."""
    from topodrake.learning.reachability.estimator import Reachability

    controller = controller_checkpoint(controller)
    reach = default_reach(controller) if reach is None else resolve_checkpoint(reach)
    for what, path in (("controller", controller), ("reach", reach)):
        if path != REGISTRATION and not Path(path).is_file():
            raise TopodrakeError(f"{what} checkpoint {path} does not exist")
    re = Reachability.from_checkpoint(reach, controller)      # refuses a mismatch first
    return controller_policy(controller), re


def _relative(path) -> str:
    """A checkpoint path as recorded in a map: relative to the installation when inside it."""
    if str(path) == REGISTRATION:
        return REGISTRATION
    p = Path(path).resolve()
    try:
        return str(p.relative_to(ROOT))
    except ValueError:
        return str(p)


def _resolve(recorded: str):
    if recorded == REGISTRATION:
        return REGISTRATION
    p = Path(recorded)
    return p if p.is_absolute() else ROOT / p


def make_scorer(modality: str, world=None, reach=None, controller=None):
    """The reachability to build a ``modality`` map with (``"oracle"`` needs
    ``world``; ``"lidar_reg"``: the registration C_WP's RE)."""
    if modality == "oracle":
        if world is None:
            raise TopodrakeError("the oracle reachability needs the world")
        return OracleScorer(world)
    if modality not in SHIPPED:
        raise TopodrakeError(f"modality must be one of {MODALITIES}, got {modality!r}")
    check_controller(controller, reach)
    if reach is None:
        if controller is not None:
            raise TopodrakeError("--controller needs --reach, the RE trained for it")
        reach, controller = shipped_checkpoint(SHIPPED[modality][0]), shipped_controller(modality)
    else:
        reach = resolve_checkpoint(reach)
        controller = controller_checkpoint(controller) if controller else reach_controller(reach)
    for p in (reach, controller):
        if p != REGISTRATION and not p.is_file():
            raise TopodrakeError(f"checkpoint {p} does not exist")
    scorer = LearnedScorer.from_checkpoints(reach, controller)
    if scorer.observation != OBSERVES[modality]:
        raise TopodrakeError(f"{reach} is a {scorer.observation} RE, not a {OBSERVES[modality]} "
                             "one")
    scorer.identity.update(reach=_relative(reach), controller=_relative(controller))
    return scorer


@dataclass
class LoadedMap:
    """A map file opened with what it was built for."""
    world: object           # the world it maps
    topomap: object         # the TopoMap
    scorer: object          # its reachability (learned, or the geometric oracle of a pose map)
    controller: object      # the C_WP checkpoint or "registration" (None: an oracle map)
    reach: object           # the RE checkpoint (None: an oracle map)
    calibration: object     # the plan calibration shipped beside the RE, or None
    meta: dict              # the file's meta


def open_map(path, reach=None, controller=None) -> LoadedMap:
    """A map file with its world and the reachability it was built for: its
    recorded checkpoints, or the ones given, which must be the same files;
    and the plan calibration shipped beside that RE (none for oracle maps)."""
    meta = read_map_meta(path)
    world = load_world(meta["world"])
    if meta.get("modality") == "pose":
        scorer = make_scorer("oracle", world)
        return LoadedMap(world, load_map(path, scorer), scorer, None, None, None, meta)
    ident = meta.get("identity", {})
    check_controller(controller, reach)
    reach = reach or _resolve(ident.get("reach", ""))
    controller = controller or _resolve(ident.get("controller", ""))
    for p, what in ((reach, "reachability estimator"), (controller, "controller")):
        if p != REGISTRATION and not Path(p).is_file():
            raise TopodrakeError(f"{path} was built for the {what} {p}, which does not exist "
                                 f"here; pass it with --reach/--controller")
    scorer = make_scorer(meta["modality"], reach=reach, controller=controller)
    calibration = calibration_beside(reach) if reach and Path(reach).is_file() else None
    return LoadedMap(world, load_map(path, scorer), scorer, controller, reach, calibration, meta)


def demo_folder(world_spec: str, demos=None) -> Path:
    """``demos``, or ``data/demos/pairs-s0/<world>`` (a map file's folder and stem)."""
    if demos:
        return Path(demos)
    p = Path(world_spec)
    name = f"{p.parent.name}-{p.stem}" if p.suffix in (".yaml", ".yml", ".json") else world_spec
    return Path("data/demos/pairs-s0") / name


def demo_drives(world_spec: str, demos=None, progress: bool = True) -> tuple[Path, list]:
    """The successful expert drives of a world, collected first (all ordered
    pairs of its places, seed 0) when ``demos`` is not given and the default
    folder holds none."""
    folder = demo_folder(world_spec, demos)
    if not (folder / "manifest.json").is_file():
        if demos:
            raise TopodrakeError(f"no demonstrations in {folder}")
        collect(world_spec, folder, progress=progress)
    manifest, drives = load_demos(folder, successful_only=True)
    if not same_world(manifest.get("world"), world_spec):
        raise TopodrakeError(f"{folder} holds demonstrations of {manifest.get('world')!r}, "
                             f"not of {world_spec!r}")
    if not drives:
        raise TopodrakeError(f"{folder} holds no successful drive")
    return folder, drives


def place_of(world, xy, tolerance_m: float = 0.3) -> int:
    """The index of the place of ``world`` within ``tolerance_m`` of ``xy`` (-1: none)."""
    if not len(world.places):
        return -1
    d = np.hypot(*(np.asarray(world.places)[:, :2] - np.asarray(xy, np.float64)[:2]).T)
    i = int(np.argmin(d))
    return i if d[i] <= tolerance_m else -1


def drives_between(world, drives: list, places) -> list[int]:
    """Indices of the ``drives`` that start and end at places of ``places``."""
    n = len(world.places)
    wanted = set(int(p) for p in places)
    bad = sorted(p for p in wanted if not 0 <= p < n)
    if bad:
        raise TopodrakeError(f"{world.name!r} has places 0..{n - 1}; there is no place {bad[0]}")
    return [i for i, d in enumerate(drives)
            if place_of(world, d.poses[0]) in wanted and place_of(world, d.poses[-1]) in wanted]


def drive_observations(world, scorer, poses: np.ndarray) -> np.ndarray:
    """What ``scorer`` observes along a drive (poses for the oracle)."""
    if scorer.observation == "pose":
        return np.asarray(poses, np.float64)

    return observe(world, scorer.observation, poses, scorer.sensor)


def view_scans(world, topomap, poses: np.ndarray) -> np.ndarray | None:
    """The lidar scans (N, beams) a camera car takes with its views at
    ``poses``, where ``topomap`` keeps its drives' scans to check links by
    (:func:`topodrake.topomap.plan.link_scans`); None for other maps."""
    if topomap.modality != "camera" or topomap.bank.scans is None:
        return None

    return lidar_scans(world, poses)
