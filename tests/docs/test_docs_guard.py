"""What the README and the documentation site may say (fast): no issue numbers or pointers outside the
repository in user-facing text, a README that stays a front door, and no dataset id, commit or measured
figure on a page unless it is tied to what produced it.

Figures live in two places only: docs/results.md (the current ones; the README repeats the demo's) and
CHANGELOG.md (history). On results pages every dataset id must be listed in results.md's "Datasets" table
with its spec, the overrides it was generated with and its config hash, and that hash must be the one
this checkout's code computes for the spec: a changed spec makes the figures stale and this test names
them. (Generation's bytes for an unchanged spec are pinned by tests/data/test_data_generation.py.) Every
commit named on a results page or in the changelog must be in this checkout's history."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
README = REPO / "README.md"
RESULTS = REPO / "docs" / "results.md"
CHANGELOG = REPO / "CHANGELOG.md"
PAGES = [README, *sorted((REPO / "docs").glob("**/*.md"))]
RESULT_PAGES = {README, RESULTS}  # the README shows the demo's table, with the same provenance as results.md

DATASET_ID = re.compile(r"\b([a-z][a-z0-9_]*)@([0-9a-f]{12})\b")
COMMIT = re.compile(r"`([0-9a-f]{7,10}|[0-9a-f]{40})`")  # dataset ids and config hashes have 12 digits
INTERVAL = re.compile(r"\d+(?:\.\d+)? \[\d+(?:\.\d+)?, \d+(?:\.\d+)?\]")  # a rate with its interval: 81.7 [77.6, 85.2]
DATE = re.compile(r"(?<![\w/-])20\d\d-\d\d-\d\d(?![\w-])")
ISSUE = re.compile(r"\bissues? #?\d+|\(issue\b", re.I)


def _looks_like_commit(token: str) -> bool:
    return any(c.isdigit() for c in token) and any(c.isalpha() for c in token)


def _prose(text: str) -> str:
    """`text` without its fenced code blocks (commands and snippets may hold example timestamps)."""
    return re.sub(r"```.*?```", "", text, flags=re.S)


def test_no_issue_numbers_in_user_facing_text():
    files = PAGES + sorted((REPO / "samp").glob("**/*.py")) + sorted((REPO / "conf").glob("**/*.yaml"))
    hits = [f"{f.relative_to(REPO)}:{i}: {line.strip()}" for f in files
            for i, line in enumerate(f.read_text().splitlines(), 1) if ISSUE.search(line)]
    assert not hits, "issue numbers in user-facing text (say what is true now instead):\n" + "\n".join(hits)


def test_no_tracked_file_points_outside_the_repository():
    try:
        tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: no list of tracked files")
    needle = "../" + "shared"  # spelled in two parts so that this file does not name it
    hits = []
    for name in tracked.splitlines():
        path = REPO / name
        try:
            text = path.read_text()
        except (UnicodeDecodeError, FileNotFoundError, IsADirectoryError):
            continue
        hits += [f"{name}:{i}" for i, line in enumerate(text.splitlines(), 1) if needle in line]
    assert not hits, f"tracked files point at {needle}, which a clone does not have (use docs/design.md):\n" \
        + "\n".join(hits)


def test_the_readme_is_a_front_door():
    text = README.read_text()
    lines = text.splitlines()
    assert len(lines) <= 260, f"README.md has {len(lines)} lines; keep it to the essentials (about 250) and move the rest to docs/"
    first = re.search(r"```bash\n(.*?)```", text, re.S)
    commands = [line.split("#")[0].strip() for line in first.group(1).splitlines()] if first else []
    assert commands == ["make demo", "make test"], f"the README must start with the two set-up commands; got {commands}"
    assert "arXiv:2509.11185" in text and "@article{" in text, "the README must cite the paper (arXiv id and BibTeX)"
    for link in re.findall(r"\]\((docs/[^)#]+)", text):
        assert (REPO / link).exists(), f"the README links to {link}, which does not exist"


def test_ids_commits_and_figures_stay_on_the_results_pages():
    """Outside README.md and docs/results.md: no dataset id, commit, rate with an interval or date (say
    what the platform does; link the figure). Examples use placeholders (`NAME@ID`, `runs/EXP/TIME`)."""
    hits = []
    for page in PAGES:
        if page in RESULT_PAGES:
            continue
        text = page.read_text()
        prose = _prose(text)
        for pattern, what, body in ((DATASET_ID, "dataset id", text), (INTERVAL, "measured rate", prose),
                                    (DATE, "date", prose)):
            hits += [f"{page.relative_to(REPO)}: {what} {m.group(0)!r}" for m in pattern.finditer(body)]
        hits += [f"{page.relative_to(REPO)}: commit {m.group(0)}" for m in COMMIT.finditer(text)
                 if _looks_like_commit(m.group(1))]
    assert not hits, "figures and run-specific ids belong in docs/results.md (history: CHANGELOG.md):\n" + "\n".join(hits)


def _datasets_table() -> dict[str, tuple[str, list[str], str]]:
    """results.md's "Datasets" table: name@id -> (spec, overrides, config hash prefix)."""
    section = RESULTS.read_text().split("\n## Datasets", 1)
    assert len(section) == 2, "docs/results.md has no '## Datasets' section listing every dataset its figures used"
    rows = {}
    for line in section[1].splitlines():
        cells = [c.strip().strip("`") for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and DATASET_ID.fullmatch(cells[0]):
            overrides = [o.strip().strip("`") for o in cells[2].split(";") if o.strip() not in ("", "-", "none")]
            rows[cells[0]] = (cells[1], overrides, cells[3])
    return rows


def test_dataset_ids_on_results_pages_come_from_this_code():
    from omegaconf import OmegaConf

    from samp.data.spec import load_spec

    table = _datasets_table()
    assert table, "the '## Datasets' table of docs/results.md lists no dataset"
    named = {m.group(0) for page in RESULT_PAGES for m in DATASET_ID.finditer(page.read_text())}
    unlisted = sorted(named - set(table))
    assert not unlisted, f"dataset ids on results pages missing from results.md's Datasets table: {unlisted}"
    stale = []
    for ref, (spec_name, overrides, recorded) in table.items():
        raw = OmegaConf.load(REPO / "conf" / "dataset" / f"{spec_name}.yaml")
        raw = OmegaConf.merge(raw, OmegaConf.from_dotlist(overrides))
        now = load_spec(raw).config_hash()
        if not now.startswith(recorded):
            stale.append(f"{ref}: spec {spec_name} {overrides} hashes to {now[:12]} now, not {recorded}")
    assert not stale, "these datasets are not what this code generates from their specs; regenerate the " \
        "figures that use them (docs/results.md gives each one's command):\n" + "\n".join(stale)


def test_results_name_their_provenance_and_commits_of_this_history():
    text = RESULTS.read_text()
    for section in text.split("\n## ")[1:]:
        title = section.splitlines()[0]
        if "|---" in section and title != "Datasets":
            paragraph = re.search(r"\*\*Provenance:\*\*.*?(?:\n\n|$)", section, re.S)
            assert paragraph and re.search(r"commits? `[0-9a-f]{7,}`", paragraph.group(0)) \
                and DATE.search(paragraph.group(0)), f"results.md section {title!r} has a table but no " \
                "'**Provenance:**' paragraph naming its commit (`abc1234`) and date (YYYY-MM-DD)"
    shallow = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=REPO, capture_output=True, text=True)
    if shallow.returncode != 0:
        pytest.skip("not a git checkout: commits cannot be looked up")
    if shallow.stdout.strip() == "true":
        pytest.skip("a shallow clone: the history the commits are in is not here")
    missing = []
    for page in (README, RESULTS, CHANGELOG):
        for m in COMMIT.finditer(page.read_text()):
            if _looks_like_commit(m.group(1)):
                ok = subprocess.run(["git", "merge-base", "--is-ancestor", m.group(1), "HEAD"], cwd=REPO,
                                    capture_output=True).returncode == 0
                if not ok:
                    missing.append(f"{page.name}: {m.group(1)}")
    assert not missing, "commits named that are not in this checkout's history:\n" + "\n".join(sorted(set(missing)))
