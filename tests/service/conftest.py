"""The service tests share `test_serve`'s server and helpers (a loopback server process)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
