"""Nothing lost, nothing half-written, nothing silent: a user's mistakes and interrupted writes, each as a
user makes them, give one clear line and leave their data and folders as they were."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from subprocesses import run_command

from lerobot_opfa import cli
from lerobot_opfa.datasets import merge as merge_module
from lerobot_opfa.datasets.io import atomic_directory, read_columns
from lerobot_opfa.datasets.synthetic import WRIST_NAMES, write_synthetic_dataset
from lerobot_opfa.galr import commands as galr_commands
from lerobot_opfa.galr.train import PretrainConfig, pretrain
from lerobot_opfa.hands import HandModel, HandSpecError, load_hand
from lerobot_opfa.hands.registry import hand_models_dir, load_spec

ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
TINY_GALR = ["latent_dim=4", "encoder=pointnet", "n_points=32", "n_level1=16", "n_superpoints=14",
             "widths=8,16,16", "decoder_hidden=16"]  # fmt: skip


@pytest.fixture(scope="module")
def datasets(tmp_path_factory) -> Path:
    """Small synthetic per-hand datasets (umi at 16 and 8 points, inspire), written once."""
    root = tmp_path_factory.mktemp("guards")
    write_synthetic_dataset(root / "umi", "umi", episodes=2, frames=6, n_points=16, seed=0)
    write_synthetic_dataset(root / "umi8", "umi", episodes=2, frames=6, n_points=8, seed=1)
    write_synthetic_dataset(root / "inspire", "inspire", episodes=2, frames=6, n_points=16, seed=2)
    return root


def _copy(source: Path, target: Path) -> Path:
    shutil.copytree(source, target)
    return target


def _error(capsys, argv: list[str]) -> str:
    """The error line a failing command ends with (it must fail with code 2, without a traceback)."""
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines()[-1].startswith("error: ") and "Traceback" not in err, err
    return err.splitlines()[-1]


def _set_state(root: Path, entry: int, value: float, rows: slice) -> None:
    """Writes `value` into state entry `entry` of the frames `rows` (of the first data file)."""
    path = next((root / "data").rglob("*.parquet"))
    table = pq.read_table(path)
    column = table.column("observation.state").combine_chunks()
    state = column.flatten().to_numpy().reshape(len(column), -1).copy()
    state[rows, entry] = value
    array = pa.FixedSizeListArray.from_arrays(pa.array(state.reshape(-1), pa.float32()), state.shape[1])
    array = array.cast(column.type)
    index = table.schema.get_field_index("observation.state")
    pq.write_table(table.set_column(index, "observation.state", array), path)


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".partial-" in p.name or ".old-" in p.name)


# --- 1. a merge never destroys an input -----------------------------------------------------------
@pytest.mark.parametrize("output", ["umi", "umi/merged", "."])
def test_merge_refuses_to_write_over_or_around_an_input(datasets, tmp_path, capsys, output):
    inputs = [_copy(datasets / h, tmp_path / h) for h in ("umi", "inspire")]
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    argv = ["dataset", "merge", "--inputs", *map(str, inputs), "--output", str(tmp_path / output)]
    assert "would write over the input" in _error(capsys, [*argv, "--overwrite"])
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_merge_refuses_an_input_named_twice(datasets, tmp_path, capsys):
    umi = str(datasets / "umi")
    err = _error(capsys, ["dataset", "merge", "--inputs", umi, umi + "/", "--output", str(tmp_path / "m")])
    assert "more than once" in err and not (tmp_path / "m").exists()


# --- 2. interrupted writes leave nothing behind ---------------------------------------------------
@pytest.mark.parametrize("episodes_saved", [1, 3, 4])
def test_a_merge_interrupted_at_any_point_leaves_nothing_and_a_rerun_succeeds(
    datasets, tmp_path, monkeypatch, episodes_saved
):
    """Interrupted after 1 or 3 of its 4 episodes (their metadata buffered, not yet on disk), or after all
    of them, while it writes the statistics."""
    inputs = [datasets / "umi", datasets / "inspire"]
    saved = []
    save_episode = LeRobotDataset.save_episode

    def save_then_interrupt(self, *args, **kwargs):
        if len(saved) == episodes_saved:
            raise KeyboardInterrupt
        saved.append(save_episode(self, *args, **kwargs))

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(LeRobotDataset, "save_episode", save_then_interrupt)
        patch.setattr(merge_module, "write_statistics", interrupt)
        with pytest.raises(KeyboardInterrupt):
            merge_module.merge_datasets(inputs, tmp_path / "m")
    assert list(tmp_path.iterdir()) == []
    merge_module.merge_datasets(inputs, tmp_path / "m")
    assert read_columns(tmp_path / "m", ["index"])["index"].size == 24 and _leftovers(tmp_path) == []


def _interruptible() -> None:
    """A child that Ctrl-C reaches even when pytest runs in the background (where a shell starts it with
    SIGINT ignored, which its children inherit and Python then leaves alone)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_sigint_during_a_merge_leaves_nothing_and_a_rerun_succeeds(datasets, tmp_path):
    inputs = [str(datasets / h) for h in ("umi", "inspire")]
    command = [sys.executable, "-m", "lerobot_opfa.cli", "dataset", "merge", "--inputs", *inputs, "--output"]
    slow = tmp_path / "slow.py"  # the merge, with each episode taking a while, so that SIGINT lands in it
    slow.write_text(
        "import sys, time\nfrom lerobot.datasets.lerobot_dataset import LeRobotDataset\n"
        "save = LeRobotDataset.save_episode\n"
        "def slow_save(self, *a, **k):\n    print('episode', flush=True)\n    time.sleep(0.5)\n"
        "    return save(self, *a, **k)\n"
        "LeRobotDataset.save_episode = slow_save\nfrom lerobot_opfa import cli\nsys.exit(cli.main())\n"
    )
    process = subprocess.Popen(
        [sys.executable, str(slow), *command[3:], str(tmp_path / "m")],
        env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_interruptible,
    )  # fmt: skip
    assert process.stdout.readline().strip() == "episode"  # inside the merge, its first episode written
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130 and err.strip().endswith("interrupted"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["slow.py"]
    done = run_command([*command, str(tmp_path / "m")], timeout=300, env=ENV)
    assert done.returncode == 0, done.stderr
    assert _leftovers(tmp_path) == []


def test_a_rerun_cleans_what_a_killed_or_older_writer_left_and_puts_back_a_moved_output(tmp_path):
    dead = run_command([sys.executable, "-c", "import os; print(os.getpid())"], timeout=60)
    pid = int(dead.stdout)
    for name in (".out.partial-1a2b3c4d", f".out.partial-{pid}-1a2b3c4d"):  # an older version's, a dead pid
        (tmp_path / name / "meta").mkdir(parents=True)
    (tmp_path / f".kept.old-{pid}-0f0f0f0f" / "meta").mkdir(parents=True)  # killed mid-replacement
    with atomic_directory(tmp_path / "out") as partial:
        partial.mkdir()
    with atomic_directory(tmp_path / "other") as partial:
        partial.mkdir()
    assert _leftovers(tmp_path) == [f".kept.old-{pid}-0f0f0f0f"]
    with pytest.raises(FileExistsError):
        atomic_directory(tmp_path / "kept").__enter__()
    assert (tmp_path / "kept" / "meta").is_dir() and _leftovers(tmp_path) == []


def test_synthetic_with_no_frames_is_one_line_and_leaves_nothing(tmp_path, capsys):
    argv = ["dataset", "synthetic", "--hand", "umi", "--output", str(tmp_path / "s")]
    with pytest.raises(SystemExit) as exit_info:
        cli.main([*argv, "--frames", "0"])
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and "--frames: must be a positive integer, got 0" in err
    assert len(err.splitlines()) == 1 and list(tmp_path.iterdir()) == []
    assert cli.main([*argv, "--frames", "3", "--episodes", "1", "--n-points", "4"]) == 0


# --- 4. inputs that disagree on a feature ---------------------------------------------------------
def test_merge_of_clouds_of_different_sizes_names_inputs_and_shapes(datasets, tmp_path, capsys):
    inputs = [str(datasets / "umi"), str(datasets / "umi8")]
    err = _error(capsys, ["dataset", "merge", "--inputs", *inputs, "--output", str(tmp_path / "m")])
    assert "feature 'observation.pointcloud'" in err and "(48,)" in err and "(24,)" in err
    assert str(datasets / "umi8") in err and not (tmp_path / "m").exists()


# --- 5. joints beyond their limits, NaN ------------------------------------------------------------
def test_merge_refuses_joints_beyond_their_limits_naming_hand_joint_frames_and_worst(
    datasets, tmp_path, capsys
):
    bad = _copy(datasets / "inspire", tmp_path / "inspire")
    joint = load_hand("inspire").joint_names.index("index_mcp_flex")
    _set_state(bad, len(WRIST_NAMES) + joint, 50.0, slice(2, 5))
    err = _error(capsys, ["dataset", "merge", "--inputs", str(bad), "--output", str(tmp_path / "m")])
    assert "joint 'index_mcp_flex' of hand 'inspire' is outside its limits" in err
    assert "in 3 of 12 frames (worst 50)" in err and not (tmp_path / "m").exists()
    _set_state(bad, len(WRIST_NAMES) + joint, float("nan"), slice(0, 1))
    err = _error(capsys, ["dataset", "merge", "--inputs", str(bad), "--output", str(tmp_path / "m")])
    assert "not finite (NaN or inf) in 1 of 12 frames, first in joint 'index_mcp_flex'" in err


@pytest.fixture(scope="module")
def tiny_galr(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("galr") / "run"
    config = galr_commands.parse_overrides(TINY_GALR)
    pretrain(PretrainConfig(output_dir=out, hands=["umi", "inspire"], steps=2, batch_size=4, validate_every=2,
                            save_every=2, validation_states=2, warmup_steps=1, model=config))  # fmt: skip
    return out


def test_galr_embed_refuses_joints_beyond_limits_and_nan_and_decode_refuses_nan(tiny_galr, tmp_path, capsys):
    q = load_hand("inspire").pose("open").numpy()[None].repeat(3, 0)
    q[1, 1] = 25.0
    np.save(tmp_path / "q.npy", q)
    embed = [
        "galr",
        "embed",
        "--checkpoint",
        str(tiny_galr),
        "--hand",
        "inspire",
        "--out",
        str(tmp_path / "z"),
    ]
    err = _error(capsys, [*embed, "--joints", str(tmp_path / "q.npy")])
    assert "of hand 'inspire' is outside its limits" in err and "in 1 of 3 frames (worst 25)" in err
    q[1, 1] = np.nan
    np.save(tmp_path / "q.npy", q)
    assert "not finite" in _error(capsys, [*embed, "--joints", str(tmp_path / "q.npy")])
    np.save(tmp_path / "z.npy", np.full((2, 4), np.nan, np.float32))
    decode = [
        "galr",
        "decode",
        "--checkpoint",
        str(tiny_galr),
        "--hand",
        "inspire",
        "--out",
        str(tmp_path / "q"),
    ]
    assert "2 of 2 latents are not finite" in _error(capsys, [*decode, "--latents", str(tmp_path / "z.npy")])


# --- 6. a user hand that takes a built-in's name ---------------------------------------------------
def test_a_spec_named_like_a_builtin_but_different_must_be_renamed(tmp_path, capsys):
    wide = _copy(hand_models_dir() / "umi", tmp_path / "wide_umi")
    urdf = wide / "umi.urdf"
    urdf.write_text(urdf.read_text().replace('box size="0.012 0.028 0.10"', 'box size="0.012 0.028 0.15"'))
    with pytest.raises(HandSpecError, match=r"field 'name': 'umi' is a built-in hand's name.*my_umi"):
        load_spec(wide / "spec.yaml")
    err = _error(capsys, ["galr", "pretrain", "--init", "long", "--hands", f"+{wide}", "--steps", "1",
                          "--output-dir", str(tmp_path / "run")])  # fmt: skip
    assert "is a built-in hand's name" in err
    same = _copy(hand_models_dir() / "umi", tmp_path / "same_umi")  # an unchanged copy is the built-in
    assert load_spec(same / "spec.yaml").sha256 == load_spec("umi").sha256


# --- 7. config errors -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("flag", "words"),
    [("--policy.horizon=10", "`horizon` (10) must be a multiple of 4"),
     ("--policy.n_action_steps=40", "n_action_steps"),
     ("--policy.action_space=latent", "`action_space` must be one of")],
)  # fmt: skip
def test_train_shows_the_configs_own_error(capsys, flag, words):
    err = _error(capsys, ["train", "--policy.type=opfa", flag, "--dataset.repo_id=local/none"])
    assert words in err and "Couldn't instantiate" not in err


@pytest.mark.parametrize(
    ("argv", "words"),
    [(["galr", "pretrain", "--output-dir", "x", "--validate-every", "0"], "--validate-every: must be a"),
     (["galr", "pretrain", "--output-dir", "x", "--lr", "fast"], "--lr: must be a number, got 'fast'"),
     (["sim", "demos", "--task", "lift", "--hand", "umi", "--output-dir", "x", "--episodes", "-3"],
      "--episodes: must be a positive integer, got -3")],
)  # fmt: skip
def test_bad_numeric_flags_are_one_line(capsys, argv, words):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and words in err and len(err.splitlines()) == 1, err


def test_one_line_of_video_backend_warning_at_most():
    result = run_command(
        [sys.executable, "-m", "lerobot_opfa.cli", "train", "--policy.type=opfa", "--policy.horizon=10",
         "--dataset.repo_id=local/none"], env=ENV, timeout=300,
    )  # fmt: skip
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and lines[-1].startswith("error: `horizon`")
    assert sum("torchcodec" in line for line in lines) <= 1 and "Traceback" not in result.stderr, lines


# --- 8. meshes that cannot be read -----------------------------------------------------------------
def test_an_unreadable_mesh_is_an_error_naming_the_spec_field_and_file(user_allegro_spec, tmp_path, capsys):
    description = tmp_path / "allegro"
    urdf = Path(re.search(r"^model: (.+)$", user_allegro_spec.read_text(), re.MULTILINE)[1])
    shutil.copytree(urdf.parents[1], description)
    copied = description / "urdf" / urdf.name
    copied.write_text(
        copied.read_text().replace("package://example-robot-data/robots/allegro_hand_description/", "../")
    )
    spec = tmp_path / "spec" / "spec.yaml"
    spec.parent.mkdir()
    spec.write_text(user_allegro_spec.read_text().replace(str(urdf), str(copied)))
    assert HandModel.from_spec(spec).dof == 16  # the copy as it ships loads
    (description / "meshes" / "link_3.0_tip.STL").write_text("solid garbage nonsense 12 34\n")
    for command in (
        ["hands", "cloud", str(spec), "--out", str(tmp_path / "c.npz")],
        ["hands", "check", str(spec)],
    ):
        err = _error(capsys, command)
        assert f"{spec}: field 'model'" in err and "link_3.0_tip.STL" in err and "holds no surface" in err
    assert not (tmp_path / "c.npz").exists()


def test_a_labelled_link_without_geometry_refuses_the_spec(umi_copy):
    urdf = umi_copy / "umi.urdf"
    text = urdf.read_text()
    start = text.index('<link name="left_jaw">')
    urdf.write_text(text[:start] + '<link name="left_jaw"/>' + text[text.index("</link>", start) + 7 :])
    with pytest.raises(
        HandSpecError, match=r"field 'links': link\(s\) \['left_jaw'\] are labelled but carry no"
    ):
        HandModel.from_spec(umi_copy / "spec.yaml")


# --- also ----------------------------------------------------------------------------------------
def test_resume_with_other_hands_is_an_error(tiny_galr, capsys):
    err = _error(
        capsys, ["galr", "pretrain", "--output-dir", str(tiny_galr), "--resume", "--hands", "umi,leap"]
    )
    assert "--resume continues a run on hands ['umi', 'inspire']" in err


def test_corrupt_dataset_metadata_names_its_file(datasets, tmp_path, capsys):
    bad = _copy(datasets / "umi", tmp_path / "umi")
    info = bad / "meta" / "info.json"
    info.write_text(info.read_text()[:200])
    err = _error(capsys, ["dataset", "merge", "--inputs", str(bad), "--output", str(tmp_path / "m")])
    assert f"{info} is not valid JSON" in err
    err = _error(
        capsys, ["train", "--policy.type=opfa", "--dataset.repo_id=local/umi", f"--dataset.root={bad}"]
    )
    assert f"{info} is not valid JSON" in err


def test_a_hand_whose_episodes_are_too_short_to_train_on_is_an_error(tmp_path, capsys):
    write_synthetic_dataset(tmp_path / "umi", "umi", episodes=2, frames=12, n_points=8, seed=0)
    write_synthetic_dataset(tmp_path / "inspire", "inspire", episodes=3, frames=1, n_points=8, seed=1)
    merged = tmp_path / "m"
    argv = ["dataset", "merge", "--inputs", str(tmp_path / "umi"), str(tmp_path / "inspire"), "--output"]
    assert cli.main([*argv, str(merged)]) == 0
    err = _error(capsys, ["train", "--policy.type=opfa", "--policy.action_space=per_embodiment",
                          "--policy.device=cpu", "--policy.push_to_hub=false", "--dataset.repo_id=local/m",
                          f"--dataset.root={merged}", "--steps=1", "--batch_size=2",
                          f"--output_dir={tmp_path / 'out'}"])  # fmt: skip
    assert "hand 'inspire' has no frame to train on: its 3 episode(s) are at most 1 frames long" in err


def test_the_cloud_guard_reads_a_history_of_clouds():
    """The cloud guard takes a history of clouds (B, n_obs, N*3) as the single frame (N*3,)."""
    from lerobot_opfa.policy.joint_steps import PointCloudBatchStep

    step = PointCloudBatchStep(n_points=16)
    assert step.observation({"observation.pointcloud": torch.zeros(48)})["observation.pointcloud"].shape == (
        1,
        48,
    )
    history = torch.zeros(2, 2, 48)
    history[1, 0, 5 * 3] = torch.inf
    with pytest.raises(ValueError, match="not finite .* at point 5"):
        step.observation({"observation.pointcloud": history})


# --- found by benchmarks/probe_user_errors.py ------------------------------------------------------
def test_overwrite_replaces_only_a_dataset(datasets, tmp_path, capsys):
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "thesis.tex").write_text("months of work")
    argv = ["dataset", "merge", "--inputs", str(datasets / "umi"), "--output", str(notes), "--overwrite"]
    assert "exists and is not a LeRobotDataset; --overwrite replaces only a dataset" in _error(capsys, argv)
    assert (notes / "thesis.tex").read_text() == "months of work"


