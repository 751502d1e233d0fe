"""Which part of a training step half precision changes (the `paper` preset does not train under
float16 autocast on a GPU: BENCHMARKS.md, "GPU: the paper preset on an H200").

An engine is trained in float32 to each of `--at-steps`; at each, one training step's gradients
are computed again from the same parameters, rays and jitter, in float32 and under autocast with
the networks' parts kept in float32 one at a time:

- `half everywhere`: what `precision="fp16"` does (the proposal networks and the field's MLPs in
  float16; densities, weights and losses float32);
- `proposal nets float32`: the field in float16, the proposal networks (which place the samples)
  in float32;
- `field density float32`: the field's density network in float32, everything else in float16;
- `proposal nets only`: only the proposal networks in float16.

For each: the relative error of each parameter group's gradient (||g_half - g_32|| / ||g_32||), the
fraction of its non-zero float32 entries that are zero in half precision (underflow; the loss is
scaled by 2^16 as a GradScaler would), the batch's colour MSE and how far the samples moved
along the rays. A float32 step repeated gives the noise floor (0 on a CPU; a GPU's atomic adds
land in no fixed order); float32 with another batch at the same step gives the gradients' own
noise, against which a change is read. With `--train-half N`, the engine is also trained N steps from scratch
under autocast with a GradScaler, as the trainer does, and its scale, skipped steps and training
views' PSNR recorded beside a float32 training of the same seed; with `--train-keep proposal` (etc.)
once more with those networks in float32 (`--train-each`: once per network named; `sigmoid` keeps
only the colour network's output activation in float32), and with `--train-scales 23` (etc.) once
more per exponent with the loss scale starting at 2^23 (`--probe-scales 20 24`: the probes once
more with the loss scaled by 2^20, 2^24). `--exact-fp16-sums` forbids cuBLAS's
float16 partial sums in half-precision matrix products (a GPU's default allows them).

    python benchmarks/bench_precision.py --data data/lego100 --engine nerfacto-cpu --at-steps 400
    python benchmarks/bench_precision.py --data data/lego100 --engine paper --device cuda \\
        --at-steps 100 1000 --train-half 1000 --train-keep proposal --json results/precision.json

On a CPU half precision is float16 autocast on the CPU (slower than float32 there, and not what
the trainer allows: this is a diagnostic), so `paper` costs about 9 s a step on this project's
machine; use a GPU for it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench_engine_walk, run as a script

VARIANTS: dict[str, tuple[str, ...]] = {
    "half everywhere": (),
    "proposal nets float32": ("proposal",),
    "field density float32": ("density",),
    "proposal nets only": ("density", "color"),
}
LOSS_SCALE = 2.0**16  # GradScaler's initial scale


@contextlib.contextmanager
def float32_parts(parts: tuple[str, ...], device_type: str):
    """Run the named networks ("proposal", "density", "color") outside autocast while inside;
    "sigmoid" keeps only the colour network's output activation in float32.

    Patches the classes' methods for the duration (a diagnostic: the engine has no switch for
    this, and must not grow one only for it)."""
    from nerfaug.nerf import field

    originals = {
        "proposal": (field.DensityField, "forward"),
        "density": (field.NerfField, "density"),
        "color": (field.NerfField, "color"),
    }
    saved = {part: getattr(cls, name) for part, (cls, name) in originals.items()}

    def outside_autocast(method):
        def wrapped(self, *tensors):
            with torch.autocast(device_type, enabled=False):
                return method(self, *(t.float() for t in tensors))

        return wrapped

    def sigmoid_float32(self, *tensors):
        # the colour network under autocast, its output handed on in float32, so the field's own
        # sigmoid (and that activation's backward, computed from its output) runs in float32
        hook = self.color_mlp.register_forward_hook(lambda _module, _inputs, output: output.float())
        try:
            return saved["color"](self, *tensors)
        finally:
            hook.remove()

    try:
        for part in parts:
            if part == "sigmoid":
                field.NerfField.color = sigmoid_float32
                continue
            cls, name = originals[part]
            setattr(cls, name, outside_autocast(saved[part]))
        yield
    finally:
        for part, (cls, name) in originals.items():
            setattr(cls, name, saved[part])


def group_of(name: str) -> str:
    """A parameter's group: the module two levels down, hash tables apart from MLP weights."""
    return ".".join(name.split(".")[:2]) + ("/table" if "table" in name else "")


