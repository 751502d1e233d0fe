"""benchmarks/bench_engine_walk.py walks from `nerfacto-cpu-last-sample` to exactly `paper`, one
group at a time, each group changing only settings where the two presets differ."""

from pathlib import Path

from nerfaug.nerf.config import NerfConfig

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_engine_walk.py"


def test_the_walk_starts_at_the_cpu_sibling_and_ends_at_the_paper_preset(bench):
    entries = bench.walk_entries()
    assert NerfConfig.preset(entries[0][2]) == NerfConfig.preset("nerfacto-cpu-last-sample")
    assert NerfConfig.preset(entries[-1][2]) == NerfConfig.preset("paper")
    bench.check_walk_reaches_paper()


def test_each_group_sets_paper_values_and_every_difference_is_in_one_group(bench):
    start, paper = NerfConfig.preset("nerfacto-cpu-last-sample").flat(), NerfConfig.preset("paper").flat()
    differing = {k for k in start if start[k] != paper[k]}
    changed = [name for _, _, changes in bench.GROUPS for name in changes]
    assert len(changed) == len(set(changed))
    assert differing <= set(changed)
    for _, _, changes in bench.GROUPS:
        alone = NerfConfig.preset(bench.variant(changes)).flat()
        assert all(alone[name] == paper[name] for name in changes), changes


def test_every_probe_is_a_valid_engine_name(bench):
    for what, engine in bench.all_entries().values():
        NerfConfig.preset(engine)  # raises on an unknown setting or a badly typed value
        assert what


def test_the_end_probes_are_the_paper_preset_with_only_their_background_changed(bench):
    paper = NerfConfig.preset("paper").flat()
    for name, (_, changes) in bench.END_PROBES.items():
        probe = NerfConfig.preset(bench.all_entries()[name][1]).flat()
        assert {k for k in paper if paper[k] != probe[k]} == set(changes) == {"background_mode"}, name
