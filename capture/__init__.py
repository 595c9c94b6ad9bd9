"""capture: Live Link Face formats (channels, CSV, take folders, UDP) and the take container."""

# First: while a stage command imports (numpy below, then its own stage's libraries), Ctrl-C stops it
# quietly (import_guard, installed on import); each stage's cli.py ends that once its imports are done.
from . import import_guard  # noqa: F401  # isort: skip

# isort: split
from .audio_io import Audio, read_audio, write_audio
from .channels import (
    ARKIT52,
    ARKIT61,
    CHANNEL_SETS,
    CSV_ORDER,
    LIVELINK_ORDER,
    PRONUNCIATION32,
    canonical,
    channel_set,
    udp_index,
)
from .csv_take import read_csv_rows, read_livelink_csv, write_livelink_csv
from .errors import InputError, S2AError
from .importer import find_sources, import_source
from .livelink import REJECT_REASONS, LiveLinkFrame, decode_packet, encode_packet
from .mov import probe_mov, read_mov_audio, write_reference_mov
from .osc_remote import PhoneRemote
from .paired import read_paired
from .recorder import LiveRecorder
from .replay import Impairment, ReplayReport, replay_take
from .serial_sync import SerialSync, SyncEvent
from .session_clock import SessionClock
from .session_takes import build_takes, find_sessions
from .take import (
    AudioInfo,
    FrameStatus,
    SourceFile,
    Take,
    TakeMeta,
    find_takes,
    read_meta,
    read_take,
    write_take,
)
from .take_folder import is_take_folder, read_csv_with_audio, read_frame_log, read_take_folder
from .timecode import Timecode

__all__ = [
    "REJECT_REASONS",
    "Impairment",
    "LiveLinkFrame",
    "LiveRecorder",
    "PhoneRemote",
    "ReplayReport",
    "SerialSync",
    "SessionClock",
    "SyncEvent",
    "build_takes",
    "decode_packet",
    "encode_packet",
    "find_sessions",
    "replay_take",
    "ARKIT52",
    "ARKIT61",
    "Audio",
    "AudioInfo",
    "CHANNEL_SETS",
    "CSV_ORDER",
    "FrameStatus",
    "InputError",
    "LIVELINK_ORDER",
    "PRONUNCIATION32",
    "S2AError",
    "SourceFile",
    "Take",
    "TakeMeta",
    "Timecode",
    "canonical",
    "channel_set",
    "find_sources",
    "find_takes",
    "import_source",
    "is_take_folder",
    "probe_mov",
    "read_audio",
    "read_csv_rows",
    "read_csv_with_audio",
    "read_frame_log",
    "read_livelink_csv",
    "read_meta",
    "read_mov_audio",
    "read_paired",
    "read_take",
    "read_take_folder",
    "udp_index",
    "write_audio",
    "write_livelink_csv",
    "write_reference_mov",
    "write_take",
]
