"""Settings' bounds, as types: the engine's (`nerfaug.nerf.config` declares each setting with one),
an experiment's and a study's (`nerfaug.experiment.config`, `study_spec`).

Each setting's bounds are declared with its type and checked once, by pydantic, wherever settings
are changed (`NerfConfig.with_settings`, `from_dict`): a width of 0, a negative learning rate or an
infinite far plane is refused as one line naming the setting, never trained. Every float is
finite: an infinite learning rate or scene bound passes a `> 0` bound and then trains NaNs.
"""

from __future__ import annotations

from typing import Annotated

from annotated_types import Ge, Gt, Le, Lt, MinLen
from pydantic import AllowInfNan, Strict

# Strict, every one: an integer setting refuses 32.0, "32" and True (a float where a width is
# meant is a mistake, never rounded), a number refuses text and True. Count: a size or number of
# things; Counts: one or more of them (per tri-plane, per proposal network); Steps: training steps
# (0: none); Seed: a random seed; NonNegativeInt: any other whole number >= 0.
_INT, _FINITE = Strict(), AllowInfNan(False)
Count, NonNegativeInt = Annotated[int, _INT, Ge(1)], Annotated[int, _INT, Ge(0)]
Steps = Seed = NonNegativeInt
Counts = Annotated[tuple[Count, ...], MinLen(1)]
Finite = Annotated[float, Strict(), _FINITE]
Positive, NonNegative = Annotated[float, Strict(), Gt(0), _FINITE], Annotated[float, Strict(), Ge(0), _FINITE]
Fraction = Annotated[float, Strict(), Ge(0), Lt(1), _FINITE]  # in [0, 1)
Share = Annotated[float, Strict(), Gt(0), Le(1), _FINITE]  # in (0, 1]
Log2Size = Annotated[int, _INT, Ge(1), Le(30)]
SHLevels = Annotated[int, _INT, Ge(1), Le(4)]  # 4 levels: 16 terms
