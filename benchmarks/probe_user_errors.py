"""User-error probes (issue 30): every command fed the mistakes a user makes, each input classified.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl .venv/bin/python benchmarks/probe_user_errors.py [--only NAME] [--keep]

Why it exists: the guards that refuse bad input (outputs over inputs, joints beyond their limits, NaN, clouds
of the wrong size, specs that lie about their model, interrupted writes ...) are each tested in tests/, but
the question the issue asks is about the whole surface: for every kind of mistake, does the user get one
line that names the culprit, with nothing lost and nothing half-written? This script asks it again on the
current code, from scratch, and writes the answer down (benchmarks/results/probes.json), so that a change
anywhere can be checked against it.

It builds its own small fixtures in a temporary folder (synthetic per-hand datasets, a tiny GaLR, merged
and latent datasets, a tiny trained `opfa` policy, edited copies of the built-in hand specs, a hand with an
STL mesh), then runs each probe: `lerobot-opfa` in this process (`cli.main`, output captured), or a real
subprocess where the entry point or a signal matters (`lerobot-train`, `lerobot-eval`, SIGINT / SIGTERM /
SIGKILL during a write, the stderr noise of a failing command), or the Python API (a policy's processors).
Each probe says what it expects: `refuse` (with the words a clear message must contain: the file, the
joint, the flag) or `accept` (with a check of the result). The verdict, in order of precedence:

- `data lost`: an input file or folder was changed or removed (names, sizes and mtimes of every fixture
  and of the probe's own inputs, before and after);
- `half-written output`: a `*.partial-*` / `*.old-*` folder left behind, or an output written by a command
  that failed;
- `traceback`: a Python traceback reached the user (an exception escaping `cli.main`, or "Traceback (most
  recent call last)" in a subprocess's output) for a user mistake;
- `silent wrong result`: exit 0 / no exception, but the bad input was accepted or the result is wrong;
- `unclear error`: refused, but the message lacks a word naming the culprit, is not one line (more than 3
  lines of stderr where a probe counts them), or (Python API) is not a ValueError;
- `clear error` / `handled correctly`: refused with a message naming the culprit / accepted and right.

The whole run takes about 10-20 minutes on a 2-core CPU.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

for _key, _value in {
    "HF_HUB_OFFLINE": "1",
    "HF_DATASETS_OFFLINE": "1",
    "MUJOCO_GL": "egl",
    "OMP_NUM_THREADS": "1",
    "TOKENIZERS_PARALLELISM": "false",
}.items():
    os.environ.setdefault(_key, _value)

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "probes.json"
BIN = Path(sys.executable).parent
ENV = dict(os.environ)
TRACEBACK = "Traceback (most recent call last)"
VERDICTS = (
    "clear error",
    "handled correctly",
    "unclear error",
    "traceback",
    "silent wrong result",
    "half-written output",
    "data lost",
)
MAX_ERROR_LINES = 3
"""A failing command whose stderr a probe counts must say what is wrong in at most this many lines."""

TINY_GALR = [
    "latent_dim=4",
    "encoder=pointnet",
    "n_points=32",
    "n_level1=16",
    "n_superpoints=14",
    "widths=8,16,16",
    "decoder_hidden=16",
]
TINY_POLICY = {
    "--policy.type": "opfa",
    "--policy.device": "cpu",
    "--policy.push_to_hub": "false",
    "--policy.down_dims": "[16,32]",
    "--policy.horizon": "8",
    "--policy.n_action_steps": "4",
    "--policy.pointcloud_widths": "[16,32]",
    "--policy.pointcloud_feature_dim": "16",
    "--policy.n_groups": "4",
    "--policy.diffusion_step_embed_dim": "16",
    "--steps": "2",
    "--batch_size": "4",
    "--save_freq": "2",
    "--log_freq": "1",
    "--num_workers": "0",
    "--wandb.enable": "false",
}


# --- outcomes and probes ---------------------------------------------------------------------------
@dataclass
class Outcome:
    rc: int | None = None
    """Exit code (`cli.main`'s return or SystemExit, a subprocess's); None for a Python API call."""
    out: str = ""
    err: str = ""
    escaped: str | None = None
    """An exception that escaped `cli.main` (a traceback the user would see), as 'Type: message'."""
    raised: BaseException | None = None
    """Python API probes: the exception the call raised (a refusal, not a traceback)."""
    value: Any = None
    note: str = ""

    @property
    def api(self) -> bool:
        return self.rc is None and self.escaped is None

    @property
    def refused(self) -> bool:
        return self.raised is not None if self.api else (self.rc != 0 or self.escaped is not None)


@dataclass
class Probe:
    name: str
    kind: str
    command: str
    expected: str
    run: Callable[[], Outcome]
    words: tuple[str | tuple[str, ...], ...] = ()
    """refuse: words (case-insensitive) a clear message must contain; a tuple: one of its words."""
    check: Callable[[Outcome], str | None] | None = None
    """accept: None if the result is right, else what is wrong."""
    setup: Callable[[], None] | None = None
    inputs: tuple[Path, ...] = ()
    """The probe's own input files/folders (besides every fixture), which must come out unchanged."""
    absent: tuple[Path, ...] = ()
    """Outputs that must not exist after a refusal."""
    count_lines: bool = False
    """Classify more than MAX_ERROR_LINES lines of stderr as an unclear error."""
    either_words: tuple[str, ...] = ()
    """accept probes where a one-line refusal naming these words is also right (a `clear error`)."""


MISSING = ("not found", "no such", "does not exist", "not a ", "no meta")
"""One of these says that a path the user gave is not there (besides naming it)."""
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def _last_lines(text: str) -> list[str]:
    lines = [ANSI.sub("", seg).strip() for line in text.splitlines() for seg in line.split("\r")]
    return [line for line in lines if line]


def error_message(outcome: Outcome) -> str:
    """What the user reads as the error: the exception, or stderr from its last 'error:' line on (else the
    last line of stderr, or of stdout)."""
    if outcome.escaped:
        return outcome.escaped
    if outcome.api:
        raised = outcome.raised
        return f"{type(raised).__name__}: {raised}" if raised is not None else outcome.note
    lines = _last_lines(outcome.err) or _last_lines(outcome.out)
    for i in range(len(lines) - 1, -1, -1):
        if re.match(r"^(\S+: )?error: |^[\w.]*(Error|Exception): ", lines[i]):
            return " | ".join(lines[i:])
    return lines[-1] if lines else ""


def snapshot(paths: list[Path]) -> dict[str, tuple[int, int]]:
    """Every file and folder under `paths`: relative name -> (size, mtime_ns)."""
    state = {}
    for root in paths:
        if not root.exists() and not root.is_symlink():
            continue
        for p in [root, *root.rglob("*")] if root.is_dir() else [root]:
            with contextlib.suppress(FileNotFoundError):
                st = p.lstat()
                state[str(p)] = (st.st_size if p.is_file() else -1, st.st_mtime_ns if p.is_file() else 0)
    return state


def leftovers(paths: list[Path]) -> list[str]:
    found = []
    for root in paths:
        if root.is_dir():
            found += [str(p) for p in root.rglob("*") if ".partial" in p.name or ".old-" in p.name]
    return sorted(found)


def classify(probe: Probe, outcome: Outcome, before: dict, after: dict, left: list[str]) -> tuple[str, str]:
    message = error_message(outcome)
    changed = sorted(k for k in before if k not in after or after[k] != before[k])
    if changed:
        return "data lost", f"input changed or removed: {', '.join(changed[:3])}; " + message
    if left:
        return "half-written output", f"left behind: {', '.join(left[:3])}; " + message
    added = sorted(k for k in after if k not in before)
    if outcome.refused and (added or any(p.exists() for p in probe.absent)):
        written = added[:2] or [str(p) for p in probe.absent if p.exists()]
        return "half-written output", f"failed but wrote {', '.join(written)}; " + message
    if outcome.escaped or TRACEBACK in outcome.err or TRACEBACK in outcome.out:
        return "traceback", message
    has_words = all(
        any(alt.lower() in message.lower() for alt in ((w,) if isinstance(w, str) else w))
        for w in probe.words
    )
    noisy = probe.count_lines and len(_last_lines(outcome.err)) > MAX_ERROR_LINES
    if probe.expected == "refuse":
        if not outcome.refused:
            return "silent wrong result", (outcome.note or "accepted") + (f"; {message}" if message else "")
        if outcome.api and not isinstance(outcome.raised, ValueError):
            return "unclear error", message
        if noisy:
            return "unclear error", f"{len(_last_lines(outcome.err))} lines of stderr; last: {message}"
        return ("clear error" if has_words else "unclear error"), message
    if outcome.refused:
        either = probe.either_words and all(w.lower() in message.lower() for w in probe.either_words)
        return ("clear error" if either and not noisy else "unclear error"), message
    try:
        problem = probe.check(outcome) if probe.check else None
    except Exception as exc:  # noqa: BLE001 - a result that cannot be read is a wrong one
        problem = f"result unreadable ({type(exc).__name__}: {exc})"
    message = f"{outcome.note}; {message}" if outcome.note else message
    return ("silent wrong result", f"{problem}; {message}") if problem else ("handled correctly", message)


# --- runners ---------------------------------------------------------------------------------------
class _StderrNow(logging.StreamHandler):
    """A log handler writing to whatever sys.stderr is at the time (the probe's captured stream)."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


def _reset_logging() -> None:
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    handler = _StderrNow()
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root.addHandler(handler)
    root.setLevel(logging.WARNING)


def cli(argv: list[str]) -> Callable[[], Outcome]:
    def run() -> Outcome:
        from lerobot_opfa import cli as opfa_cli

        out, err, outcome = io.StringIO(), io.StringIO(), Outcome()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                outcome.rc = opfa_cli.main([str(a) for a in argv])
            except SystemExit as exit_:
                outcome.rc = exit_.code if isinstance(exit_.code, int) else 1
            except BaseException as exc:  # noqa: BLE001 - what escapes main() is what the user sees
                outcome.escaped = f"{type(exc).__name__}: {exc}"
                outcome.rc = 1
                err.write(traceback.format_exc())
        outcome.out, outcome.err = out.getvalue(), err.getvalue()
        return outcome

    return run


def without_torchcodec_noise(err: str) -> str:
    """stderr without the FFmpeg-loading tracebacks that stock LeRobot entry points log (about 100 lines
    each time) where FFmpeg's libraries are missing: the machine's, not a reply to the user's input."""
    pattern = re.compile(
        r"\[start of libtorchcodec loading traceback\].*?\[end of libtorchcodec loading traceback\]\.?",
        re.DOTALL,
    )
    return pattern.sub("[torchcodec loading traceback left out]", err)


