"""Found by the flake audit: windows where a timing-sensitive outcome depended on the machine's load."""

from __future__ import annotations

import json

from conftest import run_python

# A command's own Python start-up: its sys.argv names s2a-capture, and a finder first on sys.meta_path
# notes each module imported until capture's Ctrl-C guard is in place.
BEFORE_THE_GUARD = """
import json, signal, sys
sys.argv[:] = ["s2a-capture", "info", "none.csv"]
before = []
class Noting:
    def find_spec(self, name, path=None, target=None):
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            before.append(name)
sys.meta_path.insert(0, Noting())
import capture
print(json.dumps(before))
"""


def test_the_ctrl_c_guard_is_up_before_any_slow_standard_module_loads():
    """Ctrl-C 0.04-0.16 s into s2a-capture import or s2a-view render on a loaded machine (3 of 168
    tries) landed in ``typing``, which the guard imported before it was up: a KeyboardInterrupt
    traceback. Before the guard, only capture and the guard itself load (os and sys are Python's own,
    signal the check's)."""
    proc = run_python(BEFORE_THE_GUARD)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == ["capture", "capture.import_guard"], proc.stdout