def step_gradients(
    trainer,
    cpu_state: torch.Tensor,
    dtype: torch.dtype | None,
    parts: tuple[str, ...] = (),
    other_batch: bool = False,
    loss_scale: float = LOSS_SCALE,
):
    """One training step's gradients, colour MSE and sample edges, without updating anything.

    The draws repeat exactly: on a CPU the trainer's generator is reset to `cpu_state`; on a GPU
    `step_generator` reseeds itself from (seed, step). `other_batch` draws other rays and jitter
    for the same step (the generator moved by one draw; on a GPU the seed by one), the scale of the
    gradient's own noise from one batch to the next, against which a change is read.

    Returns:
        ({parameter name: gradient}, mse, t_starts (rays, samples)).
    """
    trainer.model.train()
    trainer.generator.set_state(cpu_state)
    if other_batch:
        torch.rand(1, generator=trainer.generator)
    seed, trainer.seed = trainer.seed, trainer.seed + int(other_batch)
    try:
        generator = trainer.step_generator()
    finally:
        trainer.seed = seed
    trainer.model.before_step(trainer.step, generator)
    origins, directions, target, background = trainer.sample_batch(generator)
    trainer.model.zero_grad(set_to_none=True)
    device_type = trainer.device.type
    autocast = torch.autocast(device_type, dtype=dtype) if dtype is not None else contextlib.nullcontext()
    with float32_parts(parts, device_type), autocast:
        output = trainer.model(origins, directions, background, generator=generator)
    mse = torch.nn.functional.mse_loss(output.rgb.float(), target)
    ((mse + trainer.model.auxiliary_loss(output)) * loss_scale).backward()
    gradients = {n: p.grad.detach() / loss_scale for n, p in trainer.model.named_parameters() if p.grad is not None}
    return gradients, float(mse.detach()), output.t_starts.detach()


def compare(reference: dict, other: dict) -> dict[str, dict[str, float]]:
    """Per group: relative error of `other`'s gradient and the fraction of `reference`'s non-zero
    entries that are zero in `other`."""
    sums: dict[str, list[float]] = {}
    for name, ref in reference.items():
        got = other.get(name, torch.zeros_like(ref))
        acc = sums.setdefault(group_of(name), [0.0, 0.0, 0, 0])
        acc[0] += float(((got - ref) ** 2).sum())
        acc[1] += float((ref**2).sum())
        nonzero = ref != 0
        acc[2] += int(nonzero.sum())
        acc[3] += int((nonzero & (got == 0)).sum())
    return {
        group: {"rel_error": (e / r) ** 0.5 if r > 0 else 0.0, "underflow": lost / n if n else 0.0}
        for group, (e, r, n, lost) in sums.items()
    }


def probe(trainer, dtype: torch.dtype, scale_exponents: tuple[int, ...] = ()) -> dict:
    """Every variant's gradients against float32's at the trainer's current step; and half
    everywhere once more per exponent e with the loss scaled by 2^e instead of 2^16."""
    state = trainer.generator.get_state()
    reference, mse, t_ref = step_gradients(trainer, state, None)
    repeat, _, _ = step_gradients(trainer, state, None)
    other, _, _ = step_gradients(trainer, state, None, other_batch=True)
    result = {
        "step": trainer.step,
        "mse_float32": mse,
        "float32_repeated": compare(reference, repeat),
        "float32_other_batch": compare(reference, other),
        "variants": {},
    }
    for name, parts in VARIANTS.items():
        gradients, half_mse, t_half = step_gradients(trainer, state, dtype, parts)
        result["variants"][name] = {
            "mse": half_mse,
            "samples_moved_max": float((t_half - t_ref).abs().max()),
            "groups": compare(reference, gradients),
        }
    for exponent in scale_exponents:
        gradients, half_mse, t_half = step_gradients(trainer, state, dtype, loss_scale=2.0**exponent)
        result["variants"][f"half everywhere, loss x 2^{exponent}"] = {
            "mse": half_mse,
            "samples_moved_max": float((t_half - t_ref).abs().max()),
            "groups": compare(reference, gradients),
        }
    trainer.generator.set_state(state)
    return result


