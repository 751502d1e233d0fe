"""The engine's component choices as types (`nerf.names`) move no fingerprint: every engine's
`ExperimentConfig.fingerprinted()` hashes as it did when every engine held every part's settings,
the running rounds study's among them, and every engine keeps its recorded name.

The fingerprints below are literals, computed by the code as it was just before the choices became
types (commit ad9d073, on this machine: `fingerprint(config.fingerprinted())` with the CPU hash
loop selected or not): literals only for this regression, since what they pin is that the code
as it was and the code as it is agree, and the code as it was is no longer here to ask.
"""

import pytest

from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.fingerprints import engine_settings
from nerfaug.experiment.store import fingerprint
from nerfaug.nerf.config import FLAT_NAMES, PRESETS
from nerfaug.nerf.encoding import HashEncoding
from nerfaug.nerf.engine import Engine
from nerfaug.selection.config import SelectionConfig

# The protocol of the rounds study (nerfacto-cpu, 4 real scenes, 8 rounds; its sweep fingerprint
# 5682ca1047b54424 with the CPU loop, as its sweep.json records), each engine put in its place.
STUDY = {
    "scenes": (
        "/work/data/real/mic",
        "/work/data/real/maryRose",
        "/work/data/real/dtu_scan24",
        "/work/results/rounds/datasets/100px/cow",
    ),
    "methods": ("uniform", "ours", "ours-batch-sharp", "fisherrf", "entropy-sampling", "furthest"),
    "trials": 10,
    "seed": 0,
    "resolution": 100,
    "steps": 2000,
    "add_at_step": 200,
    "n_new": 1,
    "n_initial": 4,
    "round_every": 100,
    "round_growth": "fixed",
    "pool": 300,
    "n_test": 50,
    "layouts": 3,
    "render_samples": 16,
    "field_lr": {"chair": 0.002, "materials": 0.002},
    "threads_per_run": 1,
    "save_renders": 3,
    "view_uncertainty": False,
    "hemisphere_map": True,
    "device": "cpu",
    "batch": 0,
    "compile": None,
}

