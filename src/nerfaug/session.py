"""The active-capture API under its earlier name: `from nerfaug.session import CaptureSession` keeps
working. The code lives in `nerfaug.capture`; this module re-exports its public names (one list,
`nerfaug.capture.__all__`)."""

from nerfaug.capture import *  # noqa: F403
from nerfaug.capture import __all__  # noqa: F401
