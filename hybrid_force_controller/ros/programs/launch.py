"""Finding the package's files and starting its nodes as processes (shared by demo and bench)."""
from __future__ import annotations

from pathlib import Path
import sys

__all__ = ['PKG', 'find_config']

PKG = 'hybrid_force_controller'


def find_config(name: str = 'params.yaml') -> Path:
    """config/NAME from the source tree, the pip prefix or the ament index."""
    here = Path(__file__).resolve().parents[1]
    candidates = [here.parent / 'config' / name,
                  Path(sys.prefix) / 'share' / PKG / 'config' / name]
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory(PKG)) / 'config' / name)
    except Exception:  # noqa: BLE001 - not in an ament index: other candidates remain
        pass
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(f'config/{name} not found in {[str(c) for c in candidates]}')
