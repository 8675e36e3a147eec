"""Which code produced a result: the git commit of the checkout whose ``phast_model`` is imported.

Located from this file, not from the working directory, so a script run against another checkout
(``PYTHONSAFEPATH=1 PYTHONPATH=<checkout> python ...``) records that checkout's commit.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

_ROOT = Path(__file__).resolve().parent.parent


def code_commit(short: bool = False, dirty: bool = False) -> str | None:
    """HEAD of the checkout holding this ``phast_model`` (``short``: abbreviated), with ``+dirty`` appended when
    ``dirty`` is asked for and ``phast_gym`` / ``phast_model`` differ from it; None outside git."""
    git = ["git", "-C", str(_ROOT)]
    try:
        head = subprocess.run([*git, "rev-parse", *(["--short"] if short else []), "HEAD"], capture_output=True,
                              text=True, timeout=10).stdout.strip()
        if not head:
            return None
        if dirty and subprocess.run([*git, "diff", "--quiet", "HEAD", "--", "phast_gym", "phast_model"],
                                    capture_output=True, timeout=10).returncode != 0:
            head += "+dirty"
    except (OSError, subprocess.SubprocessError):
        return None
    return head
