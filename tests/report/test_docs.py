"""The user docs' Python examples run as written and print what the docs show."""

import re
import subprocess
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _blocks(page: str, lang: str) -> list[str]:
    fences = re.findall(r"^```(\w*)\n(.*?)^```", (DOCS / page).read_text(), re.DOTALL | re.MULTILINE)
    return [body for tag, body in fences if tag == lang]


def test_accuracy_calculator_prints_the_documented_output(tmp_path):
    code, shown = _blocks("accuracy.md", "python")[0], _blocks("accuracy.md", "")[-1]
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == shown.strip()


def test_docs_link_to_pages_that_exist():
    for page in ("quickstart.md", "tutorial-real-rig.md", "file-formats.md", "accuracy.md"):
        for target in re.findall(r"\]\(([^)#]+\.md)\)", (DOCS / page).read_text()):
            assert (DOCS / target).is_file(), f"{page} links to missing {target}"
