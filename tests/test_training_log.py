"""`--logger tensorboard`: a session's named losses written as TensorBoard scalars, read back with
TensorBoard's own event reader."""

import builtins

import pytest

from nerfaug.training_log import TENSORBOARD_FOLDER, LoggerUnavailable, open_log

event_accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")

ENTRIES = [
    {"step": 10, "loss": 0.50, "psnr": 11.0, "losses": {"rgb": 0.40, "interlevel": 0.08, "distortion": 0.02}},
    {"step": 20, "loss": 0.25, "psnr": 14.0, "losses": {"rgb": 0.20, "interlevel": 0.04, "distortion": 0.01}},
]


def test_each_named_loss_is_a_scalar_at_its_step(tmp_path):
    log = open_log("tensorboard", tmp_path)
    for entry in ENTRIES:
        log(entry)
    log.close()
    events = event_accumulator.EventAccumulator(str(tmp_path / TENSORBOARD_FOLDER))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    assert tags == {"train/loss", "train/psnr", "train/loss/rgb", "train/loss/interlevel", "train/loss/distortion"}
    rgb = events.Scalars("train/loss/rgb")
    assert [e.step for e in rgb] == [10, 20]
    assert [e.value for e in rgb] == pytest.approx([0.40, 0.20])
    assert [e.value for e in events.Scalars("train/psnr")] == pytest.approx([11.0, 14.0])


def test_none_logs_nothing_and_writes_nothing(tmp_path):
    assert open_log("none", tmp_path) is None
    assert not any(tmp_path.iterdir())


def test_without_the_package_one_line_says_how_to_install_it(tmp_path, monkeypatch):
    real_import = builtins.__import__

    def no_tensorboard(name, *args, **kwargs):
        if name.startswith("torch.utils.tensorboard"):
            raise ImportError("No module named 'tensorboard'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_tensorboard)
    with pytest.raises(LoggerUnavailable, match=r"pip install 'nerfaug\[tensorboard\]'") as error:
        open_log("tensorboard", tmp_path)
    assert "\n" not in str(error.value)