@pytest.mark.parametrize("output", [".", "z"])
def test_latent_never_writes_over_or_into_its_input(datasets, tmp_path, capsys, output):
    source = _copy(datasets / "umi", tmp_path / "mg")
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    argv = [
        "policy",
        "latent-dataset",
        "--input",
        str(source),
        "--output",
        str(source / output),
        "--overwrite",
    ]
    assert "would write over the input" in _error(capsys, argv)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_merge_refuses_non_finite_body_entries(datasets, tmp_path, capsys):
    bad = _copy(datasets / "umi", tmp_path / "umi")
    _set_state(bad, 1, float("inf"), slice(3, 5))
    err = _error(capsys, ["dataset", "merge", "--inputs", str(bad), "--output", str(tmp_path / "m")])
    assert (
        f"observation.state is not finite (NaN or inf) in 2 of 12 frames, first in entry '{WRIST_NAMES[1]}'"
        in err
    )


@pytest.mark.parametrize("part", ["meta/episodes", "data"])
def test_a_dataset_folder_missing_its_episodes_or_data_is_one_line(datasets, tmp_path, capsys, part):
    bad = _copy(datasets / "umi", tmp_path / "umi")
    shutil.rmtree(bad / part)
    err = _error(capsys, ["dataset", "merge", "--inputs", str(bad), "--output", str(tmp_path / "m")])
    assert f"{bad}: a LeRobotDataset folder without {part}/*.parquet" in err


