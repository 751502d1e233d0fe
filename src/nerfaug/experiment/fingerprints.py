"""Which settings a run's fingerprint hashes: the rule under which a new setting moves no recorded
fingerprint.

A run's fingerprint (`store.fingerprint` of `ExperimentConfig.fingerprinted`, with its method's
definition: `store.run_fingerprint`) sets apart results that were computed differently. Hashing
every setting there is would make each new one, even one whose default computes exactly what the
code computed before it existed, move the fingerprint of every recorded run: each new setting
would be a decision about the recorded studies. The rule:

- The settings of fingerprint version 1 (`VERSION_1`: the protocol's, every `SelectionConfig`
  field and every engine setting that existed when the rule was set) are hashed at every value,
  as every run recorded before the rule hashed them.
- Every other setting, the engine version among them, is hashed only when it differs from its
  neutral value: the value under which a run computes what it computed before the setting
  existed. That is the setting's default, unless `NEUTRAL` declares another (a setting whose
  default changes the numbers, e.g. a new kernel on by default, is hashed at that default).

So a setting added with a neutral default moves no recorded fingerprint, and a run that sets it
otherwise is never mixed with those that did not. A setting that another setting's value leaves
unused (`UNUSED_WHEN`: with one round, the spacing of rounds) is hashed as its neutral value, so
it splits no results either. A change of arithmetic that no setting names
is a new engine version (`nerf.config.HASH_CPU_ENGINE_VERSION` is one): recorded runs keep theirs.

Light: no torch (`nerfaug run --help` imports `experiment.config`, which imports this).
"""

from __future__ import annotations

import dataclasses
import json
from types import MappingProxyType
from typing import Any

from nerfaug.nerf import names
from nerfaug.nerf.config import FLAT_NAMES, PRESETS, NerfConfig, preset_value
from nerfaug.nerf.engine import Engine

_PROTOCOL_1 = (
    "seed engine resolution steps add_at_step n_new n_initial pool n_test render_samples field_lr threads_per_run "
    "device"
)
_SELECTION_1 = (
    "entropy_resolution entropy_mode normalisation entropy_weight distance_weight metric scale_m sampler "
    "authors_threshold max_draws fisher_method fisher_train_pixels fisher_train_chunk fisher_train_probes "
    "fisher_resolution fisher_probes fisher_lambda fisher_cache_floats chunk background scoring_fov scoring_crop "
    "min_polar entropy_max_polar distance_rotations temperature sharpness batch_entropy_sigma"
)
_ENGINE_1 = (
    "near far box_half_size encoding hash_levels hash_features_per_level hash_log2_table_size hash_base_resolution "
    "hash_max_resolution plane_resolutions plane_features hidden_dim geo_feat_dim color_hidden_dim color_layers "
    "sh_levels density_activation average_init_density sampler num_samples transmittance_eps occupancy_resolution "
    "occupancy_update_every occupancy_warmup_steps occupancy_ema_decay occupancy_threshold occupancy_update_fraction "
    "proposal_samples proposal_hash_levels proposal_max_resolutions proposal_log2_table_size proposal_hidden_dim "
    "proposal_anneal_steps proposal_anneal_slope interlevel_loss_mult distortion_loss_mult proposal_update_every "
    "proposal_warmup_steps batch_size field_lr lr lr_final lr_decay_steps adam_eps background_mode random_background "
    "render_chunk"
)

VERSION_1 = frozenset(
    [*_PROTOCOL_1.split()]
    + [f"selection.{name}" for name in _SELECTION_1.split()]
    + [f"engine.{name}" for name in _ENGINE_1.split()]
)
"""The settings hashed at every value, by their names in a fingerprint's record: those every run
recorded before this rule hashed. Frozen: a setting added since is not named here. (`compile`,
`layouts` and `engine_version` were already left out at their neutral values, by hand.)"""

NEUTRAL: MappingProxyType[str, Any] = MappingProxyType({})
"""Settings outside `VERSION_1` whose neutral value is not their default, by their names in a
fingerprint's record ("selection.NAME", "engine.FLAT_NAME", a protocol field's name) -> the value
under which runs compute what they computed before the setting existed. None so far: every setting
added since version 1 defaults to its neutral value."""


