"""`lerobot-opfa train`: `lerobot-train` itself (its flags, loop, optimizer and scheduler presets,
checkpoints, resume, logging, wandb, accelerate) on the dataset held in memory.

LeRobot's `make_train_eval_datasets` is swapped, for this call only, for one that wraps the LeRobotDatasets
it makes in `InMemoryDataset`; everything else is LeRobot's code, including its episode-aware sampler. The
swap, and one more (`sys.argv`, which LeRobot reads itself), are patched with `unittest.mock` because
LeRobot 0.6.1 offers no seam for them: `train` says why beside each. The config is parsed here and handed
to LeRobot's `train(cfg)` (`parser.wrap` takes a parsed config), so that a flag's error shows its cause.
The process also keeps freed memory for reuse (glibc), which spares the update step its page faults.
"""

from __future__ import annotations

import argparse
import ctypes
import functools
import logging
import os
import platform
import sys
import time
from pathlib import Path
from unittest import mock  # for two pieces of LeRobot 0.6.1 that offer no seam: see `train` below

HELP = (
    "lerobot-train with the dataset held in memory: same flags (see lerobot-train --help), numeric datasets"
)


def add_command(subparsers: argparse._SubParsersAction) -> None:
    # No argparse options of its own: every argument, --help included, is lerobot-train's (cli.main passes
    # the ones argparse does not know through as `lerobot_args`).
    parser = subparsers.add_parser("train", help=HELP, description=HELP, add_help=False)
    parser.set_defaults(func=run, passthrough=True)


def run(args: argparse.Namespace) -> int:
    train(args.lerobot_args)
    return 0


def train(argv: list[str]) -> None:
    """Runs LeRobot's training entry point on `argv` (lerobot-train's flags) with the in-memory dataset.

    The loader runs in the main process unless `--num_workers` is given: an item is a few index gathers,
    cheaper than shipping it from a worker process. Torch's thread count follows OMP_NUM_THREADS when set,
    else every core goes to the update step (there are no loader workers to leave cores to): on an idle
    2-core machine 2 threads train 1.4x faster than 1, but torch's OpenMP threads spin while they wait, so
    where other busy processes share the cores set OMP_NUM_THREADS=1 (2 threads there ran 10-20x
    slower). See benchmarks/bench_training.py."""
    import torch
    from huggingface_hub import constants
    from lerobot.scripts import lerobot_train
    from lerobot.utils.import_utils import register_third_party_plugins

    from lerobot_opfa.datasets.io import check_dataset_folder

    _check_output(argv)
    root = next((a.split("=", 1)[1] for a in argv if a.startswith("--dataset.root=")), None)
    if root is not None and Path(root).is_dir():
        check_dataset_folder(root)
    elif root is not None and constants.HF_HUB_OFFLINE:
        raise ValueError(
            f"--dataset.root {root} does not exist (and the Hub, to download into it, is offline)"
        )
    if not any(a == "--num_workers" or a.startswith("--num_workers=") for a in argv):
        argv = [*argv, "--num_workers=0"]
    if "OMP_NUM_THREADS" not in os.environ:
        usable = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else range(os.cpu_count() or 1)
        torch.set_num_threads(len(usable))
    _reuse_freed_memory()
    make = _in_memory(lerobot_train.make_train_eval_datasets)
    # Two pieces of LeRobot 0.6.1 are swapped for this call only. LeRobot has no seam for either:
    with (
        # No seam for the dataset: `train(cfg)` calls the module's `make_train_eval_datasets` by name, takes
        # no dataset or factory, and datasets have no registry (`DatasetConfig` is a plain dataclass).
        mock.patch.object(lerobot_train, "make_train_eval_datasets", make),
        # No seam for the arguments: `TrainPipelineConfig.validate()` reads `--policy.path` /
        # `--reward_model.path` from `sys.argv` itself (`parser.get_path_arg`): there is no argv parameter.
        mock.patch.object(sys, "argv", ["lerobot-opfa train", *argv]),
    ):
        register_third_party_plugins()
        if "--help" in argv or "-h" in argv:
            lerobot_train.main()  # LeRobot's own help of its flags
        else:
            lerobot_train.train(_parse(argv))


