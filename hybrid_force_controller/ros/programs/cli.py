"""Console entry points of the offline programs, with a quiet Ctrl-C (exit 0, no traceback)."""
from __future__ import annotations

import sys
from typing import Callable, Sequence

__all__ = ['identify_tool', 'interruptible', 'paper', 'report']


def interruptible(load: Callable[[], Callable[[Sequence[str] | None], int]], name: str,
                  argv: Sequence[str] | None = None) -> int:
    """Import the program (``load()``) and run it; SIGINT ends it with exit code 0."""
    try:
        return load()(argv)
    except KeyboardInterrupt:
        print(f'{name}: interrupted', file=sys.stderr)
        return 0


def _paper_main() -> Callable[[Sequence[str] | None], int]:
    from ...tools.paper import main
    return main


def _report_main() -> Callable[[Sequence[str] | None], int]:
    from ...tools.report import main
    return main


def _identify_tool_main() -> Callable[[Sequence[str] | None], int]:
    from ...tools.identify_tool import main
    return main


def identify_tool(argv: Sequence[str] | None = None) -> int:
    """``identify_tool``: the tool's mass and centre of mass from a bag (tools.identify_tool)."""
    return interruptible(_identify_tool_main, 'identify_tool', argv)


def paper(argv: Sequence[str] | None = None) -> int:
    """``paper``: the paper's scenario offline (tools.paper)."""
    return interruptible(_paper_main, 'paper', argv)


def report(argv: Sequence[str] | None = None) -> int:
    """``report``: figures and metrics from a bag (tools.report)."""
    return interruptible(_report_main, 'report', argv)