def train_half(
    data,
    engine: str,
    seed: int,
    steps: int,
    device: str,
    dtype: torch.dtype | None,
    keep: tuple[str, ...] = (),
    init_scale: float = LOSS_SCALE,
) -> dict:
    """Train `steps` steps on the initial views under autocast to `dtype` (None: float32) with a
    GradScaler for float16 starting at `init_scale` (the trainer's: 2^16), as the trainer's fp16
    does, with the networks named in `keep` (see `float32_parts`) in float32, and record the
    scale, the skipped steps and the training views' PSNR."""
    from bench_engine_walk import view_metrics
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.trainer import Trainer

    trainer = Trainer(data.initial, NerfConfig.preset(engine), seed=seed, device=device, progress=False)
    trainer._autocast = dtype  # the trainer refuses half precision on a CPU; this diagnostic wants it
    trainer.scaler = torch.amp.GradScaler(trainer.device.type, init_scale) if dtype == torch.float16 else None
    skipped, trace = 0, []
    while trainer.step < steps:
        scale = trainer.scaler.get_scale() if trainer.scaler else 1.0
        with float32_parts(keep, trainer.device.type):
            entry = trainer.train_step()
        if trainer.scaler and trainer.scaler.get_scale() < scale:
            skipped += 1
        if trainer.step % 50 == 0 or trainer.step == steps:
            trace.append({"step": trainer.step, "batch_psnr": entry["psnr"], "scale": scale, "skipped": skipped})
    train_psnr, opacity = view_metrics(trainer.model, trainer.train_views)
    return {
        "precision": str(dtype).removeprefix("torch.") if dtype is not None else "float32",
        "steps": steps,
        "float32": list(keep),
        "init_scale": init_scale if dtype == torch.float16 else None,
        "skipped": skipped,
        "train_psnr": train_psnr,
        "opacity": opacity,
        "trace": trace,
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="Blender-format dataset folder with an initial split")
    parser.add_argument("--engine", default="paper")
    parser.add_argument("--at-steps", type=int, nargs="+", default=[100], help="float32 steps before each probe")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--half", choices=["fp16", "bf16"], default="fp16")
    parser.add_argument("--train-half", type=int, default=0, help="also train this many steps in half precision")
    parser.add_argument(
        "--train-keep",
        nargs="*",
        default=[],
        choices=["proposal", "density", "color", "sigmoid"],
        help="and once more with these networks in float32 (e.g. proposal)",
    )
    parser.add_argument(
        "--train-each", action="store_true", help="one training per network named in --train-keep, not one for all"
    )
    parser.add_argument(
        "--train-scales",
        type=int,
        nargs="*",
        default=[],
        help="and once more in half precision per exponent e, the loss scale starting at 2^e (the trainer's: 16)",
    )
    parser.add_argument(
        "--probe-scales",
        type=int,
        nargs="*",
        default=[],
        help="also probe half everywhere with the loss scaled by 2^e, per exponent e (the probes use 2^16)",
    )
    parser.add_argument(
        "--exact-fp16-sums",
        action="store_true",
        help="on cuda, forbid cuBLAS's float16 partial sums in half-precision matrix products "
        "(torch.backends.cuda.matmul.allow_fp16_reduced_precision_reduction = False)",
    )
    parser.add_argument("--resolution", type=int, default=100)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)

    from bench_engine_walk import load_data
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.trainer import Trainer

    torch.set_num_threads(args.threads)
    # PyTorch lets cuBLAS add float16 products' partial sums in float16 unless told not to; a
    # weight gradient sums over every sample of a batch (4096 rays x 48 samples at paper scale)
    torch.backends.cuda.matmul.allow_fp16_reduced_precision_reduction = not args.exact_fp16_sums
    dtype = torch.float16 if args.half == "fp16" else torch.bfloat16
    data = load_data(args.data, 2, args.resolution)
    trainer = Trainer(data.initial, NerfConfig.preset(args.engine), seed=args.seed, device=args.device, progress=False)
    report = {
        "engine": args.engine,
        "seed": args.seed,
        "half": args.half,
        "device": str(trainer.device),
        "exact_fp16_sums": args.exact_fp16_sums,
        "probes": [],
    }
    for step in sorted(args.at_steps):
        start = time.perf_counter()
        trainer.train(step)
        probe_result = probe(trainer, dtype, tuple(args.probe_scales))
        probe_result["seconds"] = time.perf_counter() - start
        report["probes"].append(probe_result)
        print_probe(probe_result)
    # float32 first: the baseline the half-precision trainings are read against
    kept = [(part,) for part in args.train_keep] if args.train_each else [tuple(args.train_keep)]
    kept = [parts for parts in kept if parts]
    plans = [(None, (), LOSS_SCALE), (dtype, (), LOSS_SCALE)] + [(dtype, parts, LOSS_SCALE) for parts in kept]
    plans += [(dtype, (), 2.0**exponent) for exponent in args.train_scales]
    report["train_half"] = [
        train_half(data, args.engine, args.seed, args.train_half, args.device, kind, keep, scale)
        for kind, keep, scale in (plans if args.train_half else [])
    ]
    for half, (kind, _, scale) in zip(report["train_half"], plans):
        kept = ", ".join(half["float32"]) or "none"
        precision = args.half if kind is not None else "float32"
        print(
            f"trained {half['steps']} steps in {precision} (networks kept in float32: {kept}"
            + (f", loss scale from 2^{math.log2(scale):.0f}" if kind == torch.float16 else "")
            + "): "
            f"train PSNR {half['train_psnr']:.2f} dB, {half['skipped']} steps skipped by the scaler"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1))
    return report


def print_probe(result: dict) -> None:
    """One line per variant: its MSE, the samples' largest move, each group's relative error; and
    float32 with another batch, the scale of the gradients' own noise."""
    print(f"step {result['step']}: float32 batch MSE {result['mse_float32']:.6f}")
    noise = ", ".join(f"{g} {v['rel_error']:.3f}" for g, v in result["float32_other_batch"].items())
    print(f"  {'float32, another batch':24s} {noise}")
    for name, variant in result["variants"].items():
        groups = ", ".join(f"{g} {v['rel_error']:.3f}" for g, v in variant["groups"].items())
        print(f"  {name:24s} MSE {variant['mse']:.6f}, samples moved <= {variant['samples_moved_max']:.3f}: {groups}")


if __name__ == "__main__":
    main()
