"""The tablet app: a page that draws the landmarks, records the pen, and measures touch errors.

:func:`make_server` binds the HTTP server (standard library); :func:`serve` runs it until
Ctrl-C. The page lives in ``static/`` (HTML, JS and CSS; no build step).
"""

from ..dataset import backup_path
from .calibration import apply_touch_errors
from .posts import PostError, parse_calibration, parse_evaluation
from .server import DEFAULT_HOST, DEFAULT_PORT, TabletApp, TabletServer, make_server, serve
from .targets import grid_targets, load_targets
from .trials import format_summary, load_trials, summarise

__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "PostError",
    "TabletApp",
    "TabletServer",
    "apply_touch_errors",
    "backup_path",
    "format_summary",
    "grid_targets",
    "load_targets",
    "load_trials",
    "make_server",
    "parse_calibration",
    "parse_evaluation",
    "serve",
    "summarise",
]