# (engine, rounds, CPU hash loop selected, the sweep fingerprint the code computed before the types)
BEFORE = [
    ("cpu", 1, False, "20c5bc2c7faa787c"),
    ("cpu", 1, True, "20c5bc2c7faa787c"),
    ("cpu", 8, False, "3352127a1d17d68a"),
    ("cpu", 8, True, "3352127a1d17d68a"),
    ("cpu+encoding=hash", 1, False, "cd5a5a5d7e6a761c"),
    ("cpu+encoding=hash", 1, True, "c401c0a9adfdf391"),
    ("cpu+encoding=hash", 8, False, "39027a1971fd5bc8"),
    ("cpu+encoding=hash", 8, True, "f450e582ec69a385"),
    ("cpu+plane_resolutions=32,64", 1, False, "e55689fab0e3543e"),
    ("cpu+plane_resolutions=32,64", 1, True, "e55689fab0e3543e"),
    ("cpu+plane_resolutions=32,64", 8, False, "d2b4d1bbd98827a5"),
    ("cpu+plane_resolutions=32,64", 8, True, "d2b4d1bbd98827a5"),
    ("cpu+sampler=proposal+num_samples=32", 1, False, "4a13effbed6de512"),
    ("cpu+sampler=proposal+num_samples=32", 1, True, "fc6bfe100e83f7fa"),
    ("cpu+sampler=proposal+num_samples=32", 8, False, "e38fbac8efe7c38a"),
    ("cpu+sampler=proposal+num_samples=32", 8, True, "e395e92000d24fed"),
    ("nerfacto-cpu", 1, False, "e44d5dc0f7298538"),
    ("nerfacto-cpu", 1, True, "785dc3c29749c2d3"),
    ("nerfacto-cpu", 8, False, "1f5ef77bf4bf79cc"),
    ("nerfacto-cpu", 8, True, "5682ca1047b54424"),
    ("nerfacto-cpu+background_mode=last_sample+hidden_dim=48", 1, False, "8f9b9120f1bdaaac"),
    ("nerfacto-cpu+background_mode=last_sample+hidden_dim=48", 1, True, "55cf6329cfaa0cb5"),
    ("nerfacto-cpu+background_mode=last_sample+hidden_dim=48", 8, False, "6621d61e5b076a42"),
    ("nerfacto-cpu+background_mode=last_sample+hidden_dim=48", 8, True, "9860d239ddf3339f"),
    ("nerfacto-cpu+encoding=kplanes+plane_features=4", 1, False, "59d766bc9f2b394b"),
    ("nerfacto-cpu+encoding=kplanes+plane_features=4", 1, True, "59d5153b5e243889"),
    ("nerfacto-cpu+encoding=kplanes+plane_features=4", 8, False, "522b4f718feb7617"),
    ("nerfacto-cpu+encoding=kplanes+plane_features=4", 8, True, "6af682129fab0f32"),
    ("nerfacto-cpu+hash_levels=8", 1, False, "0fccbe06137e2fbd"),
    ("nerfacto-cpu+hash_levels=8", 1, True, "cbb8ffed40509400"),
    ("nerfacto-cpu+hash_levels=8", 8, False, "10930a59a6200b7b"),
    ("nerfacto-cpu+hash_levels=8", 8, True, "4da55569d15489e0"),
    ("nerfacto-cpu-last-sample", 1, False, "8c239604c3ee3ed6"),
    ("nerfacto-cpu-last-sample", 1, True, "1d76206cc7c2ff58"),
    ("nerfacto-cpu-last-sample", 8, False, "9cda35ffca68eeff"),
    ("nerfacto-cpu-last-sample", 8, True, "6f9de141af405742"),
    ("paper", 1, False, "b89e036070b32b6e"),
    ("paper", 1, True, "d55cd34505d9a126"),
    ("paper", 8, False, "ff92508be67d35c8"),
    ("paper", 8, True, "0b80dd4f29be2b11"),
    ("paper+sampler=occupancy", 1, False, "d156edc0f73e7fac"),
    ("paper+sampler=occupancy", 1, True, "c9ac291cb18be5ba"),
    ("paper+sampler=occupancy", 8, False, "cabb1b1327cb3d0a"),
    ("paper+sampler=occupancy", 8, True, "287c9d645e0036ee"),
    ("test", 1, False, "18e64c09a9c687d6"),
    ("test", 1, True, "18e64c09a9c687d6"),
    ("test", 8, False, "0976844a035bf3d3"),
    ("test", 8, True, "0976844a035bf3d3"),
    ("test+encoding=hash+hash_levels=8", 1, False, "f4dfc7a513e7f074"),
    ("test+encoding=hash+hash_levels=8", 1, True, "98ec0ce6eb332d5b"),
    ("test+encoding=hash+hash_levels=8", 8, False, "5ec64451dd995de2"),
    ("test+encoding=hash+hash_levels=8", 8, True, "3b9a268a61373a33"),
    ("test+sampler=proposal+proposal_samples=64,32+proposal_max_resolutions=32,64", 1, False, "86f267f801f060e9"),
    ("test+sampler=proposal+proposal_samples=64,32+proposal_max_resolutions=32,64", 1, True, "a83605c3ed1638bf"),
    ("test+sampler=proposal+proposal_samples=64,32+proposal_max_resolutions=32,64", 8, False, "829bd8c0d6a3ae14"),
    ("test+sampler=proposal+proposal_samples=64,32+proposal_max_resolutions=32,64", 8, True, "2368a3487dca4f73"),
    ({"preset": "cpu", "sampler": {"occupancy": {"resolution": 32}}}, 1, False, "b17c2346e8763501"),
    ({"preset": "cpu", "sampler": {"occupancy": {"resolution": 32}}}, 1, True, "b17c2346e8763501"),
    ({"preset": "cpu", "sampler": {"occupancy": {"resolution": 32}}}, 8, False, "7f8c892a5193fd26"),
    ({"preset": "cpu", "sampler": {"occupancy": {"resolution": 32}}}, 8, True, "7f8c892a5193fd26"),
    (
        {"preset": "paper", "field": {"hidden_dim": 32}, "sampler": {"proposal": {"samples": [64, 32]}}},
        1,
        False,
        "58b1efb376cf2870",
    ),
    (
        {"preset": "paper", "field": {"hidden_dim": 32}, "sampler": {"proposal": {"samples": [64, 32]}}},
        1,
        True,
        "84feceedbef053e5",
    ),
    (
        {"preset": "paper", "field": {"hidden_dim": 32}, "sampler": {"proposal": {"samples": [64, 32]}}},
        8,
        False,
        "b47016da7e5029f4",
    ),
    (
        {"preset": "paper", "field": {"hidden_dim": 32}, "sampler": {"proposal": {"samples": [64, 32]}}},
        8,
        True,
        "a50ff9b6edbf450b",
    ),
]

