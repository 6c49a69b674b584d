"""Serial acquisition: the scanner + scales stream and the thermocouple logger
recorded together into a run directory, with nothing good lost
(docs/protocols.md).

``acquire(run_dir, scanner=PORT, thermo=PORT, duration=S)`` records and returns
the ``cmmpose.Run``; ``Recorder`` gives control over start and stop;
``recover(run_dir)`` rebuilds a run from its journal after a crash.
"""

from .assemble import assemble
from .clock import ClockFit, fit_clock, host_time
from .plan import DEFAULT_CHANNELS, Plan, plan_from_run
from .protocol import FrameParser, ProfileHeader, Rejection, decode_header, decode_points, encode_profile
from .recorder import Recorder, Recovery, acquire, recover
from .scpi import configure_commands, parse_reply
from .stats import Snapshot
from .store import JOURNAL_NAME, LOG_NAME, JournalContents, TornTail, read_journal

__all__ = [
    "acquire",
    "Recorder",
    "recover",
    "Recovery",
    "Plan",
    "plan_from_run",
    "DEFAULT_CHANNELS",
    "assemble",
    "read_journal",
    "JournalContents",
    "TornTail",
    "JOURNAL_NAME",
    "LOG_NAME",
    "encode_profile",
    "decode_header",
    "decode_points",
    "FrameParser",
    "ProfileHeader",
    "Rejection",
    "configure_commands",
    "parse_reply",
    "ClockFit",
    "fit_clock",
    "host_time",
    "Snapshot",
]
