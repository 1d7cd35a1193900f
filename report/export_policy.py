"""``export-policy``: a trained run's deterministic policy as an ONNX file, for game engines and robot stacks.

The graph is the policy the evaluator runs, with its normaliser folded in, in float32, with a free batch axis. Its
boundary is each learner's own (``onnx_module`` in ``<learner>/export.py``; the sidecar describes it):

- SuperTrack: the simulated state S_t and the reference K_{t+1} as per-body world states (B, N, 13), and the
  reference's joint rotations k_{t+1} (B, J, 4) -> the offsets o (B, J, 3) and the PD target joint rotations
  (B, J, 4). Local(), the root offset features and the normaliser are inside the graph.
- PPO: the observation (B, D) and the reference's next hinge angles (B, A) -> the clipped action mean (B, A) and the
  PD target angles (B, A). The running observation normaliser (frozen) is inside the graph; the observation, which
  reads future reference frames, is not.

``FILE.json`` next to the ONNX file names every input and output with its shape, meaning and layout, and records the
learner, run, checkpoint iteration and opset. Before anything is written, onnxruntime runs the exported graph on a
random batch and its outputs must match torch's (the largest difference is recorded).

The exporter is torch's ``torch.export``-based one (``dynamo=True``, which needs ``onnxscript``): the TorchScript
exporter (``dynamo=False``) is deprecated since torch 2.9 and warns that it will be removed.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from common.bundled_configs import plain_help
from common.character.humanoid import Humanoid
from common.cli import (
    EXIT_RUN_FAILED,
    CommandParser,
    check_output_file,
    exit_status,
    fail,
    non_negative_int,
    one_line,
)
from common.config import ConfigError, atomic_output
from common.run.checkpoint import CheckpointError
from common.run.command_line import portable_path
from report.learners import LEARNERS
from report.runs import ReportError, export_module, load_run

# The lowest opset torch's exporter writes without a version conversion (onnxruntime >= 1.14 runs it).
DEFAULT_OPSET = 18
# The self-check batch: random inputs, so it tests the graph, not the policy (the tests use real gym states).
CHECK_BATCH = 64
CHECK_RTOL, CHECK_ATOL = 1e-4, 1e-5

EXAMPLES = """examples:
  export-policy runs/supertrack-20250101-120000 --onnx supertrack_walk.onnx
  export-policy runs/ppo-20250101-120000 --checkpoint 4000 --onnx ppo.onnx --opset 17

In Python (onnxruntime), with the input names of the sidecar supertrack_walk.onnx.json:
  session = onnxruntime.InferenceSession("supertrack_walk.onnx")
  offsets, target_rot = session.run(None, {"sim_state": s, "kin_next_state": k, "kin_next_joint_rot": q})"""


class ExportError(RuntimeError):
    """The exported graph is not the policy: onnxruntime's outputs differ from torch's."""


def _example_inputs(spec: dict[str, Any], batch: int, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """Standard normal float32 inputs of the shapes in ``spec`` with ``batch`` rows."""
    gen = torch.Generator().manual_seed(seed)
    return tuple(torch.randn(batch, *t["shape"][1:], generator=gen) for t in spec["inputs"])


def export_onnx(module: nn.Module, spec: dict[str, Any], path: Path, opset: int) -> float:
    """Writes ``module`` to ``path`` as one self-contained ONNX file and checks it with onnxruntime.

    Args:
        module: A float32 module whose forward takes the inputs of ``spec`` in order and returns its outputs.
        spec: ``{"inputs": [{"name", "shape"}...], "outputs": [...]}``, shapes with the batch axis first.
        path: The ONNX file.
        opset: ONNX opset; below the exporter's own, the graph is converted.

    Returns:
        The largest |onnxruntime - torch| over the outputs on a random batch of :data:`CHECK_BATCH`.

    Raises:
        ValueError: If the graph cannot be converted to ``opset``.
        ExportError: If onnxruntime disagrees with torch.
    """
    import onnx
    import onnxruntime

    batch = torch.export.Dim("batch")  # traced at batch 3: torch.export would fix an axis of size 1
    names = [t["name"] for t in spec["inputs"]]
    # Quiet: the exporter logs its progress, optional packages it does not need here (torchvision) and the opset
    # conversion's tracebacks; a conversion that failed is caught below by its result.
    loggers = [logging.getLogger(name) for name in ("torch.onnx", "onnxscript")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(module, _example_inputs(spec, 3), dynamo=True, opset_version=opset,
                                        input_names=names, output_names=[t["name"] for t in spec["outputs"]],
                                        dynamic_shapes=tuple({0: batch} for _ in names), verbose=False)  # fmt: skip
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)
    assert program is not None
    # Weights inside the file: an engine gets one file, and no sidecar weight file names the temporary path.
    program.save(path, external_data=False)
    model = onnx.load(str(path))
    got = max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx"))
    if got != opset:
        raise ValueError(f"the graph could not be converted to opset {opset} (it stays at {got}); try --opset {got}")
    inputs = _example_inputs(spec, CHECK_BATCH, seed=1)
    with torch.no_grad():
        expected = [t.numpy() for t in module(*inputs)]
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    outputs = session.run(None, {n: x.numpy() for n, x in zip(names, inputs, strict=True)})
    for t, out, ref in zip(spec["outputs"], outputs, expected, strict=True):
        if out.shape != ref.shape or not np.allclose(out, ref, rtol=CHECK_RTOL, atol=CHECK_ATOL):
            raise ExportError(f"onnxruntime's {t['name']} differs from torch's (max |diff| "
                              f"{np.abs(out - ref).max() if out.shape == ref.shape else 'shape'})")  # fmt: skip
    return max(float(np.abs(out - ref).max()) for out, ref in zip(outputs, expected, strict=True))


def sidecar_path(onnx_path: Path) -> Path:
    """Where the description of ``onnx_path`` goes: ``FILE.json`` next to it."""
    return onnx_path.with_name(onnx_path.name + ".json")


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="export-policy", description=plain_help(__doc__), epilog=EXAMPLES,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("run", metavar="RUN_DIR", help="a training run directory (SuperTrack or PPO)")
    parser.add_argument("--checkpoint", type=non_negative_int, metavar="ITER",
                        help="checkpoint iteration (default: the newest)")  # fmt: skip
    parser.add_argument("--onnx", required=True, type=Path, metavar="FILE", help="the ONNX file to write")
    parser.add_argument("--opset", type=_opset, default=DEFAULT_OPSET,
                        help=f"ONNX opset (default {DEFAULT_OPSET}; lower ones converted where ONNX can)")  # fmt: skip
    return parser


def _opset(text: str) -> int:
    """``--opset``'s value: an ONNX opset, 7 or above."""
    value = non_negative_int(text)
    if value < 7:
        raise argparse.ArgumentTypeError(f"ONNX opsets below 7 are not supported, got {value}")
    return value