def interruptible() -> None:
    """Ctrl-C reaches the child even when this script runs in the background (a shell starts background
    jobs with SIGINT ignored, which children inherit and Python then leaves alone)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def proc(cmd: list[str], cwd: Path, timeout: float = 300) -> Callable[[], Outcome]:
    def run() -> Outcome:
        cwd.mkdir(parents=True, exist_ok=True)
        process = subprocess.Popen(
            [str(c) for c in cmd], cwd=cwd, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, preexec_fn=interruptible,
        )  # fmt: skip
        try:
            out, err = process.communicate(timeout=timeout)
            return Outcome(rc=process.returncode, out=out, err=without_torchcodec_noise(err))
        except subprocess.TimeoutExpired:
            process.send_signal(signal.SIGINT)  # let it clean up as after Ctrl-C
            try:
                out, err = process.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                process.kill()
                out, err = process.communicate()
            note = f"still running after {timeout:g} s (then SIGINT)"
            return Outcome(rc=0, out=out, err=without_torchcodec_noise(err), note=note)

    return run


def interrupted(cmd: list[str], cwd: Path, output: Path, sig: int, then: Callable[[], Outcome] | None = None):
    """Starts `cmd`, sends `sig` once its partial output folder exists (it is writing), and waits; `then`
    (a rerun) runs after, and its outcome is the probe's."""

    def run() -> Outcome:
        cwd.mkdir(parents=True, exist_ok=True)
        process = subprocess.Popen(
            [str(c) for c in cmd], cwd=cwd, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, preexec_fn=interruptible,
        )  # fmt: skip
        deadline, writing = time.monotonic() + 240, False
        while process.poll() is None and time.monotonic() < deadline:
            if output.parent.is_dir() and any(
                p.name.startswith(f".{output.name}.partial-") for p in output.parent.iterdir()
            ):
                writing = True
                break
            time.sleep(0.05)
        time.sleep(1.0)  # well inside the write: episodes saved, more to come
        sent = process.poll() is None
        if sent:
            process.send_signal(sig)
        out, err = process.communicate(timeout=180)
        note = "" if sent and writing else "the command ended before the signal: make the dataset larger"
        first = Outcome(rc=process.returncode, out=out, err=err, note=note)
        if then is None:
            return first
        if not sent:
            return first
        left = leftovers([output.parent])
        rerun = then()
        rerun.note = (
            f"after {signal.Signals(sig).name} (exit {process.returncode}, which left {len(left)} partial "
            f"folder(s)): " + rerun.note
        ).rstrip(": ")
        return rerun

    return run


def python_in_subprocess(code: str, cwd: Path) -> Callable[[], Any]:
    """A Python API call in a fresh interpreter (no state left by other probes): returns what the code
    leaves in `action`, or raises (as ValueError, or RuntimeError naming another type) what it raised."""
    wrapper = (
        "import sys, traceback\ntry:\n"
        + "".join(f"    {line}\n" for line in code.splitlines())
        + "    print('VALUE', tuple(action.shape), bool(action.isfinite().all()))\n"
        "except Exception as exc:\n    print('RAISED', type(exc).__name__, str(exc).replace(chr(10), ' '))\n"
    )

    def call() -> Any:
        cwd.mkdir(parents=True, exist_ok=True)
        result = subprocess.run(
            [sys.executable, "-c", wrapper], cwd=cwd, env=ENV, capture_output=True, text=True
        )
        last = (_last_lines(result.stdout) or [f"RAISED RuntimeError exit {result.returncode}"])[-1]
        kind, _, rest = last.partition(" ")
        if kind == "VALUE":
            return rest
        name, _, message = rest.partition(" ")
        raise ValueError(message) if name.endswith("ValueError") else RuntimeError(f"{name}: {message}")

    return call


def api(fn: Callable[[], Any]) -> Callable[[], Outcome]:
    def run() -> Outcome:
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                value = fn()
            except Exception as exc:  # noqa: BLE001 - a refusal is what the probe looks for
                return Outcome(raised=exc, err=err.getvalue())
        warnings = _last_lines(err.getvalue())
        return Outcome(value=value, err=err.getvalue(), note=f"warned: {warnings[-1]}" if warnings else "")

    return run


# --- fixtures --------------------------------------------------------------------------------------
def must(argv: list[str]) -> None:
    outcome = cli(argv)()
    if outcome.rc != 0:
        raise RuntimeError(
            f"fixture failed: lerobot-opfa {shlex.join(map(str, argv))}\n{outcome.err[-3000:]}"
        )


def synthetic(out: Path, hand: str, *extra: str) -> None:
    must(
        [
            "dataset",
            "synthetic",
            "--hand",
            hand,
            "--output",
            out,
            "--episodes",
            "2",
            "--frames",
            "10",
            "--n-points",
            "128",
            *extra,
        ]
    )


def tiny_galr(out: Path, hands: str) -> None:
    must(
        [
            "galr",
            "pretrain",
            "--hands",
            hands,
            "--steps",
            "2",
            "--batch-size",
            "4",
            "--validate-every",
            "2",
            "--save-every",
            "2",
            "--output-dir",
            out,
            "--model",
            *TINY_GALR,
        ]
    )


def dataset_without_clouds(out: Path, source: Path) -> None:
    """A umi dataset holding state, action and object state only (no point clouds)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_opfa.datasets.io import read_columns

    info = json.loads((source / "meta" / "info.json").read_text())
    keep = ("observation.state", "action", "observation.environment_state")
    features = {k: {**info["features"][k], "shape": tuple(info["features"][k]["shape"])} for k in keep}
    columns = read_columns(source, [*keep, "episode_index"])
    dataset = LeRobotDataset.create(
        repo_id=f"local/{out.name}",
        root=out,
        fps=info["fps"],
        features=features,
        robot_type="umi",
        use_videos=False,
    )
    episodes = columns["episode_index"]
    for episode in sorted(set(episodes.tolist())):
        for row in (episodes == episode).nonzero()[0]:
            dataset.add_frame({**{k: columns[k][row].astype("float32") for k in keep}, "task": "lift"})
        dataset.save_episode()
    dataset.finalize()


def set_state(root: Path, entry: int, value: float, rows: slice, key: str = "observation.state") -> None:
    """Writes `value` into entry `entry` of column `key` for the frames `rows` of the first data file."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = next((root / "data").rglob("*.parquet"))
    table = pq.read_table(path)
    column = table.column(key).combine_chunks()
    state = column.flatten().to_numpy().reshape(len(column), -1).copy()
    state[rows, entry] = value
    array = pa.FixedSizeListArray.from_arrays(pa.array(state.reshape(-1), pa.float32()), state.shape[1])
    index = table.schema.get_field_index(key)
    pq.write_table(table.set_column(index, key, array.cast(column.type)), path)


def mesh_hand(folder: Path) -> Path:
    """A copy of the umi gripper named `mesh_umi` whose left jaw is an STL mesh (jaw.stl) instead of a box."""
    import trimesh

    shutil.copytree(REPO / "hand_models" / "umi", folder)
    spec = folder / "spec.yaml"
    spec.write_text(spec.read_text().replace("name: umi", "name: mesh_umi"))
    urdf = folder / "umi.urdf"
    urdf.write_text(
        urdf.read_text().replace('<box size="0.012 0.028 0.10" />', '<mesh filename="jaw.stl" />', 2)
    )
    trimesh.creation.box(extents=(0.012, 0.028, 0.10)).export(folder / "jaw.stl")
    return spec


def copy_hand(
    source: Path,
    target: Path,
    spec_edit: Callable[[str], str] | None = None,
    urdf_edit: Callable[[str], str] | None = None,
) -> Path:
    shutil.copytree(source, target)
    spec = target / "spec.yaml"
    if spec_edit:
        spec.write_text(spec_edit(spec.read_text()))
    if urdf_edit:
        urdf = next(target.glob("*.urdf"))
        urdf.write_text(urdf_edit(urdf.read_text()))
    return spec


def wider_jaws(text: str) -> str:
    return text.replace('box size="0.012 0.028 0.10"', 'box size="0.012 0.028 0.15"')


def build_fixtures(f: Path) -> dict[str, Path]:
    from lerobot_opfa.datasets.synthetic import write_synthetic_dataset

    ds = f / "ds"
    fx = {
        name: ds / name
        for name in (
            "umi",
            "inspire",
            "umi256",
            "inspire256",
            "big_umi",
            "inspire_1frame",
            "umi_fps20",
            "umi_badjoint",
            "umi_nocloud",
            "merged",
            "merged_galr",
            "merged256",
            "latent",
            "demos_umi",
        )
    }
    synthetic(fx["umi"], "umi")
    synthetic(fx["inspire"], "inspire", "--seed", "1")
    synthetic(fx["umi256"], "umi", "--n-points", "256", "--seed", "2")
    synthetic(fx["inspire256"], "inspire", "--n-points", "256", "--seed", "3")
    synthetic(fx["big_umi"], "umi", "--episodes", "40", "--frames", "40", "--seed", "4")
    synthetic(fx["inspire_1frame"], "inspire", "--episodes", "3", "--frames", "1")
    write_synthetic_dataset(fx["umi_fps20"], "umi", episodes=2, frames=10, n_points=128, fps=20, seed=5)
    write_synthetic_dataset(fx["umi_badjoint"], "umi", 2, 10, 128, seed=6, joint_names=["nosuch_joint"])
    dataset_without_clouds(fx["umi_nocloud"], fx["umi"])
    fx["galr"], fx["galr_umi"] = f / "galr", f / "galr_umi"
    tiny_galr(fx["galr"], "umi,inspire")
    tiny_galr(fx["galr_umi"], "umi")
    must(["dataset", "merge", "--inputs", fx["umi"], fx["inspire"], "--output", fx["merged"]])
    must(
        [
            "dataset",
            "merge",
            "--inputs",
            fx["umi"],
            fx["inspire"],
            "--output",
            fx["merged_galr"],
            "--galr",
            fx["galr"],
        ]
    )
    must(
        [
            "dataset",
            "merge",
            "--inputs",
            fx["umi256"],
            fx["inspire256"],
            "--output",
            fx["merged256"],
            "--galr",
            fx["galr"],
        ]
    )
    must(["policy", "latent-dataset", "--input", fx["merged_galr"], "--output", fx["latent"]])
    must(
        [
            "sim",
            "demos",
            "--task",
            "press_button",
            "--hand",
            "umi",
            "--episodes",
            "1",
            "--output-dir",
            fx["demos_umi"],
            "--n-points",
            "128",
            "--pointcloud-source",
            "geometry",
        ]
    )
    fx["mesh_umi"] = mesh_hand(f / "hands" / "mesh_umi").parent
    fx["empty"] = f / "empty"
    fx["empty"].mkdir()
    fx["train"] = f / "train"
    fx["checkpoint"] = fx["train"] / "checkpoints" / "last" / "pretrained_model"
    return fx


