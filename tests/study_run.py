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