def main(argv: list[str] | None = None) -> int:
    """``export-policy``: bad input ends in one line and exit status 2 with nothing written; an export whose graph
    onnxruntime disagrees with, or a file that cannot be written (a full disk), in one line and exit status 1."""
    return exit_status(lambda: _main(argv), ReportError, ConfigError, CheckpointError)


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    missing = [p for p in ("onnx", "onnxruntime", "onnxscript") if importlib.util.find_spec(p) is None]
    if missing:
        fail(f"export-policy needs {', '.join(missing)}: pip install -e '.[onnx]'")
    for path in (args.onnx, sidecar_path(args.onnx)):
        check_output_file(path, "--onnx")
    run = load_run(args.run, args.checkpoint)
    module = export_module(run.learner)
    if not hasattr(module, "onnx_module"):
        fail(f"{run.path}: {LEARNERS[run.learner].display} has no network policy to export")
    humanoid = Humanoid(run.physics())
    try:
        net, spec = module.onnx_module(run.path, run.checkpoint, humanoid)
    except (ValueError, KeyError) as e:  # a checkpoint that is not this learner's
        fail(one_line(e))
    try:
        with atomic_output(args.onnx) as tmp:
            max_diff = export_onnx(net, spec, tmp, args.opset)
    except ValueError as e:
        fail(one_line(e))
    except ExportError as e:
        fail(one_line(e), EXIT_RUN_FAILED)
    except OSError as e:
        fail(f"{args.onnx}: cannot write it: {e.strerror or one_line(e)}; nothing was changed", EXIT_RUN_FAILED)
    sidecar = {
        "learner": run.learner, "run_dir": portable_path(str(run.path.absolute())),
        "checkpoint": portable_path(str(run.checkpoint.absolute())),
        "iteration": run.iteration, "samples": run.samples, "opset": args.opset, "dtype": "float32",
        **spec,
        "check": {"max_abs_diff_onnxruntime_torch": max_diff, "batch": CHECK_BATCH, "inputs": "standard normal"},
        "torch": torch.__version__,
    }  # fmt: skip
    try:
        with atomic_output(sidecar_path(args.onnx)) as tmp:
            tmp.write_text(json.dumps(sidecar, indent=2) + "\n", encoding="utf-8")
    except OSError as e:
        fail(f"{sidecar_path(args.onnx)}: cannot write it: {e.strerror or one_line(e)} ({args.onnx} was written)",
             EXIT_RUN_FAILED)  # fmt: skip
    print(f"{run.label} (iteration {run.iteration}): wrote {args.onnx} and {sidecar_path(args.onnx)} "
          f"(opset {args.opset}; onnxruntime matches torch within {max_diff:.1e})")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
