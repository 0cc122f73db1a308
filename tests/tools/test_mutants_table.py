"""tools/mutants.py's table stays applicable: every mutant's text is in its file exactly once. A refactor that
rewrites a guarded line otherwise leaves its mutant silently unappliable (and the guard unmeasured)."""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_every_mutant_applies_to_exactly_one_place():
    sys.path.insert(0, str(REPO / "tools"))
    try:
        import mutants
    finally:
        sys.path.remove(str(REPO / "tools"))
    stale = {m.id: (REPO / m.file).read_text().count(m.old) for m in mutants.ALL}
    assert mutants.PROTOCOL_MUTANTS and mutants.MUTANTS and all(n == 1 for n in stale.values()), \
        {k: n for k, n in stale.items() if n != 1}
