"""
Where the controller's robot model comes from: parameter, .xacro, topic or bundled arm.

``robot_description`` (parameter) may be URDF XML, a URDF path or a ``.xacro`` path (expanded
with the ``xacro`` package). When it is empty the node waits for the ``robot_description``
topic (relative: it follows the namespace; transient local, as robot_state_publisher
publishes it), unless ``use_bundled_model`` asks for the paper's 2-link arm.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ['DescriptionError', 'expand_description', 'missing_description_hint']


class DescriptionError(ValueError):
    """The robot description cannot be read or expanded; the message says why."""


def expand_description(value: str) -> str:
    """URDF XML or URDF path as given; a ``.xacro`` path expanded to URDF XML."""
    text = value.strip()
    if not text.endswith('.xacro') or text.startswith('<'):
        return value
    path = Path(text).expanduser()
    if not path.is_file():
        raise DescriptionError(f"robot_description: xacro file '{path}' does not exist")
    try:
        import xacro
    except ImportError as exc:
        raise DescriptionError('robot_description is a .xacro file but the xacro package is '
                               'not installed (pip install xacro)') from exc
    try:
        return xacro.process_file(str(path)).toxml()
    except Exception as exc:  # noqa: BLE001 - xacro raises many kinds; say which file
        raise DescriptionError(f"robot_description: expanding '{path}' failed: {exc}") from exc


def missing_description_hint(topic: str) -> str:
    """Say what the node waits for and how to give it (the log line)."""
    return (f"robot_description parameter is empty: waiting for the URDF on '{topic}' "
            '(std_msgs/String, transient local, e.g. from robot_state_publisher). Or pass '
            '-p robot_description:=<URDF XML | .urdf | .xacro path>, or -p '
            "use_bundled_model:=true for the paper's 2-link arm.")