# (engine, the flat name it was recorded and hashed under before the types)
NAMES = [
    ("cpu", "cpu"),
    ("cpu+encoding=hash", "cpu+encoding=hash"),
    ("cpu+plane_resolutions=32,64", "cpu+plane_resolutions=32,64"),
    ("cpu+sampler=proposal+num_samples=32", "cpu+sampler=proposal+num_samples=32"),
    ("nerfacto-cpu", "nerfacto-cpu"),
    (
        "nerfacto-cpu+background_mode=last_sample+hidden_dim=48",
        "nerfacto-cpu+hidden_dim=48+background_mode=last_sample",
    ),
    ("nerfacto-cpu+encoding=kplanes+plane_features=4", "nerfacto-cpu+encoding=kplanes+plane_features=4"),
    ("nerfacto-cpu+hash_levels=8", "nerfacto-cpu+hash_levels=8"),
    ("nerfacto-cpu-last-sample", "nerfacto-cpu-last-sample"),
    ("paper", "paper"),
    ("paper+sampler=occupancy", "paper+sampler=occupancy"),
    ("test", "test"),
    ("test+encoding=hash+hash_levels=8", "test+encoding=hash+hash_levels=8"),
    (
        "test+sampler=proposal+proposal_samples=64,32+proposal_max_resolutions=32,64",
        "test+sampler=proposal+proposal_samples=64,32+proposal_max_resolutions=32,64",
    ),
    ({"preset": "cpu", "sampler": {"occupancy": {"resolution": 32}}}, "cpu+occupancy_resolution=32"),
    (
        {"preset": "paper", "field": {"hidden_dim": 32}, "sampler": {"proposal": {"samples": [64, 32]}}},
        "paper+hidden_dim=32+proposal_samples=64,32",
    ),
    (
        {"preset": "cpu", "sampler": {"kind": "proposal", "num_samples": 32, "proposal": {"hidden_dim": 8}}},
        "cpu+sampler=proposal+num_samples=32+proposal_hidden_dim=8",
    ),
    (
        {
            "preset": "nerfacto-cpu",
            "field": {"encoding": "kplanes", "hidden_dim": 48},
            "sampler": {"kind": "occupancy", "transmittance_eps": 0.001},
        },
        "nerfacto-cpu+encoding=kplanes+hidden_dim=48+sampler=occupancy+transmittance_eps=0.001",
    ),
]


@pytest.mark.parametrize("engine, rounds, loop, expected", BEFORE)
def test_every_engine_hashes_as_before_the_choices_were_types(engine, rounds, loop, expected, monkeypatch):
    monkeypatch.setattr(HashEncoding, "cpu_loop_selected", classmethod(lambda cls: loop))
    config = ExperimentConfig(**STUDY, engine=engine, rounds=rounds, selection=SelectionConfig())
    assert fingerprint(config.fingerprinted()) == expected


def test_the_running_study_keeps_its_sweep_fingerprint(monkeypatch):
    monkeypatch.setattr(HashEncoding, "cpu_loop_selected", classmethod(lambda cls: True))
    config = ExperimentConfig(**STUDY, engine="nerfacto-cpu", rounds=8, selection=SelectionConfig())
    assert fingerprint(config.fingerprinted()) == "5682ca1047b54424"  # as its sweep.json records


@pytest.mark.parametrize("engine, name", NAMES)
def test_every_engine_keeps_its_recorded_name(engine, name):
    assert Engine.read(engine).flat_name() == name
    assert Engine.read(name) == Engine.read(engine)  # and the name reads back as the engine


@pytest.mark.parametrize("preset", list(PRESETS))
def test_an_engine_holds_its_parts_settings_only_and_a_fingerprint_every_parts(preset):
    engine = Engine.read(preset)
    own, every = engine.config.flat(), engine_settings(engine)
    assert list(every) == list(FLAT_NAMES) and own.items() <= every.items()
    other = {"hash": "plane_resolutions", "kplanes": "hash_levels"}[own["encoding"]]
    assert other not in own and other in every
