"""The exports' formats and default frame names, apart from the exports themselves: the
command line's ``--help`` reads them without loading NumPy."""

from __future__ import annotations

import re

FORMATS = ("json", "yaml", "urdf", "ros2", "opencv", "python", "easy_handeye")
#: Formats that cannot hold an unknown value and write 0 (with a comment) instead.
ZERO_FILLED_FORMATS = ("urdf", "ros2", "opencv", "easy_handeye")
DEFAULT_PARENT_LINK = "tool0"
DEFAULT_BASE_FRAME = "base_link"
DEFAULT_TABLET_FRAME = "tablet"
DEFAULT_CAMERA_FRAME = "camera_optical_frame"
DEFAULT_PEN_FRAME = "pen_tip"
#: Link and frame names: what URDF, tf2 and ROS node names all accept.
NAME_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,127}")
