"""The documentation's promises: its tutorials run and say what the pages say,
every page is in the site's navigation, and the formats it states are the code's."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
TUTORIALS = ("diagram", "monte_carlo", "reachability")


def _tutorial(name: str) -> dict:
    """Run ``docs/tutorials/NAME.py`` from the checkout's root, as a user
    would; its last line of output is one JSON object."""
    done = subprocess.run([sys.executable, str(DOCS / "tutorials" / f"{name}.py")], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_every_tutorial_is_run_here_and_shown_in_the_docs():
    scripts = {p.stem for p in (DOCS / "tutorials").glob("*.py")}
    assert scripts == set(TUTORIALS)
    pages = "\n".join(p.read_text() for p in DOCS.rglob("*.md"))
    for name in TUTORIALS:
        assert f'--8<-- "docs/tutorials/{name}.py"' in pages, f"no page shows {name}.py"


def test_tutorial_diagram_drives_a_plan_on_the_shipped_map():
    out = _tutorial("diagram")
    assert out["diagram"] == "topodrake_navigation"
    assert {"car", "lidar", "follower", "waypoint_net", "rmp", "actuation_noise",
            "odometry"} <= set(out["systems"])
    assert out["anchors"] > 2 and 0.0 < out["plan_probability"] <= 1.0
    assert out["simulated_s"] == pytest.approx(8.0)
    assert out["outcome"] in ("timeout", "reached")
    assert 0.5 < out["distance_m"] <= 0.5 * 8.0 + 0.1     # it drove, within the speed cap
    assert sum(out["mode_periods"].values()) == 80           # one mode per 0.1 s period


def test_tutorial_monte_carlo_is_seeded():
    out = _tutorial("monte_carlo")
    assert out["reproduced"] is True                # the same seeds, one worker or two
    assert set(out["noise"]) == {"0.33", "1.0"}
    for level in out["noise"].values():
        assert len(level["outcomes"]) == len(level["time_s"]) == out["trials"]
        lo, hi = level["ci95"]
        assert lo <= level["success"] <= hi
        assert level["success"] == sum(o == "reached" for o in level["outcomes"]) / out["trials"]
    assert out["noise"]["0.33"]["success"] >= 0.9          # the expert reaches its goals
    assert all(0 < t <= 150 for t in out["noise"]["0.33"]["time_s"])


def test_tutorial_reachability_agrees_with_the_outcomes():
    out = _tutorial("reachability")
    pairs = out["pairs"]
    assert len(pairs) == 5 and out["runs_per_pair"] == 4
    assert all(0.0 <= p["re"] <= 1.0 and 0.0 <= p["success"] <= 1.0 for p in pairs)
    assert pairs[0]["re"] > 0.9 and pairs[0]["success"] == 1.0      # a near target in sight
    assert out["brier"] < 0.1                      # far better than a coin (0.25)
    sure = [p["success"] for p in pairs if p["re"] > 0.9]
    doubtful = [p["success"] for p in pairs if p["re"] < 0.1]
    if sure and doubtful:
        assert min(sure) > max(doubtful)


def _nav_pages(nav) -> list[str]:
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, dict):
        return [p for v in nav.values() for p in _nav_pages(v)]
    return [p for item in nav for p in _nav_pages(item)]


def test_every_page_is_in_the_navigation():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    assert config["docs_dir"] == "docs"
    nav = _nav_pages(config["nav"])
    pages = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md")
             if not p.resolve().is_relative_to(ROOT / "results")}
    assert sorted(nav) == sorted(set(nav)), "a page is twice in the navigation"
    assert set(nav) == pages, (f"pages without a place in mkdocs.yml's nav: {pages - set(nav)}; "
                               f"nav entries without a page: {set(nav) - pages}")


def test_the_limits_are_short_and_current():
    text = (DOCS / "limits.md").read_text()
    assert len(text.split()) <= 2000
    assert not re.search(r"\bbefore that\b", text)


def test_the_docs_state_the_map_format_the_code_writes():
    from topodrake.topomap.mapfile import FORMAT, VERSION

    for page in (DOCS / "formats.md", ROOT / "README.md"):
        stated = re.findall(rf"`{FORMAT}`,? version (\d+)", page.read_text())
        assert stated and all(int(v) == VERSION for v in stated), page.name
