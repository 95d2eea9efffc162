"""Running a study script as a program in tests: exit status, output and errors."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_study(name: str, *argv) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of ``python studies/<name>.py ARGV``
    run from the checkout's root."""
    done = subprocess.run([sys.executable, str(ROOT / "studies" / f"{name}.py"),
                           *[str(a) for a in argv]], cwd=ROOT, capture_output=True, text=True)
    return done.returncode, done.stdout, done.stderr


def check_scenarios(name: str, schema, named=("default",), same: dict | None = None) -> None:
    """Study ``name``'s scenarios file names ``named``; its ``default`` scenario
    is ``schema``'s defaults and so is ``--print-config`` with no flags; every
    named scenario loads; each ``same`` scenario prints as its flags (a list)
    do: the figure's command and its scenario are one run."""
    from dataclasses import asdict

    import yaml

    from topodrake.experiments.scenarios import load_scenario, scenario_names

    path = ROOT / "studies" / "scenarios" / f"{name}.yaml"
    assert set(named) <= set(scenario_names(path))
    assert load_scenario(schema, path, "default") == schema()
    for scenario in scenario_names(path):
        load_scenario(schema, path, scenario)
    code, out, err = run_study(name, "--print-config")
    assert code == 0, err
    assert yaml.safe_load(out) == asdict(schema())
    for scenario, flags in (same or {}).items():
        code, out, err = run_study(name, *flags, "--print-config")
        assert code == 0, err
        assert out == run_study(name, "--scenario", scenario, "--print-config")[1]