def _parse(argv: list[str]):
    """lerobot-train's config from `argv`, parsed as `parser.wrap` parses it (plugins, `--config_path`,
    the `.path` flags left for `validate`), with a flag's real error raised as one line: `wrap` prints
    draccus's own, which for a `--policy.*` value is "Could not decode the value into any of the given
    types" with the cause on a second line, and for another config's ValueError only "Couldn't
    instantiate ..."."""
    import draccus
    from lerobot.configs import parser
    from lerobot.configs.train import TrainPipelineConfig

    args = list(argv)
    for flag, plugin in parser.parse_plugin_args(parser.PLUGIN_DISCOVERY_SUFFIX, args).items():
        parser.load_plugin(plugin)
        args = parser.filter_arg(flag, args)
    path_fields = TrainPipelineConfig.__get_path_fields__()
    args = parser.filter_path_args(path_fields, args)
    config_path = parser.parse_arg("config_path", args)
    try:
        if config_path:
            config_path = parser.extract_path_fields_from_config(config_path, path_fields)
            cli_args = parser.filter_arg("config_path", args)
            return TrainPipelineConfig.from_pretrained(config_path, cli_args=cli_args)
        return draccus.parse(config_class=TrainPipelineConfig, args=args, exit_on_error=False)
    except draccus.utils.DraccusException as err:
        cause = err
        while isinstance(cause, draccus.utils.DraccusException) and (cause.__cause__ or cause.__context__):
            cause = cause.__cause__ or cause.__context__
        flag = ".".join(getattr(err, "field_path", ()) or ())
        raise ValueError(f"--{flag}: {cause}" if flag else str(cause)) from None


def _flag(argv: list[str], name: str) -> str | None:
    """The value of lerobot-train's `--name=value` or `--name value` in `argv` (the last one given)."""
    value = None
    for i, arg in enumerate(argv):
        if arg.startswith(f"--{name}="):
            value = arg.split("=", 1)[1]
        elif arg == f"--{name}" and i + 1 < len(argv):
            value = argv[i + 1]
    return value


def _check_output(argv: list[str]) -> None:
    """Before any step: the run's folder can be written (LeRobot finds out at the first checkpoint, after
    the steps before it), and its checkpoints hold no incomplete one (a run killed while saving it leaves
    a numbered folder without `last` pointing there, which LeRobot refuses without saying so)."""
    from lerobot_opfa.output_folders import check_writable

    resume = (_flag(argv, "resume") or "false").lower() in ("true", "1", "yes")
    config_path, output_dir = _flag(argv, "config_path"), _flag(argv, "output_dir")
    if output_dir is not None:
        check_writable(output_dir, "--output_dir")
    elif not resume:
        check_writable("outputs/train", "--output_dir (not given: outputs/train)")
    if resume and config_path is not None and "checkpoints" in Path(config_path).parts:
        parts = Path(config_path).parts
        at = len(parts) - 1 - parts[::-1].index("checkpoints")
        checkpoints = Path(*parts[: at + 1])
        if at + 1 < len(parts):
            _check_resumable(checkpoints, parts[at + 1], f"--config_path {config_path}")
        if output_dir is None:
            check_writable(checkpoints.parent, f"--config_path {config_path}: the run folder")
    elif not resume and output_dir is not None and (Path(output_dir) / "checkpoints").is_dir():
        incomplete = _incomplete_checkpoints(Path(output_dir) / "checkpoints")
        if incomplete:
            raise ValueError(
                f"--output_dir {output_dir}: checkpoint {incomplete[-1].name} is incomplete (the run was "
                f"killed while saving it); {_how_to_go_on(Path(output_dir) / 'checkpoints', incomplete)}"
            )


CHECKPOINT_FILES = (
    "pretrained_model/config.json",
    "pretrained_model/model.safetensors",
    "pretrained_model/train_config.json",
    "training_state/training_step.json",
    "training_state/optimizer_state.safetensors",
)
"""What every checkpoint LeRobot saves holds, the policy's files first and the optimiser's last."""


