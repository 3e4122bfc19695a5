"""The tablet app: a page that draws the landmarks, records the pen, and measures touch errors;
and its server: the app's state and the files it writes (touch errors into the dataset with
bounded backups, trials), HTTP on asyncio and h11 with a cap on connections and a deadline per
request, the answers to each route, the guard (the secret, ``Host`` and ``Origin``), the posts'
validation, a printable, rate-bounded log, and the start-up that checks every file first.

:func:`make_server` checks the inputs and binds the server; :func:`serve` runs it until
Ctrl-C. Only whoever has the secret the server
prints (in its URL and QR code) can use it (:mod:`.guard`). The page lives in ``static/``
(HTML, JS and CSS; no build step).
"""

from ..data import backup_path as versioned_backup_path
from ._app import TabletApp
from ._calibration import apply_touch_errors
from ._guard import new_token
from ._posts import (
    MAX_BODY_BYTES,
    MAX_TOUCHES,
    MAX_TRIALS,
    PostError,
    parse_calibration,
    parse_evaluation,
)
from ._server import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    EvaluationFiles,
    Listen,
    TabletServer,
    make_server,
    serve,
)
from ._targets import grid_targets, load_targets
from ._trials import format_summary, load_trials, summarise

__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "EvaluationFiles",
    "Listen",
    "MAX_BODY_BYTES",
    "MAX_TOUCHES",
    "MAX_TRIALS",
    "PostError",
    "TabletApp",
    "TabletServer",
    "apply_touch_errors",
    "format_summary",
    "grid_targets",
    "load_targets",
    "load_trials",
    "make_server",
    "new_token",
    "parse_calibration",
    "parse_evaluation",
    "serve",
    "summarise",
    "versioned_backup_path",
]
