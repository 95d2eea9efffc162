"""Regenerate every figure the README shows, each with the command that makes it.

    python studies/figures.py --list          # the figures and their commands
    python studies/figures.py                 # make them all (long: runs every study)
    python studies/figures.py --only navigation_diagram map_scalability

Each entry names the image(s) the README links and the one command that
writes them (a study script, ``topodrake demo`` or the navigation diagram
drawn here from Drake's Graphviz export, which needs the ``dot`` program of
Debian's graphviz package). The commands run one after the other; a failing
one is reported and the rest still run.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable

#: name -> (images the README links, command that writes them)
FIGURES = {
    "navigation_diagram": (["docs/navigation_diagram.png"],
                           f"{PY} studies/figures.py --diagram docs/navigation_diagram.png"),
    "demo": (["docs/demo/plan.png"], "topodrake demo --out docs/demo --seed 0"),
    "controller_success": (["results/controller_success.png"],
                           f"{PY} studies/controller_success.py --trials 400 --json"),
    "reachability_calibration": (["results/reachability_calibration.png"],
                                 f"{PY} studies/reachability_calibration.py --pairs 1000 --json"),
    "sparsification": (["results/sparsification.png"],
                       f"{PY} studies/sparsification.py --check-drives 3 --json"),
    "map_scalability": (["results/map_scalability.png"],
                        f"{PY} studies/map_scalability.py --json"),
    "trajectory_following": (["results/trajectory_following.png"],
                             f"{PY} studies/trajectory_following.py --json"),
    "planning": (["results/planning.png", "results/pruned_maps.png"],
                 f"{PY} studies/planning.py --json"),
    "plan_calibration": (["results/plan_calibration/plan_calibration.png"],
                         f"{PY} studies/planning.py --rescore "
                         + ",".join(["results/joining/planning/planning.json",
                                     "results/lidar_planning/test-0-2.json",
                                     "results/lidar_planning/test-3-4.json"]
                                    + [f"results/plan_calibration/test_ours/planning_{t}.json"
                                       for t in "abc"])
                         + " --out results/plan_calibration --json"),
}


def draw_navigation_diagram(out: Path) -> Path:
    """The learned navigation diagram (camera C_WP and RE, a two-anchor route)
    as a PNG, from ``Diagram.GetGraphvizString`` and ``dot``."""
    import shutil

    import numpy as np

    from topodrake.contract.route import route_from_trajectory
    from topodrake.systems.navigation import NavigationScenario, load_networks, make_navigation_diagram
    from topodrake.world import load_world

    if shutil.which("dot") is None:
        raise SystemExit("drawing the diagram needs 'dot': apt-get install graphviz")
    scenario = NavigationScenario(world="test-0")
    world = load_world(scenario.world)
    policy, reach = load_networks(scenario)
    p = world.places[0]
    poses = np.array([[p[0] + 0.05 * i * np.cos(p[2]), p[1] + 0.05 * i * np.sin(p[2]), p[2]]
                      for i in range(20)])
    route = route_from_trajectory(world, poses, np.array([0, 19]), policy)
    built = make_navigation_diagram(scenario, route, world=world, policy=policy, reach=reach)
    dot = built.diagram.GetGraphvizString(max_depth=1)
    out.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run(["dot", "-Tpng", "-Gdpi=110", "-o", str(out)], input=dot.encode(), check=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Regenerate the README's figures.")
    ap.add_argument("--list", action="store_true", help="print the figures and their commands")
    ap.add_argument("--only", nargs="+", choices=sorted(FIGURES), help="make only these figures")
    ap.add_argument("--diagram", metavar="PNG", help="draw only the navigation diagram into PNG")
    args = ap.parse_args(argv)
    if args.diagram:
        print(f"wrote {draw_navigation_diagram(Path(args.diagram))}")
        return 0
    if args.list:
        for name, (images, command) in FIGURES.items():
            print(f"{name}: {', '.join(images)}\n    {command}")
        return 0
    failed = []
    for name in args.only or FIGURES:
        images, command = FIGURES[name]
        wall = time.perf_counter()
        print(f"[{name}] {command}", flush=True)
        code = subprocess.run(shlex.split(command), cwd=ROOT).returncode
        print(f"[{name}] exit {code} in {time.perf_counter() - wall:.0f} s", flush=True)
        if code != 0:
            failed.append(name)
    print(f"{len(args.only or FIGURES) - len(failed)} figures made, {len(failed)} failed"
          + (f": {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
