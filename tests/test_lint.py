"""The tree is lint-clean under the project's ruff rules (pyproject.toml, [tool.ruff]). ruff is a
pinned requirement, so a missing ruff fails here instead of passing unchecked."""
import re
import subprocess
import sys

from taichi_soft.paths import ROOT


def test_ruff_finds_nothing():
    done = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(ROOT)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-1000:]


def _tracked_text_files():
    listed = subprocess.run(["git", "ls-files"], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert listed.returncode == 0, listed.stderr
    return [ROOT / p for p in listed.stdout.split() if p.endswith((".py", ".md", ".toml", ".txt"))
            and not p.startswith("docs/benchmarks/") and p != "CHANGELOG.md"]


# Our own tracker's numbers are small; Taichi's upstream issues (four digits and more) may be cited.
OWN_ISSUE = re.compile(r"\bissues? ?#?\d{1,3}\b(?!\d)", re.IGNORECASE)
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")


def test_no_issue_numbers_and_no_dates_in_the_product():
    """Issue numbers appear nowhere in the product, tests or docs; dated measurements live in
    docs/decisions/ and docs/benchmarks/, never in the package's code."""
    found = []
    for path in _tracked_text_files():
        rel = path.relative_to(ROOT).as_posix()
        for no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if OWN_ISSUE.search(line):
                found.append(f"{rel}:{no}: issue number: {line.strip()[:80]}")
            if rel.startswith(("taichi_soft/", "main.py")) and DATE.search(line):
                found.append(f"{rel}:{no}: date in code: {line.strip()[:80]}")
    assert not found, "\n".join(found)


def test_the_issue_number_rule_sees_one():
    word = "issue"  # split so that this file does not cite one itself
    assert OWN_ISSUE.search(f"see {word} 23") and OWN_ISSUE.search(f"({word}s #4, #11)")
    assert not OWN_ISSUE.search("Taichi issues #8576 and #8578")
    assert DATE.search("measured " + "-".join(("2026", "12", "06")))
