"""Regenerate every figure the README and the docs show, each with the command that makes it.

    python studies/figures.py --list          # the figures, their files and their commands
    python studies/figures.py                 # make them all (long: runs every study)
    python studies/figures.py --only navigation_diagram map_scalability

Each entry names the files it keeps (the JSON and PNG under ``results/``
and the images under ``docs/`` that the pages link) and the one command
that writes them: a study script, a ``topodrake`` command, or the
navigation diagram drawn here from Drake's Graphviz export (which needs the
``dot`` program of Debian's graphviz package). ``results/`` holds exactly
these files. The commands run one after the other; a failing one is
reported and the rest still run.
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
TF = f"{PY} studies/trajectory_following.py --trajectories 300 --p 0.99"
PLAN = f"{PY} studies/planning.py"

#: name -> (files the command writes that the README and the docs show, the command)
FIGURES = {
    "navigation_diagram": (["docs/navigation_diagram.png"],
                           f"{PY} studies/figures.py --diagram docs/navigation_diagram.png"),
    "demo": (["docs/demo/plan.png", "docs/demo/meshcat.html"],
             "topodrake demo --out docs/demo --seed 0"),
    "willow_plan": (["docs/willow.png"], "topodrake world plot tests/data/maps/willow_full_0.05/"
                                         "map.yaml --out docs/willow.png --astar 0 7"),
    "yujin_plan": (["docs/yujin.png"], "topodrake world plot tests/data/maps/yujin_rnd_extended/"
                                       "map.yaml --out docs/yujin.png --astar 0 7"),
    "controller_success": (["results/controller_success.json",
                            "results/controller_success_details.json",
                            "results/controller_success.png"],
                           f"{PY} studies/controller_success.py --trials 400 --json"),
    "reachability_calibration": (["results/reachability_calibration.json",
                                  "results/reachability_calibration.png"],
                                 f"{PY} studies/reachability_calibration.py --pairs 1000 --json"),
    "sparsification": (["results/sparsification.json", "results/sparsification.png"],
                       f"{PY} studies/sparsification.py --check-drives 3 --json"),
    "oracle_reach": (["results/oracle_reach.json"], f"{PY} studies/oracle_reach.py --json"),
    "map_scalability": (["results/map_scalability.json", "results/map_scalability.png"],
                        f"{PY} studies/map_scalability.py --json"),
    "map_joining": (["results/map_joining.json"], f"{PY} studies/map_joining.py --json"),
    "partial_maps": (["results/partial_maps/partial_maps.json"],
                     f"{PY} studies/partial_maps.py --out results/partial_maps --json"),
    "partial_maps_no_check": (["results/partial_maps_no_check/partial_maps.json"],
                              f"{PY} studies/partial_maps.py --scenario-text "
                              "'{map: {link_cover: 0}}' --out results/partial_maps_no_check "
                              "--json"),
    "following_lidar_reg": (["results/following/lidar_reg/trajectory_following.json"],
                            f"{TF} --controllers lidar_reg --out results/following/lidar_reg --json"),
    "following_lidar_scale": (["results/following/lidar_k5_scale/trajectory_following.json"],
                              f"{TF} --controllers lidar_k5_scale --runs re "
                              "--out results/following/lidar_k5_scale --json"),
    "table2": (["results/table2/planning.json", "results/table2/planning.png",
                "results/table2/plan_calibration.png"],
               f"{PLAN} --methods lidar_reg,lidar,oracle_full --pruned-fractions none "
               "--out results/table2 --json"),
    "table2_ours": (["results/table2_ours/planning.json"],
                    f"{PLAN} --methods ours --pruned-fractions none --trials 100 "
                    "--out results/table2_ours --json"),
    "table2_sptm": (["results/table2_sptm/planning.json"],
                    f"{PLAN} --methods sptm --pruned-fractions none --trials 100 "
                    "--out results/table2_sptm --json"),
    "willow": (["results/willow/planning.json"],
               f"{PLAN} --world tests/data/maps/willow_full_0.05/map.yaml --methods oracle_full "
               "--out results/willow --json"),
    "yujin": (["results/yujin/planning.json"],
              f"{PLAN} --world tests/data/maps/yujin_rnd_extended/map.yaml --methods oracle_full "
              "--out results/yujin --json"),
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
    ap = argparse.ArgumentParser(description="Regenerate the figures of the README and the docs.")
    ap.add_argument("--list", action="store_true",
                    help="print the figures, their files and their commands")
    ap.add_argument("--only", nargs="+", choices=sorted(FIGURES), help="make only these figures")
    ap.add_argument("--diagram", metavar="PNG", help="draw only the navigation diagram into PNG")
    args = ap.parse_args(argv)
    if args.diagram:
        print(f"wrote {draw_navigation_diagram(Path(args.diagram))}")
        return 0
    if args.list:
        for name, (files, command) in FIGURES.items():
            print(f"{name}: {', '.join(files)}\n    {command}")
        return 0
    failed = []
    for name in args.only or FIGURES:
        _, command = FIGURES[name]
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
