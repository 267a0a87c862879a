"""The package's files: config/ from the source tree, the pip prefix or the ament index."""
from __future__ import annotations

from pathlib import Path
import sys

__all__ = ['LOOPBACK_PROFILE', 'PKG', 'PROFILE_VAR', 'find_config']

PKG = 'hybrid_force_controller'
# Fast DDS 2.x reads its default XML profile from this variable (rmw_fastrtps loads it first)
PROFILE_VAR = 'FASTRTPS_DEFAULT_PROFILES_FILE'
LOOPBACK_PROFILE = 'fastdds_loopback.xml'


def find_config(name: str = 'params.yaml') -> Path:
    """config/NAME from the source tree, the pip prefix or the ament index."""
    source_tree = Path(__file__).resolve().parents[3]  # <tree>/<package>/ros/common/.
    candidates = [source_tree / 'config' / name,
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
