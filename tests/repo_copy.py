"""What git would commit, copied (tracked and untracked-not-ignored files; links as links): the source a wheel is
built from in the tests, so a build leaves nothing in the checkout and a file not added cannot make a test pass."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def git_files_copy(dest: Path) -> None:
    """Copy the repository's committable files into ``dest``.

    Parameters
    ----------
    dest : Path
        A folder (made where missing).
    """
    files = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout.split()
    for f in files:
        target = dest / f
        target.parent.mkdir(parents=True, exist_ok=True)
        if (REPO / f).is_symlink():
            target.symlink_to(os.readlink(REPO / f))
        elif (REPO / f).is_file():
            shutil.copy2(REPO / f, target)
