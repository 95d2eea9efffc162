"""The README's promises: its images exist and each has the command that makes it."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _images(page: Path) -> list[Path]:
    links = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", page.read_text())
    return [(page.parent / link).resolve() for link in links if "://" not in link]


def test_every_image_the_docs_link_exists():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    missing = [str(p.relative_to(ROOT)) for page in pages for p in _images(page) if not p.is_file()]
    assert not missing, f"linked images that do not exist: {missing}"


def test_every_readme_image_has_a_command_in_the_figures_script():
    from study_run import run_study

    code, listed, err = run_study("figures", "--list")    # "name: image, image" and its command
    assert code == 0, err
    images = [line.split(": ", 1)[1].split(", ") for line in listed.splitlines()
              if line and not line.startswith(" ")]
    assert images and all(images)
    made = {(ROOT / image).resolve() for names in images for image in names}
    orphans = [str(p.relative_to(ROOT)) for p in _images(ROOT / "README.md") if p not in made]
    assert not orphans, f"README images no command in studies/figures.py makes: {orphans}"


def test_readme_is_for_users():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    assert not re.search(r"\bsessions?\b|\bissue #?\d+", text, re.I)
    quick = text.split("## Quick start", 1)[1].split("```bash", 1)[1].split("```", 1)[0]
    lines = [line for line in quick.splitlines() if line.strip()]
    assert len(lines) == 2 and "topodrake demo" in lines[0] and "pytest" in lines[1]


def test_code_and_docs_speak_of_the_project_only():
    """No work history (issue numbers, sessions) in the code, studies or docs."""
    pattern = re.compile(r"\bissues? #?\d+\b|\bwork sessions?\b", re.I)
    files = [p for folder in ("topodrake", "systems", "studies", "docs")
             for p in (ROOT / folder).rglob("*") if p.suffix in (".py", ".md")]
    found = [str(p.relative_to(ROOT)) for p in files if pattern.search(p.read_text())]
    assert not found, f"files that speak of the project's history: {found}"
