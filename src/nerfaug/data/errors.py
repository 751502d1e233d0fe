"""The one error type for bad dataset input; its message names the file, the field and the value.

Defined in `nerfaug.errors` (a leaf, so `nerfaug.jsonio` raises it without importing a room above
it); this is its name in the data package.
"""

from __future__ import annotations

from nerfaug.errors import DatasetError

__all__ = ["DatasetError"]
