"""The README's promises: two Quick-start lines that CI runs, headline figures
each with the command that remakes it, images that exist, and results/
holding exactly what studies/figures.py makes."""

import re
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _images(page: Path) -> list[Path]:
    links = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", page.read_text())
    return [(page.parent / link).resolve() for link in links if "://" not in link]


def _pages() -> list[Path]:
    docs = ROOT / "docs"
    return [README, *sorted(p for p in docs.rglob("*.md")
                            if not p.resolve().is_relative_to(ROOT / "results"))]


def _figures() -> dict[str, tuple[list[str], str]]:
    """studies/figures.py --list: name -> (files, command with "python" for the interpreter)."""
    from study_run import run_study

    code, listed, err = run_study("figures", "--list")
    assert code == 0, err
    out, lines = {}, listed.splitlines()
    for head, command in zip(lines[::2], lines[1::2]):
        name, files = head.split(": ", 1)
        out[name] = (files.split(", "), command.strip().replace(sys.executable, "python"))
    assert out and all(files and command for files, command in out.values())
    return out


def _quick_start() -> list[str]:
    quick = README.read_text().split("## Quick start", 1)[1].split("```bash", 1)[1]
    return [line for line in quick.split("```", 1)[0].splitlines() if line.strip()]


def _headline_rows() -> list[list[str]]:
    table = README.read_text().split("## Headline figures", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in table.splitlines() if line.startswith("|")]
    assert rows[0].split("|")[1:-1] == [" figure ", " value ", " paper ", " command "]
    return [[c.strip() for c in row.split("|")[1:-1]] for row in rows[2:]]


def test_the_quick_start_is_two_lines_and_ci_runs_the_second():
    lines = _quick_start()
    assert len(lines) == 2
    assert "pip install -e ." in lines[0] and lines[0].endswith("topodrake demo")
    assert 'pip install -e ".[test]"' in lines[1] and lines[1].endswith("-m pytest")
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert lines[1] in ci, ".ci/run must run the README's test line as written"
    assert any(line.strip().startswith(".venv/bin/mkdocs build --strict") for line in ci)


def test_every_headline_figure_is_one_number_with_a_command_that_remakes_it():
    rows = _headline_rows()
    assert len(rows) >= 8
    commands = {command for _, command in _figures().values()}
    for figure, value, paper, command in rows:
        assert re.fullmatch(r"\d+\.\d+", value), f"{figure}: {value!r} is not one number"
        assert paper == "-" or re.fullmatch(r"\d+\.\d+", paper), f"{figure}: paper {paper!r}"
        assert command.startswith("`") and command.endswith("`"), figure
        assert command.strip("`") in commands, \
            f"{figure}: {command} is not a command of studies/figures.py"


def test_every_image_the_docs_link_exists():
    missing = [str(p) for page in _pages() for p in _images(page) if not p.is_file()]
    assert not missing, f"linked images that do not exist: {missing}"


def test_every_image_shown_has_a_command_in_the_figures_script():
    made = {(ROOT / f).resolve() for files, _ in _figures().values() for f in files}
    orphans = [str(p.relative_to(ROOT)) for page in _pages() for p in _images(page)
               if p not in made]
    assert not orphans, f"images no command in studies/figures.py makes: {orphans}"


def test_results_hold_exactly_what_the_figures_script_makes():
    listed = {f for files, _ in _figures().values() for f in files}
    missing = sorted(f for f in listed if not (ROOT / f).is_file())
    assert not missing, f"studies/figures.py names files that are not here: {missing}"
    tracked = subprocess.run(["git", "ls-files", "results"], cwd=ROOT, capture_output=True,
                             text=True)
    if tracked.returncode == 0 and tracked.stdout.strip():
        extra = sorted(set(tracked.stdout.split()) - listed)
        assert not extra, f"results/ files no figure is made from: {extra}"
    size = sum(p.stat().st_size for p in (ROOT / "results").rglob("*") if p.is_file())
    assert size <= 10 * 2 ** 20


def test_every_figure_command_is_a_command_of_this_checkout():
    for name, (_, command) in _figures().items():
        argv = shlex.split(command)
        assert argv[0] in ("python", "topodrake"), name
        if argv[0] == "python":
            assert (ROOT / argv[1]).is_file(), f"{name}: {argv[1]} does not exist"


def test_readme_is_for_users():
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    assert not re.search(r"\bsessions?\b|\bissue #?\d+|\bbefore that\b", text, re.I)
    from topodrake.topomap.mapfile import FORMAT, VERSION

    assert f"`{FORMAT}` version {VERSION}" in text


def test_code_and_docs_speak_of_the_project_only():
    """No work history (issue numbers, sessions) in the code, studies or docs."""
    pattern = re.compile(r"\bissues? #?\d+\b|\bwork sessions?\b", re.I)
    files = [p for folder in ("topodrake", "systems", "studies", "docs")
             for p in (ROOT / folder).rglob("*") if p.suffix in (".py", ".md")]
    found = [str(p.relative_to(ROOT)) for p in files if pattern.search(p.read_text())]
    assert not found, f"files that speak of the project's history: {found}"
