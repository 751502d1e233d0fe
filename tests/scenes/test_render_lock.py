"""The lock that lets only one process render a dataset folder at a time."""

import subprocess
import sys

from nerfaug.scenes.render import exclusive_lock

TRY_LOCK = """
import fcntl, os, sys
handle = os.open(sys.argv[1], os.O_RDONLY)
try:
    fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
except BlockingIOError:
    sys.exit(3)
"""


def other_process_can_lock(path) -> bool:
    result = subprocess.run([sys.executable, "-c", TRY_LOCK, str(path)], timeout=60)
    assert result.returncode in (0, 3)
    return result.returncode == 0


def test_lock_excludes_other_processes_until_released(tmp_path):
    with exclusive_lock(tmp_path):
        assert not other_process_can_lock(tmp_path)
    assert other_process_can_lock(tmp_path)
    assert list(tmp_path.iterdir()) == []  # nothing left behind
