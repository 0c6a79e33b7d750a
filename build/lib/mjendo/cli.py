"""What every ``python -m mjendo.<tool>`` does with a user's mistake: one line on stderr, exit status 2."""

from __future__ import annotations

import sys
from collections.abc import Callable


def run(action: Callable[[], object], *expected: type[BaseException]) -> int:
    """Run a command's body; the errors it expects (bad input, with the fix named) become ``error: ...``."""
    try:
        action()
    except expected as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0
