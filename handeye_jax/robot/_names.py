"""The exports' formats and default frame names, apart from the exports themselves: the
command line's ``--help`` reads them without loading NumPy."""

from __future__ import annotations

import re
from dataclasses import dataclass

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


@dataclass(frozen=True)
class FrameNames:
    """The link and frame names an export writes (URDF, tf2 and easy_handeye names).

    Each must match :data:`NAME_PATTERN` (letters, digits and ``_``, not first a digit), and
    the three a URDF or ROS 2 file joins (``parent_link``, ``camera_frame``, ``pen_frame``)
    must differ; otherwise ``ValueError`` naming the field.

    Attributes:
        parent_link: the URDF/tf2 name of the hand (flange) frame.
        camera_frame: the camera's optical frame.
        pen_frame: the pen tip's frame.
        base_frame: the robot's base frame (easy_handeye's ``robot_base_frame``).
    """

    parent_link: str = DEFAULT_PARENT_LINK
    camera_frame: str = DEFAULT_CAMERA_FRAME
    pen_frame: str = DEFAULT_PEN_FRAME
    base_frame: str = DEFAULT_BASE_FRAME

    def __post_init__(self) -> None:
        for field in ("parent_link", "camera_frame", "pen_frame", "base_frame"):
            name = getattr(self, field)
            if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
                raise ValueError(
                    f"{field}: not a valid link or frame name: {name!r} (letters, digits, _)"
                )
        if len({self.parent_link, self.camera_frame, self.pen_frame}) != 3:
            raise ValueError(
                "parent_link, camera_frame, pen_frame: need three distinct names (got "
                f"{self.parent_link}, {self.camera_frame}, {self.pen_frame})"
            )