UNUSED_WHEN: tuple[tuple[str, Any, tuple[str, ...]], ...] = (
    # One round adds its views at add_at_step and never again: there is no second round to space,
    # so the steps between rounds and how they grow compute nothing, and runs of one round that
    # differ only in them are the same runs (`experiment.schedule`).
    ("rounds", 1, ("round_every", "round_growth")),
)
"""(setting, value, the settings that value leaves unused), by their names in a fingerprint's
record: while `setting` has `value`, each unused setting is hashed as its neutral value (`NEUTRAL`,
else its default), whatever it is set to; so it is left out when it is outside `VERSION_1`."""


def as_stored(value: Any) -> Any:
    """`value` as JSON stores it (tuples become lists), so that a setting read back from sweep.json
    compares equal to the same setting in code."""
    return json.loads(json.dumps(value, default=str))


def defaults_of(cls: type) -> dict[str, Any]:
    """The default of each field of the dataclass `cls` that has one, by name."""
    found = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            found[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            found[f.name] = f.default_factory()
    return found


def surviving(settings: dict[str, Any], defaults: dict[str, Any]) -> dict[str, Any]:
    """The settings a fingerprint hashes: `settings` (every setting that changes a run's numbers,
    by its name in the record) as JSON stores them, without those outside `VERSION_1` that equal
    their neutral value (`NEUTRAL`, else their entry in `defaults`), those another setting leaves
    unused (`UNUSED_WHEN`) taken at their neutral value first. A setting with neither is kept.

    Equal means the same JSON text, so a setting is left out only when hashing it would hash its
    neutral value: 1 and 1.0, or 0 and false, are not taken for each other.
    """
    stored = as_stored(settings)
    neutral = as_stored({**defaults, **NEUTRAL})
    for setting, value, unused in UNUSED_WHEN:
        if setting in stored and _text(stored[setting]) == _text(as_stored(value)):
            stored |= {name: neutral[name] for name in unused if name in stored and name in neutral}
    return {
        name: value
        for name, value in stored.items()
        if name in VERSION_1 or name not in neutral or _text(value) != _text(neutral[name])
    }


def engine_name(engine: Engine) -> str:
    """The engine's name as every run recorded before settings were named by their nested names
    hashed it ("nerfacto-cpu+hidden_dim=48", `Engine.flat_name`): a fingerprint's "engine", so that
    no recorded run's fingerprint moves."""
    return engine.flat_name()


def engine_settings(engine: Engine | NerfConfig) -> dict[str, Any]:
    """Every engine setting by its flat name (`FLAT_NAMES`, in its order), every part's: those of
    the parts `engine` chose as it holds them; those of a part it did not choose (a hash grid's on
    a K-planes engine) as its preset holds them where the preset chose that part, else at their
    defaults in the part's type.

    Why the parts not chosen are there: fingerprint version 1 hashed every setting of every part,
    because every engine then held every part's settings. A part no preset chose held its type's
    defaults (every preset's did, and a change to one was refused as naming a new engine that
    trains as the old one), and an engine that chose another part over its preset's kept the
    preset's part's settings ("cpu+encoding=hash" held the cpu preset's plane_resolutions). Filled
    in so, every recorded fingerprint and every study table's "engine_settings" keeps its value,
    though an engine now holds only the settings of the parts it uses (`nerf.names`).
    """
    config = engine.config if isinstance(engine, Engine) else engine
    preset = PRESETS[engine.preset] if isinstance(engine, Engine) else config
    return {
        flat: preset_value(preset, path) if names.unused(config, path) else names.get(config, path)
        for flat, path in FLAT_NAMES.items()
    }


def engine_record(engine: Engine | NerfConfig) -> dict[str, Any]:
    """The settings of `engine` a fingerprint hashes, as "engine.FLAT_NAME" (`engine_settings`);
    the neutral value of a setting outside `VERSION_1` is its default in `NerfConfig()`."""
    return surviving(_engine_names(engine_settings(engine)), _engine_names(engine_settings(NerfConfig())))


def _engine_names(flat: dict[str, Any]) -> dict[str, Any]:
    return {f"engine.{name}": value for name, value in flat.items()}


def _text(value: Any) -> str:
    return json.dumps(value, sort_keys=True)
