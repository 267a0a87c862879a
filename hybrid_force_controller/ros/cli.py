"""Console entry points of the offline programs, with a quiet Ctrl-C (exit 0, no traceback)."""
from __future__ import annotations

import sys
from typing import Callable, Sequence

__all__ = ['interruptible', 'paper', 'report']


def interruptible(main: Callable[[Sequence[str] | None], int], name: str,
                  argv: Sequence[str] | None = None) -> int:
    """Run ``main(argv)``; a KeyboardInterrupt (SIGINT) ends it with exit code 0."""
    try:
        return main(argv)
    except KeyboardInterrupt:
        print(f'{name}: interrupted', file=sys.stderr)
        return 0


def paper(argv: Sequence[str] | None = None) -> int:
    """``paper``: the paper's scenario offline (tools.paper)."""
    from ..tools.paper import main
    return interruptible(main, 'paper', argv)


def report(argv: Sequence[str] | None = None) -> int:
    """``report``: figures and metrics from a bag (tools.report)."""
    from ..tools.report import main
    return interruptible(main, 'report', argv)