def test_train_on_a_dataset_root_that_does_not_exist_is_one_line(tmp_path, capsys):
    root = tmp_path / "typo"
    err = _error(
        capsys, ["train", "--policy.type=opfa", "--dataset.repo_id=local/typo", f"--dataset.root={root}"]
    )
    assert f"--dataset.root {root} does not exist" in err


def test_merging_a_latent_dataset_says_what_it_is(datasets, tiny_galr, tmp_path, capsys):
    inputs = [str(datasets / "umi"), str(datasets / "inspire")]
    assert cli.main(["dataset", "merge", "--inputs", *inputs, "--output", str(tmp_path / "m"), "--galr",
                     str(tiny_galr)]) == 0  # fmt: skip
    argv = ["policy", "latent-dataset", "--input", str(tmp_path / "m"), "--output", str(tmp_path / "z")]
    assert cli.main(argv) == 0
    err = _error(
        capsys, ["dataset", "merge", "--inputs", str(tmp_path / "z"), "--output", str(tmp_path / "m2")]
    )
    assert f"{tmp_path / 'z'} is a latent dataset" in err


def test_galr_command_inputs_of_the_wrong_kind_are_one_line(tiny_galr, tmp_path, capsys):
    np.save(tmp_path / "q.npy", np.array(["a", None], dtype=object), allow_pickle=True)
    embed = [
        "galr",
        "embed",
        "--checkpoint",
        str(tiny_galr),
        "--hand",
        "inspire",
        "--out",
        str(tmp_path / "z"),
    ]
    assert f"{tmp_path / 'q.npy'} is not a .npy array" in _error(
        capsys, [*embed, "--joints", str(tmp_path / "q.npy")]
    )
    err = _error(
        capsys, ["galr", "pretrain", "--model", "latent_dim=four", "--output-dir", str(tmp_path / "r")]
    )
    assert "--model 'latent_dim=four': latent_dim takes int values" in err
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").write_text('{"step": 1, "loss": 0.5}\n')
    err = _error(capsys, ["galr", "curves", str(run), "--out", str(tmp_path / "c.png")])
    assert "has no validation rows yet" in err