def _incomplete_checkpoints(checkpoints: Path) -> list[Path]:
    """The numbered checkpoints newer than `last` (all of them without it) that lack one of their files."""
    last = checkpoints / "last"
    done = int(last.resolve().name) if last.exists() and last.resolve().name.isdigit() else -1
    numbered = sorted((p for p in checkpoints.iterdir() if p.name.isdigit()), key=lambda p: int(p.name))
    return [
        p for p in numbered if int(p.name) > done and not all((p / f).is_file() for f in CHECKPOINT_FILES)
    ]


def _how_to_go_on(checkpoints: Path, incomplete: list[Path]) -> str:
    """What to delete, and what to resume from, when `incomplete` checkpoints are in `checkpoints`."""
    bad = {p.name for p in incomplete}
    complete = [p for p in checkpoints.iterdir() if p.name.isdigit() and p.name not in bad]
    remove = " ".join(str(p) for p in incomplete)
    if not complete:
        return f"no checkpoint is complete: delete {checkpoints.parent} and train again"
    good = max(complete, key=lambda p: int(p.name))
    return (
        f"delete {remove} and resume from checkpoint {good.name}: --resume=true "
        f"--config_path={good / 'pretrained_model' / 'train_config.json'}"
    )


def _check_resumable(checkpoints: Path, name: str, flag: str) -> None:
    """A resumed checkpoint (`last` or a numbered one) exists and is complete."""
    incomplete = _incomplete_checkpoints(checkpoints) if checkpoints.is_dir() else []
    target = checkpoints / name
    if incomplete and (not target.exists() or target.resolve() in {p.resolve() for p in incomplete}):
        raise ValueError(
            f"{flag}: checkpoint {incomplete[-1].name} is incomplete (the run was killed while saving it"
            f"{f', before {target} was made' if name == 'last' and not target.exists() else ''}); "
            f"{_how_to_go_on(checkpoints, incomplete)}"
        )


def _reuse_freed_memory() -> None:
    """Has glibc keep freed memory for reuse: by default it maps blocks over 128 KB (the bound rises to 32
    MB as it goes) afresh and unmaps them on free, and trims free memory off the heap, so the activations a
    CPU training step allocates come back as new pages every step, each a page fault (about 10,000 a step
    for the `small` scale's policy, whose update this makes 20-25 % faster on 2 cores). The process keeps
    its peak memory instead. Other C libraries are left alone."""
    if platform.libc_ver()[0] != "glibc":
        return
    mallopt = ctypes.CDLL("libc.so.6").mallopt
    m_trim_threshold, m_mmap_threshold = -1, -3
    if not mallopt(m_mmap_threshold, 1 << 30):
        mallopt(m_mmap_threshold, 32 << 20)  # the most older glibc versions accept
    mallopt(m_trim_threshold, (1 << 31) - 1)


def _in_memory(make_train_eval_datasets):
    """LeRobot's dataset factory, with its map-style datasets read into memory."""
    import torch

    from lerobot_opfa.datasets.in_memory import InMemoryDataset
    from lerobot_opfa.process_group import hold_until_exit

    @functools.wraps(make_train_eval_datasets)
    def make(cfg):
        if cfg.dataset.streaming:
            raise ValueError("the in-memory fast path reads whole datasets, not streams; use lerobot-train")
        hold_until_exit()  # the accelerator (and its process group) exists by now; see process_group.py
        dataset, eval_dataset = make_train_eval_datasets(cfg)
        start = time.perf_counter()
        dataset = InMemoryDataset(dataset)
        eval_dataset = None if eval_dataset is None else InMemoryDataset(eval_dataset)
        seconds = time.perf_counter() - start
        logging.info(
            f"Dataset held in memory: {dataset.num_frames} frames read in {seconds:.2f} s; "
            f"torch threads: {torch.get_num_threads()}"
        )
        return dataset, eval_dataset

    return make
