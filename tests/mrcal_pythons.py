"""The interpreters that can run mrcal here, for tests that check circcal against every mrcal version present:
Debian's mrcal 2.2 (``/usr/bin/python3``, or ``$CIRCCAL_MRCAL_PYTHON``) and PyPI's 2.5 in ``.venv-mrcal25`` (``make
mrcal-2.5``). Each comes with the folder of its command-line tools."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: Where `make mrcal-2.5` builds PyPI's mrcal 2.5.
MRCAL25_PYTHON = REPO / ".venv-mrcal25" / "bin" / "python"


def mrcal_pythons() -> list[tuple[str, str, Path]]:
    """``[(label, python, tools folder)]`` for every working mrcal here (label: its API, "2.2" or "2.5"); empty
    when there is none."""
    from circcal.formats.mrcal_process import DEFAULT_PYTHON, ENV_VAR, _probe

    candidates = [os.environ.get(ENV_VAR) or DEFAULT_PYTHON, str(MRCAL25_PYTHON)]
    out, seen = [], set()
    for py in candidates:
        if not py or py in seen or not Path(py).exists():
            continue
        seen.add(py)
        ok, _, info = _probe(py)
        if ok:
            tools = Path("/usr/bin") if py == DEFAULT_PYTHON else Path(py).parent
            out.append((f"mrcal-{info.get('api', '?')}", py, tools))
    return out