# --- the probes ------------------------------------------------------------------------------------
def define_probes(fx: dict[str, Path], work: Path) -> list[Probe]:  # noqa: C901 - one list, read top down
    import numpy as np
    import torch

    probes: list[Probe] = []
    tmp = str(work.parent)

    def show(argv: list[str], exe: str = "lerobot-opfa") -> str:
        return (exe + " " + shlex.join(map(str, argv))).replace(tmp, "$TMP")

    def w(name: str) -> Path:
        return work / name

    def add_cli(name, kind, argv, expected="refuse", words=(), **kw):
        probes.append(Probe(name, kind, show(argv), expected, cli(argv), tuple(words), **kw))

    def add_proc(name, kind, cmd, expected="refuse", words=(), timeout=300, **kw):
        cwd = w(name)
        exe = Path(cmd[0]).name
        probes.append(
            Probe(name, kind, show(cmd[1:], exe), expected, proc(cmd, cwd, timeout), tuple(words), **kw)
        )

    def add_api(name, kind, command, fn, expected="refuse", words=(), **kw):
        probes.append(Probe(name, kind, command, expected, api(fn), tuple(words), **kw))

    def copy(source: Path, target: Path) -> Callable[[], None]:
        return lambda: shutil.copytree(source, target)

    def frames_of(root: Path, n: int, hands: list[str] | None = None) -> Callable[[Outcome], str | None]:
        def check(_: Outcome) -> str | None:
            info = json.loads((root / "meta" / "info.json").read_text())
            if info["total_frames"] != n:
                return f"{root.name} holds {info['total_frames']} frames, expected {n}"
            names = info["features"].get("observation.embodiment", {}).get("names")
            if hands is not None and names != hands:
                return f"embodiments {names}, expected {hands}"
            return None

        return check

    def file_exists(path: Path) -> Callable[[Outcome], str | None]:
        return lambda _: None if path.is_file() and path.stat().st_size > 0 else f"{path} was not written"

    umi, inspire, galr = fx["umi"], fx["inspire"], fx["galr"]
    merge = ["dataset", "merge", "--inputs"]

    # --- merge: never over or around an input (issue item 1) --------------------------------------
    for name, output in (
        ("merge_output_is_an_input", "umi"),
        ("merge_output_inside_an_input", "umi/merged"),
        ("merge_output_is_the_inputs_parent", "."),
    ):
        d = w(name)
        add_cli(
            name,
            "merge",
            [*merge, d / "umi", d / "inspire", "--output", d / output, "--galr", "long", "--overwrite"],
            words=["would write over", "umi"],
            setup=lambda d=d: (copy(umi, d / "umi")(), copy(inspire, d / "inspire")()),
            inputs=(d,),
        )
    d = w("merge_a_dataset_with_itself")
    add_cli(
        "merge_a_dataset_with_itself",
        "merge",
        [*merge, umi, umi, "--output", d / "m"],
        words=["more than once", "umi"],
        absent=(d / "m",),
    )
    d = w("merge_a_dataset_with_a_symlink_to_itself")
    add_cli(
        "merge_a_dataset_with_a_symlink_to_itself",
        "merge",
        [*merge, umi, d / "link", "--output", d / "m"],
        words=["more than once"],
        setup=lambda d=d: (d / "link").symlink_to(umi),
        absent=(d / "m",),
    )

    # --- merge: interrupted writes, reruns (item 2) -------------------------------------------------
    d = w("merge_sigint_while_writing")
    big = [BIN / "lerobot-opfa", *merge, fx["big_umi"], inspire, "--output", d / "m"]
    probes.append(
        Probe(
            "merge_sigint_while_writing",
            "merge",
            show(big[1:]) + "  # SIGINT once writing",
            "refuse",
            interrupted(big, d, d / "m", signal.SIGINT),
            ("interrupted",),
            absent=(d / "m",),
        )
    )
    probes.append(
        Probe(
            "merge_rerun_after_sigint",
            "merge",
            show(big[1:]) + "  # again, after the SIGINT",
            "accept",
            cli(big[1:]),
            check=frames_of(d / "m", 1620, ["umi", "inspire"]),
        )
    )
    d = w("merge_sigterm_while_writing")
    big = [BIN / "lerobot-opfa", *merge, fx["big_umi"], inspire, "--output", d / "m"]
    probes.append(
        Probe(
            "merge_sigterm_while_writing",
            "merge",
            show(big[1:]) + "  # SIGTERM once writing",
            "refuse",
            interrupted(big, d, d / "m", signal.SIGTERM),
            ("interrupted",),
            absent=(d / "m",),
        )
    )
    d = w("merge_rerun_after_sigkill")
    big = [BIN / "lerobot-opfa", *merge, fx["big_umi"], inspire, "--output", d / "m"]
    probes.append(
        Probe(
            "merge_rerun_after_sigkill",
            "merge",
            show(big[1:]) + "  # SIGKILL once writing, then the same command again",
            "accept",
            interrupted(big, d, d / "m", signal.SIGKILL, then=cli(big[1:])),
            check=frames_of(d / "m", 1620),
        )
    )

    # --- merge: inputs that disagree, bad values (items 4, 5) ---------------------------------------
    add_cli(
        "merge_clouds_of_256_and_128_points",
        "merge",
        [*merge, umi, fx["umi256"], "--output", w("m4") / "m"],
        words=["observation.pointcloud", "umi256"],
        absent=(w("m4") / "m",),
    )
    d = w("merge_joint_at_50_rad")
    add_cli(
        "merge_joint_at_50_rad",
        "merge",
        [*merge, d / "inspire", "--output", d / "m"],
        words=["index_mcp_flex", "inspire", "limits"],
        inputs=(d / "inspire",),
        absent=(d / "m",),
        setup=lambda d=d: (
            copy(inspire, d / "inspire")(),
            set_state(d / "inspire", 6 + 2, 50.0, slice(2, 5)),
        ),
    )
    d = w("merge_nan_joint")
    add_cli(
        "merge_nan_joint",
        "merge",
        [*merge, d / "inspire", "--output", d / "m"],
        words=["not finite", "inspire"],
        inputs=(d / "inspire",),
        absent=(d / "m",),
        setup=lambda d=d: (
            copy(inspire, d / "inspire")(),
            set_state(d / "inspire", 7, float("nan"), slice(0, 1)),
        ),
    )
    d = w("merge_nan_wrist_in_action")
    add_cli(
        "merge_nan_wrist_in_action",
        "merge",
        [*merge, d / "umi", "--output", d / "m"],
        words=["not finite", "action"],
        inputs=(d / "umi",),
        absent=(d / "m",),
        setup=lambda d=d: (
            copy(umi, d / "umi")(),
            set_state(d / "umi", 0, float("nan"), slice(3, 4), "action"),
        ),
    )
    add_cli(
        "merge_joint_name_not_in_the_model",
        "merge",
        [*merge, fx["umi_badjoint"], "--output", w("m5") / "m"],
        words=["nosuch_joint"],
        absent=(w("m5") / "m",),
    )

    def merged_at(root: Path, fps: int, input_fps: list[int]) -> Callable[[Outcome], str | None]:
        def check(_: Outcome) -> str | None:
            rate = json.loads((root / "meta" / "info.json").read_text())["fps"]
            recorded = json.loads((root / "meta" / "opfa.json").read_text())["input_fps"]
            return None if (rate, recorded) == (fps, input_fps) else f"{rate} fps from {recorded}"

        return check

    at_two_rates = [*merge, umi, fx["umi_fps20"], "--output", w("m6") / "m"]
    probes.append(  # inputs at 10 and 20 fps merge at the lower rate (resampled), each input's kept
        Probe(
            "merge_inputs_at_different_fps", "merge", show(at_two_rates), "accept", cli(at_two_rates),
            check=merged_at(w("m6") / "m", 10, [10, 20]),
        )
    )  # fmt: skip
    add_cli(
        "merge_sim_demos_with_synthetic_fps",
        "merge",
        [*merge, fx["demos_umi"], inspire, "--output", w("m7") / "m"],
        words=["observation.environment_state", "record them alike"],
        absent=(w("m7") / "m",),
    )
    add_cli(
        "merge_galr_without_an_inputs_hand",
        "merge",
        [*merge, umi, inspire, "--output", w("m8") / "m", "--galr", fx["galr_umi"]],
        words=["inspire"],
        absent=(w("m8") / "m",),
    )
    d = w("merge_map_with_a_mistyped_entry")

    def typo_map(d: Path = d) -> None:
        names = json.loads((inspire / "meta" / "info.json").read_text())["features"]["observation.state"][
            "names"
        ]
        joints = {name: {"joint": name} for name in names[6:]}
        joints["thumb_benx"] = joints.pop("thumb_bend")
        d.mkdir(parents=True, exist_ok=True)
        (d / "map.yaml").write_text(json.dumps({"hand": "inspire", "joints": joints}))

    add_cli(
        "merge_map_with_a_mistyped_entry",
        "merge",
        [*merge, inspire, "--output", d / "m", "--joint-maps", d / "map.yaml"],
        words=["thumb_benx", "thumb_bend"],
        absent=(d / "m",),
        setup=typo_map,
    )

    # --- merge: a spec named like a built-in but different (item 6) ---------------------------------
    d = w("merge_dataset_of_a_copy_named_umi_then_changed")

    def recorded_then_changed(d=d):
        spec = copy_hand(REPO / "hand_models" / "umi", d / "umi_copy")
        must(
            [
                "dataset",
                "synthetic",
                "--hand",
                spec,
                "--output",
                d / "ds",
                "--episodes",
                "1",
                "--frames",
                "6",
                "--n-points",
                "128",
            ]
        )
        urdf = d / "umi_copy" / "umi.urdf"
        urdf.write_text(wider_jaws(urdf.read_text()))

    # The data was recorded with a copy identical to the built-in (same sha256), so the built-in is the
    # hand it was recorded with; the changed copy is refused where it is named (the two probes below).
    add_cli(
        "merge_dataset_of_a_copy_named_umi_then_changed",
        "merge",
        [*merge, d / "ds", "--output", d / "m"],
        "accept",
        setup=recorded_then_changed,
        inputs=(d / "ds",),
    )
    d = w("synthetic_on_a_changed_spec_named_umi")
    add_cli(
        "synthetic_on_a_changed_spec_named_umi",
        "synthetic",
        [
            "dataset",
            "synthetic",
            "--hand",
            d / "wide_umi" / "spec.yaml",
            "--output",
            d / "ds",
            "--episodes",
            "1",
            "--frames",
            "4",
        ],
        words=["built-in", "name"],
        absent=(d / "ds",),
        setup=lambda d=d: copy_hand(REPO / "hand_models" / "umi", d / "wide_umi", urdf_edit=wider_jaws),
    )
    d = w("galr_init_long_with_a_changed_umi")
    add_cli(
        "galr_init_long_with_a_changed_umi",
        "galr",
        [
            "galr",
            "pretrain",
            "--init",
            "long",
            "--hands",
            f"+{d / 'wide_umi' / 'spec.yaml'}",
            "--steps",
            "1",
            "--output-dir",
            d / "run",
        ],
        words=["built-in", "name"],
        absent=(d / "run",),
        setup=lambda d=d: copy_hand(REPO / "hand_models" / "umi", d / "wide_umi", urdf_edit=wider_jaws),
    )

    # --- merge: paths and folders that are not what they should be ----------------------------------
    add_cli(
        "merge_input_does_not_exist",
        "merge",
        [*merge, w("nowhere") / "umi_typo", "--output", w("m9") / "m"],
        words=["umi_typo", MISSING],
        absent=(w("m9") / "m",),
    )
    add_cli(
        "merge_input_not_a_dataset",
        "merge",
        [*merge, fx["empty"], "--output", w("m10") / "m"],
        words=["not a LeRobotDataset", "empty"],
        absent=(w("m10") / "m",),
    )
    d = w("merge_corrupt_info_json")
    add_cli(
        "merge_corrupt_info_json",
        "merge",
        [*merge, d / "umi", "--output", d / "m"],
        words=["info.json", "not valid JSON"],
        inputs=(d / "umi",),
        absent=(d / "m",),
        setup=lambda d=d: (
            copy(umi, d / "umi")(),
            (d / "umi/meta/info.json").write_text((umi / "meta/info.json").read_text()[:200]),
        ),
    )
    d = w("merge_missing_data_file")
    add_cli(
        "merge_missing_data_file",
        "merge",
        [*merge, d / "umi", "--output", d / "m"],
        words=["parquet"],
        inputs=(d / "umi",),
        absent=(d / "m",),
        setup=lambda d=d: (copy(umi, d / "umi")(), (d / "umi/data/chunk-000/file-000.parquet").unlink()),
    )
    d = w("merge_truncated_data_file")
    add_cli(
        "merge_truncated_data_file",
        "merge",
        [*merge, d / "umi", "--output", d / "m"],
        words=["file-000.parquet"],
        inputs=(d / "umi",),
        absent=(d / "m",),
        setup=lambda d=d: (copy(umi, d / "umi")(), _truncate(d / "umi/data/chunk-000/file-000.parquet")),
    )
    d = w("merge_missing_episodes_metadata")
    add_cli(
        "merge_missing_episodes_metadata",
        "merge",
        [*merge, d / "umi", "--output", d / "m"],
        words=["episodes"],
        inputs=(d / "umi",),
        absent=(d / "m",),
        setup=lambda d=d: (copy(umi, d / "umi")(), shutil.rmtree(d / "umi/meta/episodes")),
    )
    add_cli(
        "merge_a_merged_dataset_again",
        "merge",
        [*merge, fx["merged"], umi, "--output", w("m11") / "m"],
        words=["already a merged dataset", "merged"],
        absent=(w("m11") / "m",),
    )
    add_cli(
        "merge_a_latent_dataset",
        "merge",
        [*merge, fx["latent"], "--output", w("m12") / "m"],
        words=["latent"],
        absent=(w("m12") / "m",),
    )
    add_cli(
        "merge_unknown_galr",
        "merge",
        [*merge, umi, "--output", w("m13") / "m", "--galr", "longg"],
        words=["longg", MISSING],
        absent=(w("m13") / "m",),
    )
    add_cli(
        "merge_galr_empty_folder",
        "merge",
        [*merge, umi, "--output", w("m14") / "m", "--galr", fx["empty"]],
        words=["config.json", "empty"],
        absent=(w("m14") / "m",),
    )
    d = w("merge_output_exists_without_overwrite")
    add_cli(
        "merge_output_exists_without_overwrite",
        "merge",
        [*merge, umi, inspire, "--output", d / "m"],
        words=["exists", "--overwrite"],
        setup=copy(fx["merged"], d / "m"),
        inputs=(d / "m",),
    )
    d = w("merge_overwrite_replaces_the_output")
    add_cli(
        "merge_overwrite_replaces_the_output",
        "merge",
        [*merge, umi, "--output", d / "m", "--overwrite"],
        "accept",
        setup=copy(fx["merged"], d / "m"),
        check=frames_of(d / "m", 20, ["umi"]),
    )
    d = w("merge_overwrite_onto_a_folder_that_is_not_a_dataset")

    def notes(d=d):
        (d / "notes").mkdir(parents=True)
        (d / "notes" / "thesis.tex").write_text("months of work\n")

    add_cli(
        "merge_overwrite_onto_a_folder_that_is_not_a_dataset",
        "merge",
        [*merge, umi, "--output", d / "notes", "--overwrite"],
        words=["notes"],
        setup=notes,
        inputs=(d / "notes",),
    )
    add_cli(
        "merge_ok",
        "merge",
        [*merge, umi, inspire, "--output", w("merge_ok") / "m", "--galr", galr],
        "accept",
        check=frames_of(w("merge_ok") / "m", 40, ["umi", "inspire"]),
    )

    # --- policy latent-dataset ------------------------------------------------------------------------
    latent = ["policy", "latent-dataset", "--input"]
    add_cli(
        "latent_on_a_per_hand_dataset",
        "latent",
        [*latent, umi, "--output", w("l1") / "z", "--galr", galr],
        "accept",
        check=frames_of(w("l1") / "z", 20),
    )
    add_cli(
        "latent_on_a_merged_dataset_without_latents",
        "latent",
        [*latent, fx["merged"], "--output", w("l2") / "z", "--galr", galr],
        "accept",
        check=frames_of(w("l2") / "z", 40),
    )
    d = w("latent_output_is_its_input")
    add_cli(
        "latent_output_is_its_input",
        "latent",
        [*latent, d / "mg", "--output", d / "mg", "--overwrite"],
        words=["--output"],
        setup=copy(fx["merged_galr"], d / "mg"),
        inputs=(d / "mg",),
    )
    d = w("latent_output_inside_its_input")
    add_cli(
        "latent_output_inside_its_input",
        "latent",
        [*latent, d / "mg", "--output", d / "mg" / "z"],
        words=["--output"],
        setup=copy(fx["merged_galr"], d / "mg"),
        inputs=(d / "mg",),
    )
    d = w("latent_output_exists")
    add_cli(
        "latent_output_exists",
        "latent",
        [*latent, fx["merged_galr"], "--output", d / "z"],
        words=["exists", "--overwrite"],
        setup=copy(fx["latent"], d / "z"),
        inputs=(d / "z",),
    )
    add_cli(
        "latent_input_does_not_exist",
        "latent",
        [*latent, w("nowhere") / "merged_typo", "--output", w("l3") / "z"],
        words=["merged_typo", MISSING],
        absent=(w("l3") / "z",),
    )
    add_cli(
        "latent_ok",
        "latent",
        [*latent, fx["merged_galr"], "--output", w("latent_ok") / "z"],
        "accept",
        check=frames_of(w("latent_ok") / "z", 40),
    )

    # --- dataset synthetic --------------------------------------------------------------------------
    syn = ["dataset", "synthetic", "--hand"]
    add_cli(
        "synthetic_frames_0",
        "synthetic",
        [*syn, "umi", "--output", w("s1") / "s", "--frames", "0"],
        words=["--frames", "0"],
        absent=(w("s1") / "s",),
    )
    add_cli(
        "synthetic_unknown_hand",
        "synthetic",
        [*syn, "umii", "--output", w("s2") / "s"],
        words=["umii"],
        absent=(w("s2") / "s",),
    )
    d = w("synthetic_output_exists")
    add_cli(
        "synthetic_output_exists",
        "synthetic",
        [*syn, "umi", "--output", d / "s", "--frames", "3"],
        words=["exists"],
        setup=copy(umi, d / "s"),
        inputs=(d / "s",),
    )
    add_cli(
        "synthetic_n_points_not_a_number",
        "synthetic",
        [*syn, "umi", "--output", w("s3") / "s", "--n-points", "many"],
        words=["--n-points", "many"],
        absent=(w("s3") / "s",),
    )
    add_cli(
        "synthetic_episodes_negative",
        "synthetic",
        [*syn, "umi", "--output", w("s4") / "s", "--episodes", "-2"],
        words=["--episodes", "-2"],
        absent=(w("s4") / "s",),
    )
    add_cli(
        "synthetic_ok",
        "synthetic",
        [*syn, "inspire", "--output", w("s5") / "s", "--episodes", "1", "--frames", "3", "--n-points", "16"],
        "accept",
        check=frames_of(w("s5") / "s", 3),
    )

    # --- sim ------------------------------------------------------------------------------------------
    demos = ["sim", "demos", "--task"]
    add_cli(
        "sim_demos_unknown_task",
        "sim",
        [*demos, "press_buton", "--hand", "umi", "--episodes", "1", "--output-dir", w("d1") / "d"],
        words=["press_buton"],
        absent=(w("d1") / "d",),
    )
    add_cli(
        "sim_demos_unknown_region",
        "sim",
        [
            *demos,
            "lift",
            "--hand",
            "umi",
            "--episodes",
            "1",
            "--regions",
            "mid_centre",
            "--output-dir",
            w("d2") / "d",
        ],
        words=["mid_centre"],
        absent=(w("d2") / "d",),
    )
    add_cli(
        "sim_demos_unknown_hand",
        "sim",
        [*demos, "lift", "--hand", "lep", "--episodes", "1", "--output-dir", w("d3") / "d"],
        words=["lep"],
        absent=(w("d3") / "d",),
    )
    add_cli(
        "sim_demos_unknown_camera",
        "sim",
        [
            *demos,
            "lift",
            "--hand",
            "umi",
            "--episodes",
            "1",
            "--depth-cameras",
            "front,top",
            "--output-dir",
            w("d4") / "d",
        ],
        words=["top"],
        absent=(w("d4") / "d",),
    )
    add_cli(
        "sim_demos_episodes_0",
        "sim",
        [*demos, "lift", "--hand", "umi", "--episodes", "0", "--output-dir", w("d5") / "d"],
        words=["--episodes"],
        absent=(w("d5") / "d",),
    )
    d = w("sim_demos_output_exists")
    add_cli(
        "sim_demos_output_exists",
        "sim",
        [
            *demos,
            "press_button",
            "--hand",
            "umi",
            "--episodes",
            "1",
            "--n-points",
            "128",
            "--pointcloud-source",
            "geometry",
            "--output-dir",
            d / "d",
        ],
        words=["exists", "--overwrite"],
        setup=copy(fx["demos_umi"], d / "d"),
        inputs=(d / "d",),
    )
    d = w("sim_demos_sigint_while_writing")
    rec = [
        BIN / "lerobot-opfa",
        *demos,
        "press_button",
        "--hand",
        "umi",
        "--episodes",
        "40",  # about 6 s of writing on a 2-core machine: the signal, 1 s in, lands while it writes
        "--n-points",
        "128",
        "--pointcloud-source",
        "geometry",
        "--output-dir",
        d / "d",
    ]
    probes.append(
        Probe(
            "sim_demos_sigint_while_writing",
            "sim",
            show(rec[1:]) + "  # SIGINT once writing",
            "refuse",
            interrupted(rec, d, d / "d", signal.SIGINT),
            ("interrupted",),
            absent=(d / "d",),
        )
    )
    add_cli(
        "sim_show_unknown_task",
        "sim",
        ["sim", "show", "--task", "lfit", "--hand", "umi", "--out", w("d6") / "scene.png"],
        words=["lfit"],
        absent=(w("d6") / "scene.png",),
    )
    add_cli(
        "sim_regions_ok",
        "sim",
        ["sim", "regions"],
        "accept",
        check=lambda o: None if "mid_center" in o.out else "no region listed",
    )

    # --- hands: specs and models that are wrong (item 8 and more) -----------------------------------
    mesh_spec = fx["mesh_umi"] / "spec.yaml"
    add_cli(
        "hands_cloud_mesh_hand_ok",
        "hands",
        ["hands", "cloud", mesh_spec, "--n-points", "64", "--batch", "2", "--out", w("h0") / "c.npz"],
        "accept",
        check=file_exists(w("h0") / "c.npz"),
    )
    for name, content in (
        ("garbage", b"solid garbage nonsense 12 34\n"),
        ("truncated", None),
        ("empty", b""),
    ):
        d = w(f"hands_corrupt_stl_{name}")

        def corrupt(d=d, content=content):
            shutil.copytree(fx["mesh_umi"], d / "hand")
            stl = d / "hand" / "jaw.stl"
            stl.write_bytes(stl.read_bytes()[: len(stl.read_bytes()) // 2] if content is None else content)

        spec = d / "hand" / "spec.yaml"
        add_cli(
            f"hands_cloud_corrupt_stl_{name}",
            "hands",
            ["hands", "cloud", spec, "--out", d / "c.npz"],
            words=["jaw.stl"],
            setup=corrupt,
            absent=(d / "c.npz",),
        )
        probes.append(
            Probe(
                f"hands_check_corrupt_stl_{name}",
                "hands",
                show(["hands", "check", spec]),
                "refuse",
                cli(["hands", "check", spec]),
                ("jaw.stl",),
            )
        )
    d = w("hands_mesh_file_missing")
    add_cli(
        "hands_mesh_file_missing",
        "hands",
        ["hands", "cloud", d / "hand" / "spec.yaml", "--out", d / "c.npz"],
        words=["jaw.stl"],
        absent=(d / "c.npz",),
        setup=lambda d=d: (shutil.copytree(fx["mesh_umi"], d / "hand"), (d / "hand" / "jaw.stl").unlink()),
    )
    spec_cases = [
        ("unknown_hand", None, "umi_gripper", ["umi_gripper"]),
        (
            "spec_missing_joints",
            lambda t: re.sub(r"joints:\n  left_jaw_joint: gripper_aperture\n", "", t),
            None,
            ["joints"],
        ),
        (
            "spec_joints_wrong_type",
            lambda t: t.replace("left_jaw_joint: gripper_aperture", "left_jaw_joint: [1, 2]"),
            None,
            ["joints"],
        ),
        (
            "spec_joint_not_in_model",
            lambda t: (
                t.replace("left_jaw_joint: gripper_aperture", "jaw: gripper_aperture")
                .replace("source: left_jaw_joint", "source: jaw")
                .replace("{left_jaw_joint: ", "{jaw: ")
            ),
            None,
            ["jaw"],
        ),
        (
            "spec_unknown_universal_joint",
            lambda t: t.replace(": gripper_aperture", ": gripper_apperture"),
            None,
            ["gripper_apperture"],
        ),
        (
            "spec_link_not_in_model",
            lambda t: t.replace("right_jaw: [2, 0]", "right_jaw: [2, 0]\n  finger: [3, 0]"),
            None,
            ["finger"],
        ),
        (
            "spec_model_file_missing",
            lambda t: t.replace("model: umi.urdf", "model: umi_v2.urdf"),
            None,
            ["umi_v2.urdf"],
        ),
        ("spec_yaml_syntax_error", lambda t: t.replace("joints:\n", "joints: [\n"), None, ["spec.yaml"]),
        (
            "spec_pose_of_unknown_joint",
            lambda t: t.replace("open: {left_jaw_joint: 0.044}", "open: {jaw: 0.044}"),
            None,
            ["jaw"],
        ),
        (
            "spec_pose_beyond_limits",
            lambda t: t.replace("open: {left_jaw_joint: 0.044}", "open: {left_jaw_joint: 0.44}"),
            None,
            ["open"],
        ),
        ("spec_kind_unknown", lambda t: t.replace("kind: gripper", "kind: claw"), None, ["kind", "claw"]),
        (
            "spec_coupling_unknown_source",
            lambda t: t.replace("source: left_jaw_joint", "source: middle_jaw"),
            None,
            ["middle_jaw"],
        ),
    ]
    for name, edit, hand, words in spec_cases:
        d = w(f"hands_{name}")
        target = hand or d / "my_umi" / "spec.yaml"

        def make(d=d, edit=edit):
            copy_hand(
                REPO / "hand_models" / "umi",
                d / "my_umi",
                lambda t: edit(t.replace("name: umi", "name: my_umi")),
            )

        setup = None if edit is None else make
        add_cli(
            f"hands_cloud_{name}",
            "hands",
            ["hands", "cloud", target, "--n-points", "32", "--out", d / "c.npz"],
            words=words,
            setup=setup,
            absent=(d / "c.npz",),
        )
        if name in ("spec_joint_not_in_model", "spec_link_not_in_model", "spec_unknown_universal_joint"):
            probes.append(
                Probe(
                    f"hands_check_{name}",
                    "hands",
                    show(["hands", "check", target]),
                    "refuse",
                    cli(["hands", "check", target]),
                    tuple(words),
                )
            )
    d = w("hands_check_model_xml_truncated")
    add_cli(
        "hands_check_model_xml_truncated",
        "hands",
        ["hands", "check", d / "my_umi" / "spec.yaml"],
        words=["umi.urdf"],
        setup=lambda d=d: copy_hand(
            REPO / "hand_models" / "umi",
            d / "my_umi",
            lambda t: t.replace("name: umi", "name: my_umi"),
            lambda t: t[: len(t) // 2],
        ),
    )
    add_cli(
        "hands_cloud_n_points_0",
        "hands",
        ["hands", "cloud", "umi", "--n-points", "0", "--out", w("h1") / "c.npz"],
        words=["--n-points"],
        absent=(w("h1") / "c.npz",),
    )
    add_cli(
        "hands_cloud_out_in_a_new_folder",
        "hands",
        ["hands", "cloud", "inspire", "--n-points", "32", "--batch", "2", "--out", w("h2") / "new" / "c.npz"],
        "accept",
        check=file_exists(w("h2") / "new" / "c.npz"),
    )
    add_cli(
        "hands_show_unknown_pose",
        "hands",
        ["hands", "show", "umi", "--joints", "closed", "--out", w("h3") / "u.png"],
        words=["--joints", "closed"],
        absent=(w("h3") / "u.png",),
    )
    add_cli(
        "hands_show_unsupported_picture_format",
        "hands",
        ["hands", "show", "umi", "--n-points", "64", "--out", w("h4") / "u.pgn"],
        words=["pgn"],
        absent=(w("h4") / "u.pgn",),
    )
    add_cli(
        "hands_list_json_ok",
        "hands",
        ["hands", "list", "--json"],
        "accept",
        check=lambda o: None if len(json.loads(o.out)) >= 11 else "fewer than 11 hands",
    )

    # --- galr: embed / decode (item 5) ----------------------------------------------------------------
    q_open = load_pose("inspire")

    def npy(path: Path, array) -> Callable[[], None]:
        return lambda: (path.parent.mkdir(parents=True, exist_ok=True), np.save(path, array))

    embed = ["galr", "embed", "--checkpoint", galr, "--hand", "inspire", "--joints"]
    decode = ["galr", "decode", "--checkpoint", galr, "--hand", "inspire", "--latents"]
    q25 = q_open.repeat(3, 0)
    q25[1, 1] = 25.0
    qnan = q_open.repeat(3, 0)
    qnan[2, 3] = np.nan
    for name, array, words in (
        ("galr_embed_joint_at_25_rad", q25, ["inspire", "limits", "25"]),
        ("galr_embed_nan_joint", qnan, ["not finite", "q.npy"]),
        ("galr_embed_wrong_number_of_joints", q_open.repeat(3, 0)[:, :5], ["q.npy", "(3, 5)", "6"]),
    ):
        d = w(name)
        add_cli(
            name,
            "galr",
            [*embed, d / "q.npy", "--out", d / "z"],
            words=words,
            setup=npy(d / "q.npy", array),
            absent=(d / "z.npy",),
        )
    d = w("galr_embed_joints_not_a_npy")
    add_cli(
        "galr_embed_joints_not_a_npy",
        "galr",
        [*embed, d / "q.csv", "--out", d / "z"],
        words=["q.csv"],
        setup=lambda d=d: (
            d.mkdir(parents=True, exist_ok=True),
            (d / "q.csv").write_text("0.1,0.2,0.3,0.4,0.5,0.6\n"),
        ),
        absent=(d / "z.npy",),
    )
    add_cli(
        "galr_embed_joints_file_missing",
        "galr",
        [*embed, w("g1") / "joints.npy", "--out", w("g1") / "z"],
        words=["joints.npy", MISSING],
        absent=(w("g1") / "z.npy",),
    )
    d = w("galr_embed_hand_not_in_checkpoint")
    add_cli(
        "galr_embed_hand_not_in_checkpoint",
        "galr",
        ["galr", "embed", "--checkpoint", galr, "--hand", "leap", "--joints", d / "q.npy", "--out", d / "z"],
        words=["leap"],
        setup=npy(d / "q.npy", q_open),
        absent=(d / "z.npy",),
    )
    d = w("galr_embed_checkpoint_does_not_exist")
    add_cli(
        "galr_embed_checkpoint_does_not_exist",
        "galr",
        [
            "galr",
            "embed",
            "--checkpoint",
            d / "galr_typo",
            "--hand",
            "inspire",
            "--joints",
            d / "q.npy",
            "--out",
            d / "z",
        ],
        words=["galr_typo", MISSING],
        setup=npy(d / "q.npy", q_open),
        absent=(d / "z.npy",),
    )
    d = w("galr_embed_checkpoint_empty_folder")
    add_cli(
        "galr_embed_checkpoint_empty_folder",
        "galr",
        [
            "galr",
            "embed",
            "--checkpoint",
            fx["empty"],
            "--hand",
            "inspire",
            "--joints",
            d / "q.npy",
            "--out",
            d / "z",
        ],
        words=["empty", "config.json"],
        setup=npy(d / "q.npy", q_open),
        absent=(d / "z.npy",),
    )
    d = w("galr_embed_out_in_a_missing_folder")
    add_cli(
        "galr_embed_out_in_a_missing_folder",
        "galr",
        [*embed, d / "q.npy", "--out", d / "new" / "z"],
        "accept",
        setup=npy(d / "q.npy", q_open.repeat(2, 0)),
        either_words=["new"],
        check=lambda o, d=d: _shape_is(d / "new" / "z.npy", (2, 4)),
    )
    d = w("galr_embed_ok")
    add_cli(
        "galr_embed_ok",
        "galr",
        [*embed, d / "q.npy", "--out", d / "z"],
        "accept",
        setup=npy(d / "q.npy", q_open.repeat(3, 0)),
        check=lambda o, d=d: _shape_is(d / "z.npy", (3, 4)),
    )
    d = w("galr_decode_nan_latents")
    add_cli(
        "galr_decode_nan_latents",
        "galr",
        [*decode, d / "z.npy", "--out", d / "q"],
        words=["not finite"],
        setup=npy(d / "z.npy", np.full((2, 4), np.nan, np.float32)),
        absent=(d / "q.npy",),
    )
    d = w("galr_decode_wrong_latent_width")
    add_cli(
        "galr_decode_wrong_latent_width",
        "galr",
        [*decode, d / "z.npy", "--out", d / "q"],
        words=["z.npy", "(2, 8)", "4"],
        setup=npy(d / "z.npy", np.zeros((2, 8), np.float32)),
        absent=(d / "q.npy",),
    )
    d = w("galr_decode_ok")
    add_cli(
        "galr_decode_ok",
        "galr",
        [*decode, d / "z.npy", "--out", d / "q"],
        "accept",
        setup=npy(d / "z.npy", np.zeros((2, 4), np.float32)),
        check=lambda o, d=d: _shape_is(d / "q.npy", (2, 6)),
    )

    # --- galr: pretrain, eval, curves --------------------------------------------------------------
    pre = ["galr", "pretrain", "--output-dir"]
    tiny = ["--steps", "2", "--batch-size", "4", "--validate-every", "2", "--save-every", "2"]
    add_cli(
        "galr_pretrain_validate_every_0",
        "galr",
        [*pre, w("p1") / "run", "--validate-every", "0"],
        words=["--validate-every", "0"],
        absent=(w("p1") / "run",),
    )
    add_cli(
        "galr_pretrain_lr_not_a_number",
        "galr",
        [*pre, w("p2") / "run", "--lr", "fast"],
        words=["--lr", "fast"],
        absent=(w("p2") / "run",),
    )
    d = w("galr_pretrain_resume_with_other_hands")
    add_cli(
        "galr_pretrain_resume_with_other_hands",
        "galr",
        [*pre, d / "run", "--resume", "--hands", "umi,leap", *tiny],
        words=["--resume", "umi", "inspire"],
        setup=copy(galr, d / "run"),
        inputs=(d / "run",),
    )
    d = w("galr_pretrain_existing_run_without_resume")
    add_cli(
        "galr_pretrain_existing_run_without_resume",
        "galr",
        [*pre, d / "run", "--hands", "umi,inspire", *tiny, "--model", *TINY_GALR],
        words=["--resume", "run"],
        setup=copy(galr, d / "run"),
        inputs=(d / "run",),
    )
    add_cli(
        "galr_pretrain_resume_without_a_run",
        "galr",
        [*pre, w("p3") / "run", "--resume", *tiny],
        words=["--resume", "run"],
        absent=(w("p3") / "run",),
    )
    add_cli(
        "galr_pretrain_unknown_hand",
        "galr",
        [*pre, w("p4") / "run", "--hands", "umi,lep", *tiny, "--model", *TINY_GALR],
        words=["lep"],
        absent=(w("p4") / "run",),
    )
    add_cli(
        "galr_pretrain_model_unknown_key",
        "galr",
        [*pre, w("p5") / "run", *tiny, "--model", "latent=4"],
        words=["latent=4"],
        absent=(w("p5") / "run",),
    )
    add_cli(
        "galr_pretrain_model_value_not_a_number",
        "galr",
        [*pre, w("p6") / "run", *tiny, "--model", "latent_dim=four"],
        words=["latent_dim"],
        absent=(w("p6") / "run",),
    )
    add_cli(
        "galr_pretrain_model_unknown_encoder",
        "galr",
        [*pre, w("p7") / "run", "--hands", "umi", *tiny, "--model", *TINY_GALR, "encoder=pointnett"],
        words=["pointnett"],
        absent=(w("p7") / "run",),
    )
    add_cli(
        "galr_pretrain_plus_hands_without_init",
        "galr",
        [*pre, w("p8") / "run", "--hands", "+leap", *tiny],
        words=["--init"],
        absent=(w("p8") / "run",),
    )
    add_cli(
        "galr_pretrain_init_already_has_the_hands",
        "galr",
        [*pre, w("p9") / "run", "--init", galr, "--hands", "+inspire", *tiny],
        words=["inspire", "already"],
        absent=(w("p9") / "run",),
    )
    add_cli(
        "galr_pretrain_init_does_not_exist",
        "galr",
        [*pre, w("p10") / "run", "--init", "defualt", "--hands", "+leap", *tiny],
        words=["defualt", MISSING],
        absent=(w("p10") / "run",),
    )
    add_cli(
        "galr_pretrain_ok",
        "galr",
        [*pre, w("p11") / "run", "--hands", "umi", *tiny, "--model", *TINY_GALR],
        "accept",
        check=file_exists(w("p11") / "run" / "model.safetensors"),
    )
    ev = ["galr", "eval", "--checkpoint", galr, "--states", "4", "--json"]
    add_cli(
        "galr_eval_states_0",
        "galr",
        [*ev, w("e1") / "r.json", "--states", "0"],
        words=["--states", "0"],
        absent=(w("e1") / "r.json",),
    )
    add_cli(
        "galr_eval_unknown_hand",
        "galr",
        [*ev, w("e2") / "r.json", "--hands", "umi,lep"],
        words=["lep"],
        absent=(w("e2") / "r.json",),
    )
    add_cli(
        "galr_eval_json_in_a_missing_folder",
        "galr",
        [*ev, w("e3") / "new" / "r.json", "--hands", "umi"],
        "accept",
        either_words=["new"],
        check=file_exists(w("e3") / "new" / "r.json"),
    )
    add_cli(
        "galr_eval_ok", "galr", [*ev, w("e4") / "r.json"], "accept", check=file_exists(w("e4") / "r.json")
    )
    add_cli(
        "galr_curves_run_does_not_exist",
        "galr",
        ["galr", "curves", w("c1") / "run_typo", "--out", w("c1") / "c.png"],
        words=["run_typo", MISSING],
        absent=(w("c1") / "c.png",),
    )
    add_cli(
        "galr_curves_folder_without_metrics",
        "galr",
        ["galr", "curves", fx["empty"], "--out", w("c2") / "c.png"],
        words=["metrics.jsonl"],
        absent=(w("c2") / "c.png",),
    )
    d = w("galr_curves_run_without_validation_rows")

    def unvalidated(d=d):
        d.mkdir(parents=True, exist_ok=True)
        rows = [json.loads(r) for r in (galr / "metrics.jsonl").read_text().splitlines()]
        (d / "metrics.jsonl").write_text(
            "".join(json.dumps(r) + "\n" for r in rows if "val/rmse_deg_mean" not in r)
        )

    add_cli(
        "galr_curves_run_without_validation_rows",
        "galr",
        ["galr", "curves", d, "--out", d / "c.png"],
        words=["metrics.jsonl"],
        setup=unvalidated,
        absent=(d / "c.png",),
    )
    add_cli(
        "galr_curves_ok",
        "galr",
        ["galr", "curves", f"tiny={galr}", "--out", w("c3") / "c.png"],
        "accept",
        check=file_exists(w("c3") / "c.png"),
    )
    add_cli(
        "galr_list_ok",
        "galr",
        ["galr", "list"],
        "accept",
        check=lambda o: None if "default" in o.out and "long" in o.out else "packaged checkpoints missing",
    )

    # --- train: lerobot-train and lerobot-opfa train (items 7 and more) ------------------------------
    def flags(root: Path, out: Path, **changed: str) -> list[str]:
        values = {
            **TINY_POLICY,
            "--dataset.repo_id": f"local/{root.name}",
            "--dataset.root": str(root),
            "--output_dir": str(out),
            **{f"--{k}": v for k, v in changed.items()},
            **({"--policy.down_dims": None} if "policy.horizon" in changed else {}),
        }
        return [f"{k}={v}" for k, v in values.items() if v is not None]

    train_ok = [BIN / "lerobot-train", *flags(fx["merged256"], fx["train"])]
    add_proc(
        "lerobot_train_tiny_ok",
        "train",
        train_ok,
        "accept",
        timeout=600,
        check=lambda o: None if (fx["checkpoint"] / "config.json").is_file() else "no checkpoint written",
    )
    for name, change, words in (
        ("horizon_10", {"policy.horizon": "10"}, ["horizon", "10"]),
        ("n_action_steps_40", {"policy.n_action_steps": "40"}, ["n_action_steps", "40"]),
        ("action_space_latent", {"policy.action_space": "latent"}, ["action_space", "latent"]),
    ):
        out = w(f"train_{name}") / "out"
        add_cli(
            f"train_{name}",
            "train",
            ["train", *flags(fx["merged256"], out, **change)],
            words=words,
            absent=(out,),
        )
    out = w("lerobot_train_horizon_10") / "out"
    add_proc(
        "lerobot_train_horizon_10",
        "train",
        [BIN / "lerobot-train", *flags(fx["merged256"], out, **{"policy.horizon": "10"})],
        words=["horizon", "10"],
        absent=(out,),
    )
    d = w("train_hand_whose_episodes_are_1_frame")
    add_cli(
        "train_hand_whose_episodes_are_1_frame",
        "train",
        ["train", *flags(d / "m", d / "out", **{"policy.action_space": "per_embodiment"})],
        words=["inspire", "frame"],
        absent=(d / "out",),
        setup=lambda d=d: must([*merge, umi, fx["inspire_1frame"], "--output", d / "m"]),
    )
    d = w("train_corrupt_info_json")
    add_cli(
        "train_corrupt_info_json",
        "train",
        ["train", *flags(d / "m", d / "out")],
        words=["info.json"],
        inputs=(d / "m",),
        absent=(d / "out",),
        setup=lambda d=d: (
            copy(fx["merged256"], d / "m")(),
            (d / "m/meta/info.json").write_text((fx["merged256"] / "meta/info.json").read_text()[:300]),
        ),
    )
    out = w("train_dataset_root_does_not_exist") / "out"
    add_cli(
        "train_dataset_root_does_not_exist",
        "train",
        ["train", *flags(w("nowhere") / "merged_typo", out)],
        words=["merged_typo", MISSING],
        absent=(out,),
    )
    out = w("train_dataset_root_not_a_dataset") / "out"
    add_cli(
        "train_dataset_root_not_a_dataset",
        "train",
        ["train", *flags(fx["empty"], out)],
        words=["not a LeRobotDataset"],
        absent=(out,),
    )
    out = w("train_galr_path_does_not_exist") / "out"
    add_cli(
        "train_galr_path_does_not_exist",
        "train",
        ["train", *flags(fx["merged256"], out, **{"policy.galr_path": "galr_typo"})],
        words=["galr_typo", MISSING],
        absent=(out,),
    )
    d = w("train_per_hand_dataset_joint_at_50_rad")
    add_cli(
        "train_per_hand_dataset_joint_at_50_rad",
        "train",
        ["train", *flags(d / "inspire", d / "out", **{"policy.action_space": "raw"})],
        words=["index_mcp_flex"],
        inputs=(d / "inspire",),
        absent=(d / "out",),
        setup=lambda d=d: (
            copy(fx["inspire256"], d / "inspire")(),
            set_state(d / "inspire", 8, 50.0, slice(2, 5)),
        ),
    )
    add_cli(
        "train_output_dir_exists", "train", ["train", *flags(fx["merged256"], fx["train"])], words=["exists"]
    )
    out = w("lerobot_train_dataset_without_point_clouds") / "out"
    add_proc(
        "lerobot_train_dataset_without_point_clouds",
        "train",
        [BIN / "lerobot-train", *flags(fx["umi_nocloud"], out, **{"policy.action_space": "raw"})],
        words=["observation.pointcloud"],
        absent=(out,),
    )

    # --- policy: the Python API with bad observations (item 3) --------------------------------------
    holder: dict[str, Any] = {}

    def act(
        state: torch.Tensor | None = None, cloud: torch.Tensor | None = None, hand: str = "umi"
    ) -> torch.Tensor:
        if "policy" not in holder:
            from lerobot.policies.factory import make_pre_post_processors

            import lerobot_policy_opfa  # noqa: F401  (the plugin, as LeRobot loads it: steps, robot_type)
            from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

            policy = OpfaPolicy.from_pretrained(fx["checkpoint"]).eval()
            holder["policy"] = policy
            holder["pre"], holder["post"] = make_pre_post_processors(
                policy.config, pretrained_path=str(fx["checkpoint"])
            )
        policy, pre, post = holder["policy"], holder["pre"], holder["post"]
        observation = {
            "observation.state": torch.tensor([0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.02])
            if state is None
            else state,
            "observation.pointcloud": torch.randn(256 * 3) * 0.03 if cloud is None else cloud,
            "observation.environment_state": torch.tensor([0.05, -0.02, 0.04]),
            "task": "lift the object",
            "robot_type": hand,  # the robot of the frames: the checkpoint drives umi and inspire
        }
        policy.reset()
        with torch.no_grad():
            return post(policy.select_action(pre(observation)))

    def finite_action(width: int) -> Callable[[Outcome], str | None]:
        def check(o: Outcome) -> str | None:
            a = o.value
            if tuple(a.shape) != (1, width):
                return f"action of shape {tuple(a.shape)}, expected (1, {width})"
            return None if bool(torch.isfinite(a).all()) else "action not finite"

        return check

    flow = "policy preprocessor -> select_action -> postprocessor"
    add_api(
        "policy_ok_umi",
        "policy",
        f"{flow} (umi state, 256-point cloud)",
        lambda: act(),
        "accept",
        check=finite_action(7),
    )
    add_api(
        "policy_ok_inspire",
        "policy",
        f"{flow} (inspire state, 256-point cloud)",
        lambda: act(
            state=torch.cat([torch.tensor([0.0, 0.0, 0.3, 0, 0, 0]), torch.tensor(q_open[0])]), hand="inspire"
        ),
        "accept",
        check=finite_action(12),
    )
    add_api(
        "policy_cloud_all_nan",
        "policy",
        f"{flow}, observation.pointcloud all NaN",
        lambda: act(cloud=torch.full((256 * 3,), float("nan"))),
        words=["observation.pointcloud", "not finite"],
    )
    add_api(
        "policy_cloud_one_inf_point",
        "policy",
        f"{flow}, observation.pointcloud with one inf",
        lambda: act(cloud=torch.zeros(256 * 3).index_fill(0, torch.tensor([30]), float("inf"))),
        words=["observation.pointcloud", "point 10"],
    )
    add_api(
        "policy_cloud_of_100_points",
        "policy",
        f"{flow}, a cloud of 100 points (trained on 256)",
        lambda: act(cloud=torch.zeros(100 * 3)),
        words=["100", "256"],
    )
    add_api(
        "policy_cloud_of_1024_points",
        "policy",
        f"{flow}, a cloud of 1024 points (trained on 256)",
        lambda: act(cloud=torch.zeros(1024 * 3)),
        words=["1024", "256"],
    )
    add_api(
        "policy_cloud_not_flattened",
        "policy",
        f"{flow}, a (256, 3) cloud instead of (768,)",
        lambda: act(cloud=torch.zeros(256, 3)),
        words=["observation.pointcloud", "shape"],
    )
    add_api(
        "policy_state_nan",
        "policy",
        f"{flow}, observation.state with NaN in the jaw",
        lambda: act(state=torch.tensor([0.0, 0.0, 0.3, 0.0, 0.0, 0.0, float("nan")])),
        words=["observation.state"],
    )
    add_api(
        "policy_state_width_of_no_hand",
        "policy",
        f"{flow}, observation.state of 9 entries",
        lambda: act(state=torch.zeros(9)),
        words=["9"],
    )
    add_api(
        "policy_state_of_a_hand_it_was_not_trained_on",
        "policy",
        f"{flow}, a leap state (22 entries)",
        lambda: act(state=torch.zeros(22)),
        words=["22"],
    )
    add_api(
        "policy_state_joint_beyond_its_limits",
        "policy",
        f"{flow}, umi jaw at 0.5 m (limits 0..0.044)",
        lambda: act(state=torch.tensor([0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.5])),
        words=["left_jaw_joint"],
    )

    # In a fresh process: a postprocessor reads its hand from any live preprocessor of the same checkpoint,
    # and the probes above have run one in this process.
    post_first = python_in_subprocess(
        "import torch\n"
        "from lerobot.policies.factory import make_pre_post_processors\n"
        "from lerobot_opfa.policy.modeling_opfa import OpfaPolicy\n"
        f"policy = OpfaPolicy.from_pretrained({str(fx['checkpoint'])!r})\n"
        f"_, post = make_pre_post_processors(policy.config, pretrained_path={str(fx['checkpoint'])!r})\n"
        "action = post(torch.zeros(1, policy.config.action_width))\n",
        w("policy_postprocessor_before_preprocessor"),
    )

    add_api(
        "policy_postprocessor_before_preprocessor",
        "policy",
        "postprocessor(action) of a fresh pipeline",
        post_first,
        words=["preprocessor"],
    )
    d = w("policy_convert_io_not_a_checkpoint")
    add_cli(
        "policy_convert_io_not_a_checkpoint",
        "policy",
        ["policy", "convert-io", "--policy", fx["empty"], "--output", d / "out"],
        words=["empty"],
        absent=(d / "out",),
    )
    add_cli(
        "policy_convert_io_on_a_dataset",
        "policy",
        ["policy", "convert-io", "--policy", umi, "--output", w("v1") / "out"],
        words=["umi"],
        absent=(w("v1") / "out",),
    )
    add_cli(
        "policy_convert_io_checkpoint_does_not_exist",
        "policy",
        [
            "policy",
            "convert-io",
            "--policy",
            w("nowhere") / "ckpt_typo",
            "--output",
            w("v2") / "out",
        ],
        words=["ckpt_typo", MISSING],
        absent=(w("v2") / "out",),
    )
    add_cli(
        "policy_convert_io_on_an_opfa_checkpoint",
        "policy",
        ["policy", "convert-io", "--policy", fx["checkpoint"], "--output", w("v3") / "out"],
        words=["opfa"],
        absent=(w("v3") / "out",),
    )

    # --- eval: lerobot-eval with an env that does not fit the policy --------------------------------
    def evaluate(name: str, expected: str = "refuse", words=(), **env: str):
        values = {
            "task": "press_button",
            "hand": "umi",
            "n_points": "256",
            "pointcloud_source": "geometry",
            "episode_length": "4",
            "obs_type": "pointcloud_state",
            **env,
        }
        out = w(name) / "out"
        cmd = [
            BIN / "lerobot-eval",
            f"--policy.path={fx['checkpoint']}",
            "--policy.device=cpu",
            "--env.type=opfa",
            *[f"--env.{k}={v}" for k, v in values.items()],
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            f"--output_dir={out}",
        ]
        check = None
        if expected == "accept":

            def check(o: Outcome, out=out) -> str | None:
                info = json.loads((out / "eval_info.json").read_text())
                return None if info["overall"]["n_episodes"] == 1 else "not one episode"

        add_proc(name, "eval", cmd, expected, words, check=check)

    evaluate("lerobot_eval_ok", "accept")
    evaluate("lerobot_eval_hand_the_policy_was_not_trained_on", words=["leap"], hand="leap")
    evaluate("lerobot_eval_env_clouds_of_other_size", words=["64", "256"], n_points="64")
    evaluate("lerobot_eval_unknown_task", words=["press_buton"], task="press_buton")
    evaluate("lerobot_eval_env_without_point_clouds", words=["observation.pointcloud"], obs_type="state")
    evaluate("lerobot_eval_ee_delta_for_a_joints_policy", words=["env.control", "joints"], control="ee_delta")

    # --- experiment / demo ------------------------------------------------------------------------------
    exp = ["experiment", "nine", "--scale", "toy", "--failure-episodes", "0", "--output-dir"]
    add_cli(
        "experiment_epochs_negative",
        "experiment",
        ["experiment", "spatial", "--epochs", "-1", "--output-dir", w("x1") / "x"],
        words=["--epochs"],
        absent=(w("x1") / "x",),
    )
    add_cli(
        "experiment_unknown_condition",
        "experiment",
        [*exp, w("x2") / "x", "--conditions", "opfa,naive"],
        words=["naive"],
        absent=(w("x2") / "x",),
    )
    add_cli(
        "experiment_unknown_region",
        "experiment",
        ["experiment", "object", "--regions", "mid_centre", "--output-dir", w("x3") / "x"],
        words=["mid_centre"],
        absent=(w("x3") / "x",),
    )
    add_cli(
        "experiment_workers_0",
        "experiment",
        [*exp, w("x4") / "x", "--workers", "0"],
        words=["--workers"],
        absent=(w("x4") / "x",),
    )
    add_cli(
        "experiment_unknown_galr",
        "experiment",
        [*exp, w("x5") / "x", "--galr", "lnog"],
        words=["lnog"],
        absent=(w("x5") / "x",),
    )
    d = w("experiment_output_dir_holding_other_files")

    def other_files(d=d):
        (d / "x").mkdir(parents=True)
        (d / "x" / "results.csv").write_text("mine\n")

    add_cli(
        "experiment_output_dir_holding_other_files",
        "experiment",
        [*exp, d / "x"],
        words=["x"],
        setup=other_files,
        inputs=(d / "x",),
    )
    add_proc(
        "experiment_unknown_second_hand",
        "experiment",
        [
            BIN / "lerobot-opfa",
            *exp,
            w("experiment_unknown_second_hand") / "x",
            "--hands",
            "umi,lep",
            "--demos-per-hand",
            "1",
            "--conditions",
            "opfa",
        ],
        words=["lep"],
        timeout=150,
    )
    add_cli(
        "demo_states_0",
        "demo",
        ["demo", "--states", "0", "--output-dir", w("y1") / "o"],
        words=["--states"],
        absent=(w("y1") / "o",),
    )
    add_cli(
        "demo_unknown_galr",
        "demo",
        ["demo", "--galr", "lnog", "--output-dir", w("y2") / "o"],
        words=["lnog"],
        absent=(w("y2") / "o",),
    )
    add_proc(
        "demo_unknown_hand",
        "demo",
        [
            BIN / "lerobot-opfa",
            "demo",
            "--hands",
            "umi,lep",
            "--states",
            "4",
            "--n-points",
            "64",
            "--output-dir",
            w("demo_unknown_hand") / "o",
        ],
        words=["lep"],
        timeout=150,
    )

    # --- flags and noise ------------------------------------------------------------------------------
    add_cli("flags_unknown_subcommand", "flags", ["hand", "list"], words=["hand"])
    add_cli("flags_unknown_option", "flags", ["hands", "list", "--jsn"], words=["--jsn"])
    add_cli("flags_missing_required_option", "flags", [*merge, umi], words=["--output"])
    add_cli(
        "flags_galr_pretrain_unknown_shares",
        "flags",
        [*pre, w("f1") / "run", "--shares", "equal"],
        words=["--shares", "equal"],
        absent=(w("f1") / "run",),
    )
    add_cli(
        "flags_max_minutes_0",
        "flags",
        [*pre, w("f2") / "run", "--max-minutes", "0"],
        words=["--max-minutes"],
        absent=(w("f2") / "run",),
    )
    add_cli(
        "flags_experiment_unknown_scale",
        "flags",
        [*exp, w("f3") / "x", "--scale", "huge"],
        words=["--scale", "huge"],
        absent=(w("f3") / "x",),
    )
    add_proc(
        "noise_unknown_hand_subprocess",
        "flags",
        [BIN / "lerobot-opfa", "hands", "cloud", "umii", "--out", "c.npz"],
        words=["umii"],
        count_lines=True,
    )
    add_proc(
        "noise_missing_input_subprocess",
        "flags",
        [BIN / "lerobot-opfa", *merge, "umi_typo", "--output", "m"],
        words=["umi_typo", MISSING],
        count_lines=True,
    )
    add_proc(
        "noise_train_config_error_subprocess",
        "flags",
        [
            BIN / "lerobot-opfa",
            "train",
            "--policy.type=opfa",
            "--policy.horizon=10",
            "--dataset.repo_id=local/none",
        ],
        words=["horizon"],
        count_lines=True,
    )
    add_proc(
        "noise_galr_embed_out_of_limits_subprocess",
        "flags",
        [BIN / "lerobot-opfa", *embed, w("galr_embed_joint_at_25_rad") / "q.npy", "--out", "z"],
        words=["limits"],
        count_lines=True,
    )
    return probes


def load_pose(hand: str):
    from lerobot_opfa.hands import load_hand

    return load_hand(hand).pose("open").numpy()[None].astype("float32")


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _shape_is(path: Path, shape: tuple[int, ...]) -> str | None:
    import numpy as np

    if not path.is_file():
        return f"{path.name} was not written"
    array = np.load(path)
    if array.shape != shape:
        return f"{path.name} has shape {array.shape}, expected {shape}"
    return None if np.isfinite(array).all() else f"{path.name} is not finite"


# --- main ------------------------------------------------------------------------------------------
def git_commit() -> str:
    result = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True)
    return result.stdout.strip() or "unknown"


def uncommitted() -> list[str]:
    """Files of the package that differ from the commit (the probes ran on the working tree)."""
    result = subprocess.run(
        ["git", "status", "--porcelain", "--", "src", "hand_models"], cwd=REPO, capture_output=True, text=True
    )
    return [line[3:] for line in result.stdout.splitlines()]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", help="comma-separated substrings: run only the probes whose names hold one")
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder (its path is printed)")
    parser.add_argument("--tmp", type=Path, help="where to make the temporary folder (default: the system's)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()

    import torch

    torch.set_num_threads(1)
    _reset_logging()
    start = time.monotonic()
    root = Path(tempfile.mkdtemp(prefix="opfa_probes_", dir=args.tmp))
    fixtures, work = root / "fixtures", root / "work"
    print(f"fixtures and probe folders under {root}", flush=True)
    fx = build_fixtures(fixtures)
    _reset_logging()
    print(f"fixtures built in {time.monotonic() - start:.0f} s", flush=True)
    probes = define_probes(fx, work)
    names = [p.name for p in probes]
    assert len(names) == len(set(names)), sorted({n for n in names if names.count(n) > 1})
    if args.only:
        wanted = args.only.split(",")
        chosen = [p for p in probes if any(k in p.name for k in wanted)]
        needs_policy = any(k in p.name for p in chosen for k in ("policy", "eval", "train_output"))
        probes = [p for p in probes if p in chosen or (needs_policy and p.name == "lerobot_train_tiny_ok")]
    rows = []
    for i, probe in enumerate(probes, 1):
        t0 = time.monotonic()
        (work / probe.name).mkdir(parents=True, exist_ok=True)
        if probe.setup:
            probe.setup()
        watched = [fixtures, *probe.inputs]
        before = snapshot(watched)
        outcome = probe.run()
        _reset_logging()
        after = snapshot(watched)
        left = leftovers([work, fixtures])
        verdict, message = classify(probe, outcome, before, after, left)
        for path in left:  # one probe's leftovers are not the next one's
            shutil.rmtree(path, ignore_errors=True)
        rows.append(
            {
                "name": probe.name,
                "kind": probe.kind,
                "command": probe.command,
                "expected": probe.expected,
                "verdict": verdict,
                "message": message.replace(str(root), "$TMP")[:300],
                "seconds": round(time.monotonic() - t0, 1),
            }
        )
        print(f"[{i:3d}/{len(probes)}] {verdict:<20} {probe.name} ({rows[-1]['seconds']:.1f} s)", flush=True)
    counts = {v: sum(r["verdict"] == v for r in rows) for v in VERDICTS}
    wall = round(time.monotonic() - start, 1)
    report = {
        "commit": git_commit(),
        "uncommitted": uncommitted(),
        "counts": counts,
        "probes": rows,
        "wall_seconds": wall,
        "python": sys.version.split()[0],
        "cpu_count": os.cpu_count(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")

    width = max(len(r["name"]) for r in rows)
    print(f"\n{'probe':<{width}}  {'kind':<10} {'expected':<8} verdict")
    for r in rows:
        print(f"{r['name']:<{width}}  {r['kind']:<10} {r['expected']:<8} {r['verdict']}")
    print("\n" + ", ".join(f"{v}: {n}" for v, n in counts.items()) + f"  ({len(rows)} probes, {wall:.0f} s)")
    for r in rows:
        if r["verdict"] not in ("clear error", "handled correctly"):
            print(f"\n{r['verdict']}: {r['name']}\n  {r['command']}\n  -> {r['message']}")
    print(f"\nwrote {args.out}")
    if args.keep:
        print(f"kept {root}")
    else:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
